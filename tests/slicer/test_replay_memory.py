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
from slicer.replay import passes as replay_passes
from slicer.replay import samples as replay_samples
from slicer.replay import stream as replay_stream
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
        (replay_passes, "BRIDGE_CHUNK"): 13, (replay_passes, "TIP_CHUNK"): 211,
        (replay_stream, "HOLD_SAMPLES"): 0, (replay_stream, "TILE_SAMPLES"): 300,
        (replay_stream, "CHUNK_SAMPLES"): 250, (replay_stream, "MAP_MOVES"): 5}


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
    assert len(replay_samples.move_chunks(np.cumsum(np.ones(len(moves), int) * 3))) > 10
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
    for name in ("map_and_sample", "map_moves"):  # how the deposits are measured and sampled
        monkeypatch.setattr(replay_stream, name, lambda *a, **k: taken.append(a))
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
    _, scaling, fixed = replay.memory_parts(parsed, move_lengths(parsed),
                                            ProcessSettings().line_width)
    with pytest.raises(ReplayBudgetError) as err:  # over by a fifth of what scales with
        replay_check(parsed, prism_mesh(np.zeros(3), UP, 5.0, 6 * height),  # the layers:
                     memory_budget=fixed + scaling / 1.2)  # 1.2 × 0.2 mm fits
    assert expected in str(err.value) and not_expected not in str(err.value)


def test_the_advice_says_when_even_the_largest_layer_height_would_not_fit():
    gib = float(1 << 30)
    assert replay.budget_advice(1.2 * gib, gib, 0.2, 0.4) == (
        "a layer height of about 0.24 mm or more (process.layer_height, at most 0.32 mm) "
        "fits, or a smaller part")
    assert replay.budget_advice(3.0 * gib, gib, 0.2, 0.4).startswith(
        "even the largest layer height the 0.4 mm nozzle takes, 0.32 mm, would not fit")
    assert "larger layer height" in replay.budget_advice(2 * gib, gib, None, None)


# -- the check by tiles and chunks against the check of all samples at once -------------------

def _sliced(mesh, planar: bool):
    from slicer.pipeline import slice_model
    from slicer.printhead import Printhead

    res = slice_model(mesh, ProcessSettings(), GEO, Printhead.default(), planar=planar,
                      check=False)
    return parse_lines(res.lines)


def _tee():
    """A tube with a horizontal branch, whose underside's lip is an unsupported wall."""
    from slicer.mesh.samples import branched_pipe

    return branched_pipe(((12.0, 0.0, 0.0),), height=26.0, branch_length=20.0)


@pytest.fixture(scope="module")
def pipe2_files():
    from slicer.mesh.samples import pipe2

    return {"five-axis": (_sliced(pipe2(), False), pipe2()),
            "planar": (_sliced(pipe2(), True), pipe2()), "tee": (_sliced(_tee(), False), _tee())}


@pytest.mark.parametrize("case", ["five-axis", "planar", "tee"])
def test_by_tiles_and_chunks_the_figures_are_those_of_all_samples_at_once(pipe2_files,
                                                                         monkeypatch, case):
    """pipe2 (0.6 M samples) is held whole and searched in one tile, as the check held every
    sample before; cut into tiles and chunks of a few thousand samples it gives the same
    figures, wall layers and unsupported wall samples (so does a tee with such layers)."""
    parsed, mesh = pipe2_files[case]
    whole = replay_check(parsed, mesh)
    monkeypatch.setattr(replay_stream, "HOLD_SAMPLES", 0)
    monkeypatch.setattr(replay_stream, "TILE_SAMPLES", 40_000)
    monkeypatch.setattr(replay_stream, "CHUNK_SAMPLES", 25_000)
    monkeypatch.setattr(replay_passes, "TIP_CHUNK", 20_000)
    monkeypatch.setattr(replay_collide, "CHUNK", 25_000)
    cut = replay_check(parsed, mesh)
    dep = replay._measured(parsed, geometry_from_header(parsed), move_lengths(parsed), 1.0,
                           0.45, 0.2)
    assert len(replay_stream.tiles(dep, 1.5)) > 10 and len(replay_stream.layer_chunks(dep)) > 10
    a, b = whole.to_dict(), cut.to_dict()
    for rep in (a, b):
        for timing in ("seconds", "timings", "cpu_timings"):
            rep.pop(timing)
    assert a == b
    assert np.array_equal(whole.unsupported_walls.p, cut.unsupported_walls.p)
    assert a["wall_supported"] < 1.0  # the figures under comparison are not trivial
    if case == "tee":
        assert a["unsupported_wall_layers"] and a["wall_layers"] and len(whole.unsupported_walls)


def test_the_tiles_own_every_sample_once_and_their_halo_holds_the_searches(pipe2_files,
                                                                          monkeypatch):
    parsed, _ = pipe2_files["five-axis"]
    monkeypatch.setattr(replay_stream, "HOLD_SAMPLES", 0)
    dep = replay._measured(parsed, geometry_from_header(parsed), move_lengths(parsed), 1.0,
                           0.45, 0.2)
    tiles = replay_stream.tiles(dep, 1.5, size=50_000)
    every = dep.samples(0, dep.n)
    owners = np.zeros(dep.n, dtype=int)
    for tile in tiles:
        owners += replay_stream.inside_box(every.p, tile.low, tile.high)
        s, index = dep.in_box(tile.low - 1.5, tile.high + 1.5)
        near = replay_stream.inside_box(every.p, tile.low - 1.5, tile.high + 1.5)
        assert np.array_equal(index, np.flatnonzero(near))  # the whole halo, sampled alike
        assert np.array_equal(s.p, every.p[near]) and np.array_equal(s.seq, every.seq[near])
    assert len(tiles) > 10 and np.all(owners == 1)


@pytest.mark.slow
def test_a_150_cm3_hollow_fitting_is_checked_within_the_budget():
    """The hollow cross (50 mm pipes, 152 cm³) at 0.2 mm: 7 M samples, which the check
    once refused (about 1.8 GiB with its model index). By tiles and chunks its estimate and
    the index fit the 1 GiB budget, and the slice's replay runs to its figures."""
    from slicer.mesh.samples import pipe_cross
    from slicer.pipeline import slice_model
    from slicer.printhead import Printhead

    mesh = pipe_cross()
    assert 140_000 < mesh.volume < 160_000
    res = slice_model(mesh, ProcessSettings(), GEO, Printhead.default(), allow_overhang=True,
                      repair_rounds=0)  # the check's memory, not the closed loop's tries
    rep = res.replay
    # 7.5 M samples before the writer merged short moves (slicer/gcode/merge.py), 7.0 M after
    assert rep["points"] > 6_500_000 and rep["collisions"] == 0
    assert rep["inside"] > 0.99 and rep["coverage"] > 0.95
    parsed = parse_lines(res.lines)
    index = model_index(mesh, ProcessSettings().line_width, np.array(
        parse_lines(res.lines[:4]).headers["PLACEMENT"]["matrix"]))
    _, need = memory_estimate(parsed, move_lengths(parsed), ProcessSettings().line_width)
    assert need + index.nbytes <= replay.MEMORY_BUDGET
