"""The replay's memory bounds: work done by chunks gives the answers of work done at once, and
a file whose check would exceed the memory budget is refused before anything is sampled."""

from __future__ import annotations

import numpy as np
import pytest
from handmade_plans import H, box_plan, prism_mesh, two_part_plan

from kinematics.machine import MachineGeometry
from slicer.gcode.reader import parse_lines
from slicer.gcode.writer import MachineSetup, generate
from slicer.mesh.samples import to_manifold, to_trimesh
from slicer.paths.layers import SlicingError
from slicer.replay import check as replay
from slicer.replay import collide as replay_collide
from slicer.replay import columns as replay_columns
from slicer.replay import geometry as replay_geometry
from slicer.replay import samples as replay_samples
from slicer.replay import support as replay_support
from slicer.replay.check import ReplayBudgetError, memory_estimate, model_index, replay_check
from slicer.replay.samples import (
    extruding_moves,
    geometry_from_header,
    map_and_sample,
    map_moves,
    move_lengths,
    sample_moves,
)
from slicer.settings import ProcessSettings

GEO = MachineGeometry()
UP = np.array([0.0, 0.0, 1.0])
TINY = {(replay_samples, "CHUNK_SAMPLES"): 97, (replay_support, "CHUNK_PAIRS"): 50,
        (replay_columns, "CHUNK_CROSSINGS"): 101, (replay_geometry, "CHUNK_POINTS"): 103,
        (replay_geometry, "EXACT_CHUNK"): 7, (replay_collide, "CHUNK"): 89,
        (replay, "BRIDGE_CHUNK"): 13}


def _tilted_child():
    plan, d = two_part_plan(GEO, tilt_deg=30.0)
    solid = (to_manifold(prism_mesh(np.zeros(3), UP, 5.0, 20 * H))
             + to_manifold(prism_mesh(np.array([0.0, 0.0, 20 * H]), d, 2.0, 10 * H)))
    return parse_lines(generate(plan, ProcessSettings(), MachineSetup(GEO)).lines), \
        to_trimesh(solid)


def _overhang_step():
    plan = box_plan(GEO, n_layers=20, shift=(2.0, 0.0), shift_from=10)
    solid = (to_manifold(prism_mesh(np.zeros(3), UP, 5.0, 10 * H))
             + to_manifold(prism_mesh(np.array([2.0, 0.0, 10 * H]), UP, 5.0, 10 * H)))
    return parse_lines(generate(plan, ProcessSettings(), MachineSetup(GEO)).lines), \
        to_trimesh(solid)


def _figures(parsed, mesh) -> dict[str, object]:
    rep = replay_check(parsed, mesh).to_dict()
    for timing in ("seconds", "timings", "cpu_timings"):
        rep.pop(timing)
    return rep


@pytest.mark.parametrize("case", [_tilted_child, _overhang_step])
def test_tiny_chunks_give_the_figures_of_the_default_ones(case, monkeypatch):
    parsed, mesh = case()
    default = _figures(parsed, mesh)
    for (module, name), value in TINY.items():
        monkeypatch.setattr(module, name, value)
    assert _figures(parsed, mesh) == default
    assert default["points"] > 50 * TINY[(replay_samples, "CHUNK_SAMPLES")]  # many chunks


def test_tiny_chunks_build_the_same_model_index(monkeypatch):
    _, mesh = _tilted_child()
    ref = model_index(mesh, 0.45)
    for (module, name), value in TINY.items():
        monkeypatch.setattr(module, name, value)
    small = model_index(mesh, 0.45)
    assert len(ref._columns.key) > 10 * TINY[(replay_columns, "CHUNK_CROSSINGS")]
    assert np.array_equal(small._columns.key, ref._columns.key)
    assert len(ref._tree.data) > 10 * TINY[(replay_geometry, "CHUNK_POINTS")]
    assert np.array_equal(small._tree.data, ref._tree.data)
    assert np.array_equal(small._owner, ref._owner)
    assert small.nbytes == ref.nbytes > ref._columns.key.nbytes


def test_samples_mapped_by_chunks_are_those_of_all_moves_mapped_at_once(monkeypatch):
    parsed, _ = _tilted_child()
    geo, lengths = geometry_from_header(parsed), move_lengths(parsed)
    moves = extruding_moves(parsed, lengths)
    whole = sample_moves(parsed, geo, map_moves(parsed, geo, moves, lengths, 1.0), 0.2, 1.0)
    monkeypatch.setattr(replay_samples, "CHUNK_SAMPLES", 97)
    assert len(replay_samples._move_chunks(np.cumsum(np.ones(len(moves), int) * 3))) > 10
    chunked = map_and_sample(parsed, geo, moves, lengths, 1.0, 0.2, 1.0)
    for name in ("p", "u", "h", "step", "move", "seq", "subpart", "layer"):
        assert np.array_equal(getattr(chunked, name), getattr(whole, name)), name
    assert chunked.move.dtype == np.int32  # half the bytes of int64 per sample


def test_support_is_searched_in_chunks_of_bounded_pairs(monkeypatch):
    monkeypatch.setattr(replay_support, "CHUNK_PAIRS", 1000)
    chunks = replay_support.support_chunks(2345, 10)
    assert [c.stop - c.start for c in chunks] == [100] * 23 + [45]
    assert replay_support.support_chunks(0, 10) == []


def test_first_bead_per_voxel_by_chunks_is_that_of_all_beads(monkeypatch):
    rng = np.random.default_rng(3)
    beads = rng.uniform(-5.0, 5.0, (5000, 3))
    whole = replay_collide.voxel_representatives(beads, 0.5)
    monkeypatch.setattr(replay_collide, "CHUNK", 77)
    assert np.array_equal(replay_collide.voxel_representatives(beads, 0.5), whole)
    assert np.all(np.diff(whole) > 0)


def test_the_estimate_counts_the_samples_the_check_takes():
    parsed, mesh = _overhang_step()
    n, need = memory_estimate(parsed, move_lengths(parsed), ProcessSettings().line_width)
    assert n == replay_check(parsed, mesh).points
    assert need >= n * replay.BYTES_PER_SAMPLE


def test_a_file_over_the_memory_budget_is_refused_in_one_line(monkeypatch):
    parsed, mesh = _overhang_step()
    taken = []
    monkeypatch.setattr(replay, "map_and_sample", lambda *a, **k: taken.append(a))
    with pytest.raises(ReplayBudgetError) as err:
        replay_check(parsed, mesh, memory_budget=10_000)
    assert isinstance(err.value, SlicingError)  # hostctl and the daemon report it as such
    assert "\n" not in str(err.value) and "budget" in str(err.value)
    assert taken == []  # refused before any sample was taken


@pytest.mark.parametrize(("height", "expected", "not_expected"), [
    (0.2, "a layer height of about", "too large for the check's memory budget"),
    (0.32, "the layer height 0.32 mm is already the largest the 0.4 mm nozzle takes: the "
           "part is too large for the check's memory budget; only a smaller part fits",
     "larger layer height"),
])
def test_the_refusal_advises_only_what_can_fit(monkeypatch, height, expected, not_expected):
    plan = box_plan(GEO, n_layers=6, h=height)
    parsed = parse_lines(generate(plan, ProcessSettings(layer_height=height),
                                  MachineSetup(GEO)).lines)
    _, need = memory_estimate(parsed, move_lengths(parsed), ProcessSettings().line_width)
    with pytest.raises(ReplayBudgetError) as err:  # over by a fifth: 1.2 × 0.2 mm fits
        replay_check(parsed, prism_mesh(np.zeros(3), UP, 5.0, 6 * height),
                     memory_budget=need / 1.2)
    assert expected in str(err.value) and not_expected not in str(err.value)


def test_the_advice_says_when_even_the_largest_layer_height_would_not_fit():
    gib = float(1 << 30)
    assert replay.budget_advice(1.2 * gib, gib, 0.2, 0.4) == (
        "a layer height of about 0.24 mm or more (process.layer_height, at most 0.32 mm) "
        "fits, or a smaller part")
    assert replay.budget_advice(3.0 * gib, gib, 0.2, 0.4).startswith(
        "even the largest layer height the 0.4 mm nozzle takes, 0.32 mm, would not fit")
    assert "larger layer height" in replay.budget_advice(2 * gib, gib, None, None)
