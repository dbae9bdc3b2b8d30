"""Replay check on hand-made plans: clean prints pass, overhangs and collisions are caught."""

from __future__ import annotations

import json

import numpy as np
import pytest
from handmade_plans import H, box_plan, frame, prism_layers, prism_mesh, two_part_plan

from kinematics.machine import MachineGeometry
from slicer.gcode.reader import GcodeFormatError, parse_lines
from slicer.gcode.writer import MachineSetup, generate
from slicer.mesh.samples import to_manifold, to_trimesh
from slicer.plan import PrintPlan, SubpartPlan
from slicer.replay import check as replay
from slicer.replay import collide as replay_collide
from slicer.replay.check import model_index, replay_check
from slicer.replay.coverage import shell_depth, shell_grid
from slicer.replay.geometry import ModelIndex
from slicer.replay.samples import geometry_from_header, move_lengths
from slicer.replay.support import strict_support
from slicer.settings import ProcessSettings

GEO = MachineGeometry()
UP = np.array([0.0, 0.0, 1.0])


def _replay(plan: PrintPlan, mesh, threads: int = 2):
    lines = generate(plan, ProcessSettings(), MachineSetup(GEO)).lines
    return replay_check(parse_lines(lines), mesh, threads=threads)


def _union(*meshes):
    solid = to_manifold(meshes[0])
    for m in meshes[1:]:
        solid = solid + to_manifold(m)
    return to_trimesh(solid)


def _tilted_child_into_the_base():
    plan, d = two_part_plan(GEO, tilt_deg=30.0)
    return plan, _union(prism_mesh(np.zeros(3), UP, 5.0, 20 * H),
                        prism_mesh(np.array([0.0, 0.0, 20 * H]), d, 2.0, 10 * H))


def _low_part_beside_a_tower():
    tower = prism_layers(0, np.zeros(3), UP, 3.0, 100, GEO)
    low = prism_layers(1, np.array([12.0, 0.0, 0.0]), UP, 2.0, 5, GEO)
    plan = PrintPlan(np.eye(4), [SubpartPlan(0, None, None, None, UP, tower),
                                 SubpartPlan(1, 0, None, None, UP, low)])
    return plan, _union(prism_mesh(np.zeros(3), UP, 3.0, 100 * H),
                        prism_mesh(np.array([12.0, 0.0, 0.0]), UP, 2.0, 5 * H))


def test_clean_box_passes_every_figure():
    rep = _replay(box_plan(GEO, n_layers=20), prism_mesh(np.zeros(3), UP, 5.0, 20 * H))
    assert rep.inside >= 0.99 and rep.coverage >= 0.95 and rep.supported >= 0.99
    assert rep.wall_supported >= 0.995 and rep.unsupported_wall_layers == []
    assert rep.collisions == 0 and rep.ok


def test_coverage_drops_when_the_model_is_larger_than_the_toolpaths():
    rep = _replay(box_plan(GEO, n_layers=20), prism_mesh(np.zeros(3), UP, 5.0, 40 * H))
    assert rep.coverage < 0.6


def test_overhang_step_is_flagged_unsupported():
    plan = box_plan(GEO, n_layers=20, shift=(2.0, 0.0), shift_from=10)
    mesh = _union(prism_mesh(np.zeros(3), UP, 5.0, 10 * H),
                  prism_mesh(np.array([2.0, 0.0, 10 * H]), UP, 5.0, 10 * H))
    rep = _replay(plan, mesh)
    assert rep.wall_supported < 0.995
    assert "sub-part 0 layer 10" in rep.unsupported_wall_layers
    assert "sub-part 0 layer 11" not in rep.unsupported_wall_layers  # stacked on layer 10
    assert rep.supported < 0.99


@pytest.mark.parametrize(("gap", "supported"), [(0.0, True), (0.15, False)])
def test_a_first_layer_on_the_flank_of_the_parents_beads(gap, supported):
    # A branch standing sideways (axis +x) on the vertical face x = 5 of an upright block:
    # its first layer lies on the flanks of the block's outer beads, whose centrelines run
    # half a width inside the face. Their material reaches the face, so the first layer is
    # supported, unless it starts a gap away from it.
    root = prism_layers(0, np.zeros(3), UP, 5.0, 60, GEO)
    side = np.array([1.0, 0.0, 0.0])
    base = np.array([5.0 + gap, 0.0, 6.0])
    child = prism_layers(1, base, side, 2.0, 10, GEO)
    plan = PrintPlan(np.eye(4), [SubpartPlan(0, None, None, None, UP, root),
                                 SubpartPlan(1, 0, base, side, side, child)])
    mesh = _union(prism_mesh(np.zeros(3), UP, 5.0, 60 * H), prism_mesh(base, side, 2.0, 10 * H))
    bad = _replay(plan, mesh).unsupported_wall_layers
    assert ("sub-part 1 layer 0" not in bad) == supported
    assert "sub-part 1 layer 1" not in bad  # stacked on the first


def test_tilted_child_over_a_clear_base_has_no_collision():
    plan, d = two_part_plan(GEO, tilt_deg=30.0, lift=1.5)
    mesh = _union(prism_mesh(np.zeros(3), UP, 5.0, 20 * H),
                  prism_mesh(np.array([0.0, 0.0, 20 * H + 1.5]), d, 2.0, 10 * H))
    rep = _replay(plan, mesh)
    assert rep.collisions == 0
    assert rep.inside >= 0.99


def test_nozzle_inside_printed_material_is_flagged():
    rep = _replay(*_tilted_child_into_the_base())
    assert rep.collisions > 0 and not rep.ok
    assert any("sub-part 1" in m and "printed part (sub-part 0" in m
               for m in rep.collision_messages)


def test_carriage_hitting_a_tall_neighbour_is_flagged():
    rep = _replay(*_low_part_beside_a_tower())
    assert rep.collisions > 0
    assert any("sub-part 1, layer 0: the head hits the printed part (sub-part 0" in m
               for m in rep.collision_messages)


def test_tilted_print_on_the_platform_hits_the_platform():
    d = np.array([0.0, -np.sin(np.radians(60)), np.cos(np.radians(60))])
    layers = prism_layers(0, np.zeros(3), d, 3.0, 3, GEO)
    plan = PrintPlan(np.eye(4), [SubpartPlan(0, None, None, None, d, layers)])
    mesh = prism_mesh(np.zeros(3), d, 3.0, 3 * H)
    rep = _replay(plan, mesh)
    assert any("the head hits the platform" in m for m in rep.collision_messages)


@pytest.mark.parametrize("name", ["inside", "coverage", "supported", "wall_supported"])
def test_figures_are_shares(name):
    rep = _replay(box_plan(GEO, n_layers=5), prism_mesh(np.zeros(3), UP, 5.0, 5 * H))
    assert 0.0 <= getattr(rep, name) <= 1.0


@pytest.mark.parametrize("case", [_tilted_child_into_the_base, _low_part_beside_a_tower])
def test_ball_queries_and_axis_groups_find_the_same_collisions(case, monkeypatch):
    plan, mesh = case()
    found = []
    for small_group in (0, 10**9):  # every tip checked with its axis group / by a ball query
        monkeypatch.setattr(replay_collide, "SMALL_GROUP", small_group)
        rep = _replay(plan, mesh)
        found.append((rep.collisions, rep.collision_messages))
    assert found[0][0] > 0
    assert found[0] == found[1]


def test_one_thread_and_two_give_the_same_figures():
    plan = box_plan(GEO, n_layers=20, shift=(2.0, 0.0), shift_from=10)
    mesh = _union(prism_mesh(np.zeros(3), UP, 5.0, 10 * H),
                  prism_mesh(np.array([2.0, 0.0, 10 * H]), UP, 5.0, 10 * H))
    one, two = (_replay(plan, mesh, threads=n).to_dict() for n in (1, 2))
    for rep in (one, two):
        for timing in ("seconds", "timings", "cpu_timings"):
            rep.pop(timing)
    assert one["wall_supported"] < 1.0  # the figures under comparison are not trivial
    assert one == two


def test_a_prebuilt_model_index_gives_the_same_figures_and_a_wrong_one_is_not_used():
    plan = box_plan(GEO, n_layers=20, shift=(2.0, 0.0), shift_from=10)
    mesh = _union(prism_mesh(np.zeros(3), UP, 5.0, 10 * H),
                  prism_mesh(np.array([2.0, 0.0, 10 * H]), UP, 5.0, 10 * H))
    parsed = parse_lines(generate(plan, ProcessSettings(), MachineSetup(GEO)).lines)
    w = ProcessSettings().line_width
    other = _union(prism_mesh(np.zeros(3), UP, 9.0, 40 * H))  # not this model at all
    gridded = model_index(mesh, w)  # with the coverage grid built, as the pipeline does
    shell_grid(gridded, shell_depth(ProcessSettings().perimeters, w))
    reps = [replay_check(parsed, mesh, index=index).to_dict()
            for index in (None, model_index(mesh, w), gridded, model_index(other, 2 * w))]
    for rep in reps:
        for timing in ("seconds", "timings", "cpu_timings"):
            rep.pop(timing)
    assert reps[0]["coverage"] > 0.9  # the figures under comparison are not trivial
    assert reps[0] == reps[1] == reps[2] == reps[3]  # another line width: rebuilt here
    assert len(gridded.grids) == 1  # the replay used the grid built before



@pytest.mark.parametrize(("key", "value"), [
    ("table_origin", [250.0, 250.0]),
    ("a_pivot", [250.0, 250.0, 80.0, 1.0]),
    ("a_limits", [-90.0]),
    ("c_limits", [-180.0, 0.0, 180.0]),
])
def test_a_kinematics_vector_of_another_length_is_a_format_error(key, value):
    # it was taken as it stood, and the replay failed later in numpy (operands could not be
    # broadcast together) instead of naming the header
    kinematics = {"type": "xyzac-trt", "table_origin": [250.0, 250.0, 100.0],
                  "a_pivot": [250.0, 250.0, 80.0], key: value}
    parsed = parse_lines([f";HOSTD_KINEMATICS {json.dumps(kinematics)}", "G1 X1 Y1 Z1 A0 C0"])
    with pytest.raises(GcodeFormatError, match=";HOSTD_KINEMATICS: bad"):
        geometry_from_header(parsed)

def test_inside_test_with_coarse_lines_casts_rays_near_the_surface():
    d = np.array([0.0, -np.sin(np.radians(30)), np.cos(np.radians(30))])
    mesh = prism_mesh(np.zeros(3), d, 3.0, 6.0)  # a tilted box: no face along the lines
    model = ModelIndex(np.asarray(mesh.vertices), np.asarray(mesh.faces), inside_pitch=1.0)
    lo, hi = mesh.bounds
    p = np.random.default_rng(3).uniform(lo - 0.5, hi + 0.5, size=(4000, 3))
    _, e1, e2 = frame(d)
    local = np.column_stack([p @ e1, p @ e2, p @ d])
    truth = (np.abs(local[:, :2]) < 3.0).all(axis=1) & (local[:, 2] > 0) & (local[:, 2] < 6.0)
    near = np.isfinite(model.distance(p, 1.0 / np.sqrt(2.0)))
    assert near.sum() > 500  # many points are left to the rays
    assert np.array_equal(model.inside(p), truth)


def _deposit_samples(parsed, p: ProcessSettings):
    """The replay's deposited samples of a parsed file printed with ``p``."""
    bead_area = np.pi * p.filament_diameter ** 2 / 4.0 / p.line_width
    return replay._deposits(parsed, geometry_from_header(parsed), move_lengths(parsed),
                            bead_area, p.line_width, p.layer_height)[1]


def _overhang_step():
    plan = box_plan(GEO, n_layers=20, shift=(2.0, 0.0), shift_from=10)
    mesh = _union(prism_mesh(np.zeros(3), UP, 5.0, 10 * H),
                  prism_mesh(np.array([2.0, 0.0, 10 * H]), UP, 5.0, 10 * H))
    return plan, mesh


def test_support_judged_on_some_samples_is_theirs_of_every_sample():
    """Judging a subset changes which points are judged, never a point's verdict: every
    sample's bead still counts as material beneath."""
    plan, _ = _overhang_step()
    parsed = parse_lines(generate(plan, ProcessSettings(), MachineSetup(GEO)).lines)
    p = ProcessSettings()
    s = _deposit_samples(parsed, p)
    every = strict_support(s, p.layer_height, p.line_width, 150.0)
    assert 0 < (~every).sum() < len(s)  # verdicts of both kinds
    rng = np.random.default_rng(11)
    for _ in range(5):
        some = np.sort(rng.choice(len(s), size=len(s) // 3, replace=False))
        judged = strict_support(s, p.layer_height, p.line_width, 150.0, judged=some)
        assert np.array_equal(judged, every[some])


def test_judging_every_second_sample_gives_the_figures_of_every_sample(monkeypatch):
    assert replay.JUDGE_STRIDE == 2  # the shipped stride (read before it is patched below)
    plan, mesh = _overhang_step()
    reps = []
    for stride in (1, replay.JUDGE_STRIDE):
        monkeypatch.setattr(replay, "JUDGE_STRIDE", stride)
        reps.append(_replay(plan, mesh).to_dict())
    every, judged = reps
    assert every["points"] == judged["points"]
    assert abs(judged["wall_points"] / every["wall_points"] - 0.5) < 0.01
    assert every["supported"] < 0.99  # the figures under comparison are not trivial
    for key in ("inside", "supported", "bridged", "wall_supported"):
        assert abs(judged[key] - every[key]) < 0.002, key
    assert judged["unsupported_wall_layers"] == every["unsupported_wall_layers"]


def test_inside_share_is_the_share_of_judged_samples_inside_or_near_the_model():
    """Beads laid 0.4 mm beyond a narrower box: the share agrees with the box's own distance
    function on the judged samples (inside, or within the slack of its surface)."""
    p = ProcessSettings()
    plan = box_plan(GEO, half=5.0, n_layers=20)
    mesh = prism_mesh(np.zeros(3), UP, 4.6, 20 * H)
    parsed = parse_lines(generate(plan, p, MachineSetup(GEO)).lines)
    rep = replay_check(parsed, mesh)
    s = _deposit_samples(parsed, p)
    q = s.p[::replay.JUDGE_STRIDE] - np.array([0.0, 0.0, 10 * H])
    beyond = np.maximum(np.abs(q) - np.array([4.6, 4.6, 10 * H]), 0.0)
    expected = np.mean(np.linalg.norm(beyond, axis=1) <= replay.INSIDE_SLACK * p.line_width)
    assert 0.5 < expected < 0.95  # some beads lie outside, most inside
    assert rep.inside == pytest.approx(expected, abs=1e-9)
