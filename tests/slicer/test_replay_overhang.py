"""A layer printed in the air is refused, whatever the decomposition did.

The planar control of a Γ bracket (a column with an arm on top) prints the arm's first
layer over nothing: the per-layer support check of the replay must refuse it, from
``slice_model``, ``hostctl slice`` and the daemon's slicing worker alike.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from handmade_plans import H, box_plan, prism_mesh

from hostd.cli.errors import EXIT_FAILED
from hostd.cli.main import main
from kinematics.machine import MachineGeometry
from slicer.gcode.reader import parse_lines
from slicer.gcode.writer import MachineSetup, generate
from slicer.mesh.samples import to_manifold, to_trimesh
from slicer.pipeline import OverhangError, overhang_message, slice_model
from slicer.printhead import Printhead
from slicer.replay.check import replay_check
from slicer.replay.support import OVERHANG_RUN, OVERHANG_SHARE
from slicer.settings import ProcessSettings

GEO = MachineGeometry()
UP = np.array([0.0, 0.0, 1.0])
OFFSET = np.array([40.0, -30.0, 7.0])  # where the STL lies: not the platform frame
COLUMN, ARM_FROM, TOP = 10.0, 6.0, 8.0  # column side, arm's underside, top (mm)


def gamma_bracket() -> trimesh.Trimesh:
    """A 10 × 10 × 8 column with a 20 × 10 × 2 arm on top (Γ), moved to ``OFFSET``."""
    column = trimesh.creation.box([COLUMN, COLUMN, TOP])
    column.apply_translation([COLUMN / 2, COLUMN / 2, TOP / 2])
    arm = trimesh.creation.box([20.0, COLUMN, TOP - ARM_FROM])
    arm.apply_translation([10.0, COLUMN / 2, (TOP + ARM_FROM) / 2])
    mesh = to_trimesh(to_manifold(column) + to_manifold(arm))
    return mesh.apply_translation(OFFSET)


@pytest.fixture(scope="module")
def refusal() -> OverhangError:
    """The planar slice of the Γ bracket (one sub-part, horizontal layers) is refused."""
    with pytest.raises(OverhangError) as err:
        slice_model(gamma_bracket(), ProcessSettings(), GEO, Printhead.default(), planar=True)
    return err.value


def test_a_layer_printed_in_the_air_is_refused_in_one_line(refusal):
    msg = str(refusal)
    assert "\n" not in msg
    first = round(ARM_FROM / H)  # the arm's first layer (index from 0) lies at z 6.2
    assert f"sub-part 0 layer {first} (z {ARM_FROM + H:.2f} mm)" in msg
    assert "printed in the air" in msg and "unsupported" in msg and "part frame" in msg
    assert "slice it five-axis" in msg


def test_the_refusal_names_a_point_of_the_arm_in_the_part_frame(refusal):
    at = str(refusal).split("around [", 1)[1].split("]", 1)[0]
    x, y, z = (float(v) for v in at.split(","))
    # over nothing: the arm beyond the column, in the STL's own coordinates
    assert COLUMN + 1.0 < x - OFFSET[0] <= 20.0 and 0.0 <= y - OFFSET[1] <= COLUMN
    assert abs(z - OFFSET[2] - (ARM_FROM + H)) < 0.05


def test_the_refused_layer_is_far_over_both_limits(refusal):
    share = float(str(refusal).split(" prints ", 1)[1].split("%", 1)[0]) / 100
    run = float(str(refusal).split("a run of ", 1)[1].split(" mm", 1)[0])
    assert share > 2 * OVERHANG_SHARE and run > 2 * OVERHANG_RUN


def test_a_synthesised_layer_in_the_air_is_in_the_replay_report():
    """The replay alone: a box whose upper layers are moved beyond its side."""
    plan = box_plan(GEO, n_layers=8, shift=(12.0, 0.0), shift_from=4)
    mesh = to_trimesh(to_manifold(prism_mesh(np.zeros(3), UP, 5.0, 4 * H))
                      + to_manifold(prism_mesh(np.array([12.0, 0.0, 4 * H]), UP, 5.0, 4 * H)))
    rep = replay_check(parse_lines(generate(plan, ProcessSettings(), MachineSetup(GEO)).lines),
                       mesh)
    assert not rep.ok and rep.collisions == 0
    assert [(d["subpart"], d["layer"]) for d in rep.overhang_layers] == [(0, 4)]
    worst = rep.overhang_layers[0]
    assert rep.worst_layer == worst and worst["share"] > 0.95
    assert rep.worst_layer_unsupported == worst["share"]
    assert rep.worst_layer_run_mm == worst["run_mm"] > OVERHANG_RUN
    assert "worst layer sub-part 0 layer 4" in rep.summary()


def test_a_clean_box_has_no_layer_in_the_air():
    plan = box_plan(GEO, n_layers=8)
    rep = replay_check(parse_lines(generate(plan, ProcessSettings(), MachineSetup(GEO)).lines),
                       prism_mesh(np.zeros(3), UP, 5.0, 8 * H))
    assert rep.ok and rep.overhang_layers == []
    assert rep.worst_layer is not None and rep.worst_layer_unsupported < OVERHANG_SHARE


def test_five_axis_advice_names_the_sub_part_and_another_seed():
    layer = {"subpart": 2, "layer": 7, "z": 12.5, "extruded_mm": 300.0,
             "unsupported_mm": 250.0, "share": 0.83, "run_mm": 120.0, "point": [1, 2, 3]}
    msg = overhang_message([layer, layer], seed=1)
    assert "sub-part 2 layer 7 (z 12.50 mm)" in msg and "83.0%" in msg
    assert "and 1 more layers" in msg
    assert "the decomposition left an overhang in sub-part 2; try decompose.seed 2" in msg


def test_hostctl_slice_refuses_it_with_exit_1_and_no_file(tmp_path, capsys):
    stl, out = tmp_path / "gamma.stl", tmp_path / "gamma.gcode"
    gamma_bracket().export(stl)
    rc = main(["slice", str(stl), "-o", str(out), "--planar"])
    err = capsys.readouterr().err.strip()
    assert rc == EXIT_FAILED
    assert len(err.splitlines()) == 1 and err.startswith(f"hostctl: {stl}: replay found a "
                                                         "layer printed in the air")
    assert not out.exists()


def test_the_daemon_job_fails_with_the_message(tmp_path, monkeypatch):
    """The slicing worker's function, with the decomposition forced to the planar one."""
    from hostd.config.loader import defaults
    from hostd.slicing_worker import SliceError, slice_in_worker
    from slicer import pipeline
    from slicer.paths.planner import plan_planar

    monkeypatch.setattr(pipeline, "plan_model", lambda mesh, placement, settings, geometry,
                        *_a, **_k: plan_planar(mesh, settings, geometry, placement))
    stl, out = tmp_path / "spool-1.stl", tmp_path / "job.gcode"
    gamma_bracket().export(stl)
    values = dict(defaults().replace(decompose__seed=4).data)
    with pytest.raises(SliceError) as err:
        slice_in_worker(str(stl), values, str(out), name="gamma.stl")
    msg = str(err.value)
    assert "\n" not in msg and "layer printed in the air" in msg
    assert msg.startswith("gamma.stl: replay found a layer printed in the air")
    assert "try --seed 5" in msg  # hostctl print's option (decompose.seed 4 in the config)
    assert "spool-1" not in msg
    assert list(tmp_path.iterdir()) == [stl]
