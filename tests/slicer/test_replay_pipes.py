"""The sample pipes end to end at 0.2 mm: five-axis passes the replay, planar control fails.

Each (model, planar) is sliced once per session (module fixture ``sliced``).
"""

from __future__ import annotations

import numpy as np
import pytest

from kinematics.machine import MachineGeometry
from slicer.gcode.reader import parse_lines
from slicer.mesh.samples import branched_pipe, pipe2, pipe3
from slicer.pipeline import slice_model
from slicer.printhead import Printhead
from slicer.replay.check import part_frame_path, replay_file
from slicer.replay.support import OVERHANG_RUN, OVERHANG_SHARE
from slicer.settings import ProcessSettings

pytestmark = pytest.mark.slow
GEO = MachineGeometry()
SETTINGS = ProcessSettings(layer_height=0.2)


STEEP = ((25.0, 0.0, 30.0),)  # one branch 30° above the horizontal: steeper than 45°
MODELS = {"pipe2": pipe2, "pipe3": pipe3, "steep": lambda: branched_pipe(STEEP)}


def _slice(mesh, planar=False, keep_plan=False, allow_overhang=False):
    return slice_model(mesh, SETTINGS, GEO, Printhead.default(), planar=planar,
                       keep_plan=keep_plan, allow_overhang=allow_overhang)


@pytest.fixture(scope="module")
def sliced():
    """One slice per (model, planar) for the whole module."""
    cache = {}

    def get(model, planar=False):
        if (model, planar) not in cache:
            # the steep branch has wall layers over air, planar and five-axis: the figures
            # of its file are measured here, so it is written as allow_overhang lets it
            cache[model, planar] = _slice(MODELS[model](), planar=planar,
                                          keep_plan=model == "pipe2" and not planar,
                                          allow_overhang=model == "steep")
        return cache[model, planar]
    return get


@pytest.fixture(scope="module")
def five_axis_pipe2(sliced):
    return sliced("pipe2")


@pytest.mark.parametrize("model", ["pipe2", "pipe3"])
def test_five_axis_pipes_pass_the_replay(model, sliced):
    res = sliced(model)
    rep = res.replay
    assert res.subparts >= 2
    assert rep["inside"] >= 0.99 and rep["coverage"] >= 0.95
    assert rep["supported"] >= 0.99 and rep["collisions"] == 0
    assert rep["wall_supported"] >= 0.995


@pytest.mark.parametrize("model", ["pipe2", "pipe3"])
def test_five_axis_pipes_have_no_unsupported_wall_layer(model, sliced):
    assert sliced(model).replay["unsupported_wall_layers"] == []


@pytest.mark.parametrize("model", ["pipe2", "pipe3"])
def test_five_axis_pipes_print_no_layer_in_the_air_with_a_margin(model, sliced):
    """Measured worst layers (0.2 mm): pipe3 1:0, 12.4 % of 225 mm unsupported; pipe2 0:14,
    a 1.8 mm run (the disc's top skin, bridging since QA finding 3). The per-layer limits
    stay at least twice as far."""
    rep = sliced(model).replay
    assert rep["overhang_layers"] == []
    assert (rep["worst_layer_unsupported"] < OVERHANG_SHARE / 2
            or rep["worst_layer_run_mm"] < OVERHANG_RUN / 2)
    assert rep["worst_layer_run_mm"] < OVERHANG_RUN / 4


@pytest.mark.parametrize("model", ["pipe2", "pipe3"])
def test_planar_control_of_the_45_degree_pipes_shows_unsupported_points(model, sliced):
    rep = sliced(model, planar=True).replay
    assert rep["supported"] < 1.0 and rep["wall_supported"] < 1.0


def test_planar_control_of_a_steeper_branch_fails_both_wall_targets(sliced):
    rep = sliced("steep", planar=True).replay
    assert rep["wall_supported"] < 0.995
    assert len(rep["unsupported_wall_layers"]) > 0


def test_five_axis_print_of_a_steeper_branch_meets_the_wall_share_target(sliced):
    """The refined cut (slicer.decompose.plane_refine) takes the 30° branch's root off the
    trunk: the walls meet the share target and only a handful of layers stay above 5 %."""
    five, planar = sliced("steep").replay, sliced("steep", planar=True).replay
    assert five["collisions"] == 0
    assert five["wall_supported"] >= 0.995 > planar["wall_supported"]
    assert 5 * len(five["unsupported_wall_layers"]) < len(planar["unsupported_wall_layers"])
    # the branch's first layer stands on the flank of the tube's beads (a near-vertical base)
    assert "sub-part 1 layer 0" not in five["unsupported_wall_layers"]


def test_five_axis_print_of_a_steeper_branch_has_no_unsupported_wall_layer(sliced):
    """The bore's arch in the trunk wall (3 layers at 5-7 % when the tube prints upright,
    where no planar cut takes it off the tube) is held once the retry leans the tube's
    layers towards the branch there (slicer.paths.upright)."""
    rep = sliced("steep").replay
    assert rep["unsupported_wall_layers"] == []


def test_replaying_the_written_text_gives_the_same_figures(five_axis_pipe2, tmp_path):
    """The pipeline replays the moves in memory; the file alone (headers, placement, STL
    coordinates) must give the same figures."""
    res = five_axis_pipe2
    path = tmp_path / "pipe2.gcode"
    path.write_text("\n".join(res.lines) + "\n")
    rep = replay_file(path, pipe2()).to_dict()
    for key in ("points", "wall_points", "collisions", "unsupported_wall_layers"):
        assert rep[key] == res.replay[key], key
    for key in ("inside", "coverage", "shell_coverage", "supported", "bridged",
                "wall_supported"):
        assert abs(rep[key] - res.replay[key]) < 5e-4, key


def test_kinematic_round_trip_of_a_real_plan(five_axis_pipe2):
    res = five_axis_pipe2
    parsed = parse_lines(res.lines)
    stl = part_frame_path(parsed)
    place = res.plan.placement
    planned = []
    for sp in res.plan.subparts:
        for la in sp.layers:
            for p in la.paths:
                pts = np.asarray(p.points)
                pts = np.vstack([pts, pts[:1]]) if p.closed and len(pts) > 2 else pts
                planned.append(pts[1:])
    planned = np.concatenate(planned)
    back = planned @ np.linalg.inv(place[:3, :3]).T - place[:3, 3] @ np.linalg.inv(
        place[:3, :3]).T
    # segments shorter than the printed precision collapse and vertices that a longer move
    # passes within the linearisation tolerance are left out (slicer/gcode/merge.py): every
    # move written ends at a planned vertex
    assert 0 < len(stl) <= len(back)
    from scipy.spatial import cKDTree
    d, _ = cKDTree(back).query(stl)
    assert d.max() < 0.01
