"""The machine envelope: travel ranges, platform footprint, nothing to print, ``{safe_z}``."""

from __future__ import annotations

import re

import manifold3d as m3
import numpy as np
import pytest
import trimesh
from handmade_plans import box_plan, two_part_plan
from shared_models import MODELS

from kinematics.machine import MachineGeometry
from slicer.envelope import (
    DEFAULT_TRAVEL,
    EnvelopeError,
    extruded_length,
    footprint_message,
    footprint_radius,
    place_of,
    travel_violation,
)
from slicer.gcode.writer import MachineSetup, draft, generate
from slicer.mesh.errors import MeshError
from slicer.mesh.read import load_mesh
from slicer.mesh.samples import cylinder, to_trimesh
from slicer.pipeline import check_envelope, plan_model, slice_model
from slicer.printhead import Printhead
from slicer.settings import ProcessSettings

GEO = MachineGeometry()
SETTINGS = ProcessSettings()
PIPE2 = MODELS / "pipe2.stl"
TABLE_Z = GEO.table_origin[2]


def thin_wall_box(wall: float = 0.3) -> trimesh.Trimesh:
    """A 20 x 20 x 10 mm open box whose walls are ``wall`` thick (no floor, no lid)."""
    inner = 20.0 - 2 * wall
    solid = m3.Manifold.cube([20, 20, 10], True) - m3.Manifold.cube([inner, inner, 12], True)
    return to_trimesh(solid.translate([0, 0, 5]))


def bar(length: float) -> trimesh.Trimesh:
    return trimesh.creation.box([length, 20, 10]).apply_translation([0, 0, 5])


# -- the pure functions ---------------------------------------------------------------------

def test_travel_violation_is_the_worst_excursion_and_ignores_unset_axes():
    xyz = np.array([[np.nan, np.nan, 650.0], [10, 20, 30], [-3, 20, 710], [-5, 20, 705]])
    v = travel_violation(xyz, DEFAULT_TRAVEL)
    assert (v.axis, v.row, v.value, v.low, v.high) == (2, 2, 710.0, 0.0, 700.0)
    assert v.message("sub-part 0, layer 3") == (
        "machine Z reaches 710.000 mm, outside machine.z_range [0, 700] (sub-part 0, layer 3)")
    low = travel_violation(xyz[:2] - [11, 0, 0], DEFAULT_TRAVEL)
    assert (low.axis, low.row, low.value) == (0, 1, -1.0)
    # the ranges are inclusive and a NaN (axis not set yet) is no position
    assert travel_violation([[np.nan, np.nan, 700.0], [0, 500, 0]], DEFAULT_TRAVEL) is None


def test_footprint_radius_against_the_platform():
    radius = footprint_radius(bar(400).vertices)
    assert radius == pytest.approx(np.hypot(200, 10))
    assert footprint_message(radius, 150.0) == (
        "does not fit on the platform: footprint radius 200.2 mm exceeds "
        "machine.platform_radius 150 mm")
    assert footprint_message(footprint_radius(bar(200).vertices), 150.0) is None


def test_extruded_length_counts_only_moves_that_extrude():
    xyz = np.array([[np.nan, np.nan, 160.0], [0, 0, 160], [0, 0, 100], [0, 0, 100],
                    [10, 0, 100], [10, 0, 100], [10, 5, 100]])
    assert extruded_length(xyz, [0, 0, 0, 1.0, 0.5, -1.0, 0.0]) == pytest.approx(10.0)
    # travels, a retract and an unretract in place: no filament laid down
    assert extruded_length(xyz, [0, 0, 0, 1.0, 0, -1.0, 0]) == 0.0


def test_place_of_a_move_is_its_layer_or_transition():
    moves = draft(two_part_plan(GEO, tilt_deg=30.0)[0], SETTINGS, MachineSetup(GEO))
    tab = moves.program.table()
    marker = next(k for k, text in enumerate(tab.texts)
                  if text.startswith(";HOSTD_TRANSITION ") and '"to": 1' in text)
    lift = int(tab.at[marker])  # the first move after the marker
    assert place_of(lift, tab.at, tab.texts) == "transition to sub-part 1"
    assert place_of(lift - 1, tab.at, tab.texts) == "sub-part 0, layer 19"  # its retract
    assert place_of(len(tab.rows) - 1, tab.at, tab.texts) == "sub-part 1, layer 9"


# -- the writer's {safe_z} ------------------------------------------------------------------

def _script_z(lines: list[str], marker: str) -> float:
    line = next(ln for ln in lines if ln.startswith("G0 Z") and ln.endswith(marker))
    return float(line.split()[1][1:])


def test_safe_z_of_the_scripts_clears_the_platform_when_nothing_was_printed():
    plan = box_plan(GEO, n_layers=3)
    for layer in plan.subparts[0].layers:
        layer.paths = []
    s = ProcessSettings(start_gcode="G0 Z{safe_z} F3001\n", end_gcode="G0 Z{safe_z} F3002\n")
    lines = generate(plan, s, MachineSetup(GEO)).lines
    for marker in ("F3001", "F3002"):
        assert _script_z(lines, marker) >= TABLE_Z + s.safe_height


def test_start_safe_z_clears_the_platform_before_a_print():
    s = ProcessSettings(start_gcode="G0 Z{safe_z} F3001\n")
    moves = draft(box_plan(GEO), s, MachineSetup(GEO))
    lines = moves.finish().lines
    assert _script_z(lines, "F3001") >= TABLE_Z + s.safe_height
    assert moves.script_safe_z()["start"] == _script_z(lines, "F3001")


# -- refusals in the pipeline ---------------------------------------------------------------

@pytest.fixture(scope="module")
def pipe2_plan():
    mesh, placement = load_mesh(PIPE2)
    return plan_model(mesh, placement.matrix, SETTINGS, GEO, Printhead.default(), None, False)


def test_pipe2_fits_the_default_machine_but_not_a_low_z_range(pipe2_plan):
    check_envelope(draft(pipe2_plan, SETTINGS, MachineSetup(GEO)))  # the shipped config
    low = MachineSetup(GEO, travel=((0, 500), (0, 500), (0, 150)))
    with pytest.raises(EnvelopeError) as err:
        check_envelope(draft(pipe2_plan, SETTINGS, low), "pipe2.stl")
    assert re.fullmatch(r"pipe2\.stl: machine Z reaches 2\d\d\.\d{3} mm, outside "
                        r"machine\.z_range \[0, 150\] \(transition to sub-part 1: the lift "
                        r"clears the part by process\.safe_height 60 mm\)", str(err.value))


def test_pipe2_near_the_x_end_of_travel_is_refused_where_it_leaves(pipe2_plan):
    corner = MachineSetup(MachineGeometry((10.0, 10.0, 100.0), (10.0, 10.0, 80.0)))
    moves = draft(pipe2_plan, SETTINGS, corner)
    xy = moves.program.table().vals[:, :2]
    assert np.nanmin(xy) < 0.0  # the part reaches X or Y below the travel
    with pytest.raises(EnvelopeError, match=r"machine [XY] reaches -\d+\.\d{3} mm, outside "
                                            r"machine\.[xy]_range \[0, 500\] \(sub-part 0, "
                                            r"layer \d+\)"):
        check_envelope(moves)


def test_a_part_wider_than_the_platform_is_refused_before_planning():
    with pytest.raises(EnvelopeError, match=r"footprint radius 200\.2 mm exceeds "
                                            r"machine\.platform_radius 150 mm"):
        slice_model(bar(400), SETTINGS, GEO, check=False)


def test_walls_thinner_than_a_line_are_nothing_to_print():
    with pytest.raises(EnvelopeError, match=r"^<mesh>: nothing to print: walls thinner than "
                                            r"the line width \(0\.45 mm\) leave no toolpath "
                                            r"in any of the \d+ layers$"):
        slice_model(thin_wall_box(0.3), SETTINGS, GEO, check=False)


def test_envelope_errors_are_bad_input_for_the_cli():
    assert issubclass(EnvelopeError, MeshError)


def test_daemon_worker_reports_the_travel_in_one_line(tmp_path):
    from hostd.config.loader import defaults
    from hostd.slicing_worker import SliceError, slice_in_worker

    stl, out = tmp_path / "cyl.stl", tmp_path / "cyl.gcode"
    cylinder(radius=6.0, height=12.0).export(stl)
    values = dict(defaults().replace(machine__z_range=[0, 150]).data)
    with pytest.raises(SliceError) as err:
        slice_in_worker(str(stl), values, str(out))
    assert "outside machine.z_range [0, 150]" in str(err.value)
    assert len(str(err.value).splitlines()) == 1
    assert list(tmp_path.iterdir()) == [stl]
