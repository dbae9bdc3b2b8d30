"""Fewer, longer moves: the merged path stays within the linearisation tolerance."""

from __future__ import annotations

import math
from itertools import pairwise

import numpy as np
import pytest

from kinematics.machine import MachineGeometry
from slicer.gcode.extrusions import Extrusions
from slicer.gcode.merge import kept_vertices, merged_filament
from slicer.gcode.reader import parse_lines
from slicer.gcode.writer import MachineSetup, filament_area, generate
from slicer.plan import Layer, Path, PrintPlan, SubpartPlan
from slicer.replay.check import part_frame_path
from slicer.settings import ProcessSettings

TOL = 0.01
SETTINGS = ProcessSettings(linearize_tolerance=TOL)
H, W = 0.2, 0.45


def _misses(points: np.ndarray, e: np.ndarray, keep: np.ndarray) -> tuple[float, float]:
    """Largest distance of a vertex from the kept move over it, and largest shift (mm along
    that move) of the filament laid up to it; one path."""
    cum = np.cumsum(e)
    idx = np.flatnonzero(keep)
    worst = shift = 0.0
    for a, b in pairwise(idx):
        ab = points[b] - points[a]
        length = float(np.linalg.norm(ab))
        for i in range(a + 1, b):
            t = min(1.0, max(0.0, float(np.dot(points[i] - points[a], ab)) / length ** 2))
            worst = max(worst, float(np.linalg.norm(points[i] - points[a] - t * ab)))
            laid = cum[b] - cum[a]
            shift = max(shift, abs(cum[i] - cum[a] - t * laid) * length / laid)
    return worst, shift


def _arc(n: int, radius: float, turns: float = 1.0) -> np.ndarray:
    t = np.linspace(0.0, 2 * math.pi * turns, n)
    return np.column_stack([radius * np.cos(t), radius * np.sin(t), np.full(n, H)])


def test_a_finely_faceted_circle_merges_to_fewer_moves_within_the_tolerance():
    pts = _arc(2000, 10.0)
    ext = Extrusions.of([Path("perimeter", pts, np.linspace(0.15, 0.25, len(pts)), W, 30.0)],
                        filament_area(SETTINGS))
    keep = kept_vertices(ext.points, ext.e, ext.start, TOL)
    assert keep[0] and keep[-1]
    assert keep.sum() < len(pts) / 5
    distance, shift = _misses(ext.points, ext.e, keep)
    assert distance <= TOL and shift <= TOL
    e = merged_filament(ext.e, keep)
    assert e.sum() == pytest.approx(ext.e.sum(), rel=1e-12)
    assert not e[~keep].any()


@pytest.mark.parametrize("seed", range(5))
def test_random_paths_keep_every_vertex_a_move_would_miss(seed):
    rng = np.random.default_rng(seed)
    paths = [Path("infill", np.cumsum(rng.normal(0.0, 0.05, (int(n), 3)), axis=0),
                  rng.uniform(0.1, 0.3, int(n)), W, 40.0)
             for n in rng.integers(1, 300, 6)]
    ext = Extrusions.of(paths, 2.405)
    keep = kept_vertices(ext.points, ext.e, ext.start, TOL)
    for s, t in zip(ext.start[:-1], ext.start[1:], strict=True):
        assert keep[s] and keep[t - 1]
        distance, shift = _misses(ext.points[s:t], ext.e[s:t], keep[s:t])
        assert distance <= TOL + 1e-12 and shift <= TOL + 1e-9
    assert 0 < keep.sum() < len(keep)
    assert merged_filament(ext.e, keep).sum() == pytest.approx(ext.e.sum(), rel=1e-12)


def test_a_corner_beyond_the_tolerance_is_kept_one_within_it_is_not():
    pts = np.array([[0.0, 0.0, H], [5.0, 2 * TOL, H], [10.0, 0.0, H], [15.0, 0.5 * TOL, H],
                    [20.0, 0.0, H]])
    ext = Extrusions.of([Path("infill", pts, np.full(len(pts), H), W, 40.0)], 2.405)
    assert kept_vertices(ext.points, ext.e, ext.start, TOL).tolist() == [
        True, True, True, False, True]


def test_a_thickness_step_keeps_the_vertex_where_the_filament_rate_changes():
    pts = np.column_stack([np.linspace(0.0, 10.0, 11), np.zeros(11), np.full(11, H)])
    height = np.where(np.arange(11) < 5, 0.1, 0.3)  # a straight line, thin then thick
    ext = Extrusions.of([Path("infill", pts, height, W, 40.0)], 2.405)
    keep = kept_vertices(ext.points, ext.e, ext.start, TOL)
    assert 0 < keep[1:-1].sum() < 9  # straight, but the filament must not slide along it
    assert _misses(ext.points, ext.e, keep)[1] <= TOL


def test_the_written_file_follows_a_tilted_fine_path_within_the_tolerance():
    geometry = MachineGeometry()
    pts = _arc(1500, 8.0)
    pts[:, 2] += 3.0
    path = Path("perimeter", pts, np.full(len(pts), H), W, 30.0)
    layer = Layer(0, 0, np.zeros(3), np.array([0.0, 0.0, 1.0]), 30.0, 40.0, (H, H), [path])
    plan = PrintPlan(np.eye(4), [SubpartPlan(0, None, None, None, np.array([0, 0, 1.0]),
                                             [layer])])
    parsed = parse_lines(generate(plan, SETTINGS, MachineSetup(geometry)).lines)
    written = part_frame_path(parsed)  # the extruding moves' end points, part frame
    assert len(written) < len(pts) / 5
    written = np.vstack([pts[:1], written])  # the path's start, reached by a travel
    # every planned vertex lies within the tolerance (and the printed rounding) of a move
    a, b = written[:-1], written[1:]
    ab = b - a
    t = np.clip(np.einsum("pij,ij->pi", pts[:, None] - a, ab) / (ab * ab).sum(1), 0.0, 1.0)
    gap = np.linalg.norm(pts[:, None] - (a + t[..., None] * ab), axis=2).min(axis=1)
    assert gap.max() <= TOL + 2e-3
    moved = np.abs(np.nan_to_num(parsed.end - parsed.start)).max(axis=1) > 0
    extruded = parsed.e[(parsed.e > 0) & moved]
    want = Extrusions.of([path], filament_area(SETTINGS)).e.sum()
    assert extruded.sum() == pytest.approx(want, abs=1e-5 * len(extruded))  # E to 5 places
