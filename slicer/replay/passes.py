"""The replay check's walks over the deposits, a slab or a chunk at a time (:mod:`.stream`).

* :func:`support_pass`, by tiles of the platform frame with a halo: the strict support rule
  of every judged sample and the coverage of the model's grid, each searched among the
  samples of its tile and halo (which hold every one within the searches' reach);
* :func:`wall_pass`, by chunks in file order: the wall and inside tests of every judged
  sample (they need nothing of the others: this pass runs beside the support pass);
* :func:`layer_pass`, by chunks of whole layers in file order: the bridging over the
  previous layer, the figures per layer and the unsupported wall layers;
* :func:`collision_pass`: the printed material read a chunk at a time, then the head's
  samples checked against it in chunks of moves.

Every answer is the one a pass over all the samples at once gives (the verdict of a sample
depends on the samples within a reach of it, or on its own layers), so the figures do not
depend on the tile or chunk sizes (``tests/slicer/test_replay_memory.py``).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field, replace

import numpy as np

from kinematics.machine import MachineGeometry
from slicer.gcode import ParsedGcode
from slicer.printhead import Printhead
from slicer.replay.collide import Collision, find_collisions, printed_material
from slicer.replay.coverage import coverage_reach, covered, shell_depth, shell_grid
from slicer.replay.geometry import ModelIndex
from slicer.replay.kdtree import point_tree
from slicer.replay.samples import (
    Samples,
    map_and_sample,
    move_chunks,
    positioned_moves,
    sample_counts,
)
from slicer.replay.stream import CHUNK_SAMPLES, Deposits, inside_box, layer_chunks, tiles
from slicer.replay.support import (
    FOOTPRINT,
    OUTLINE_DEPTH,
    WALL_SLACK,
    LayerSupport,
    bead_axes,
    bridged,
    layer_support,
    max_depth,
    strict_support,
    support_reach,
)
from slicer.replay.walls import WallLayer, WallLayerPoints, WallSamples, wall_layers

BRIDGE_CHUNK = 1 << 16  # bridging candidates whose footprints are tested at once
TIP_CHUNK = 1 << 18  # head samples taken and checked at once
TIP_SPACING = 1.0  # mm between head samples along moves
FAR_TIP_SPACING = 3.0  # mm between samples of the carriage (radius ≥ 15 mm by default)


@dataclass(frozen=True)
class Rules:
    """What the passes take from the file: the process, the platform and the stride.

    Attributes
    ----------
    line_width, layer_height, infill_density : float
        The process (``;HOSTD_PROCESS``).
    perimeters : int
    platform_radius : float
    stride : int
        Every ``stride``-th sample (in file order, from the first) is judged.
    inside_slack : float
        Distance to the surface within which a judged sample counts as inside, mm.
    """

    line_width: float
    layer_height: float
    infill_density: float
    perimeters: int
    platform_radius: float
    stride: int
    inside_slack: float


def support_pass(dep: Deposits, model: ModelIndex, rules: Rules
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The strict support verdict of every judged sample (n_judged,) bool, and the model's
    coverage grid's shell mask and coverage, (g,) bool each."""
    w, t = rules.line_width, rules.layer_height
    depth = max_depth(dep.h_max, t, w)
    halo = max(support_reach(depth, t, w),
               coverage_reach(w, t, rules.infill_density, dep.h_max)) + 1e-6
    ok = np.zeros(-(-dep.n // rules.stride), dtype=bool)
    g, shell = shell_grid(model, shell_depth(rules.perimeters, w))
    cov = np.zeros(len(g), dtype=bool)
    for tile in tiles(dep, halo):
        s, index = dep.in_box(tile.low - halo, tile.high + halo)
        if len(s) == 0:
            continue
        tree = point_tree(s.p)
        judged = np.flatnonzero((index % rules.stride == 0)
                                & inside_box(s.p, tile.low, tile.high))
        ok[index[judged] // rules.stride] = strict_support(
            s, t, w, rules.platform_radius, tree, judged, depth)
        own = inside_box(g, tile.low, tile.high)
        cov[own] = covered(g[own], shell[own], s, tree, w, t, rules.infill_density, dep.h_max)
    return ok, shell, cov


def wall_pass(dep: Deposits, model: ModelIndex, rules: Rules) -> tuple[np.ndarray, int]:
    """Which judged samples lie on the model's walls (n_judged,) bool, and how many lie
    inside it (or within the inside slack of its surface)."""
    stride = rules.stride
    wall = np.zeros(-(-dep.n // stride), dtype=bool)
    inside = 0
    for lo in range(0, len(wall), CHUNK_SAMPLES):  # judged samples lo:hi
        hi = min(lo + CHUNK_SAMPLES, len(wall))
        s = dep.samples(lo * stride, (hi - 1) * stride + 1)
        p = s.p[::stride]
        bound, wall[lo:hi] = _wall(model, p, rules.line_width)
        inside += int(_inside(model, p, bound, rules.inside_slack).sum())
    return wall, inside


@dataclass
class LayerFigures:
    """What :func:`layer_pass` counts and gathers.

    Attributes
    ----------
    judged, supported, bridged, wall, wall_supported : int
        Judged samples; those supported (strictly or bridging), bridging only, on the
        model's walls, and the walls' held (strictly or bridging sparse infill, which issue 8
        does not count as an overhang).
    layers : LayerSupport
        Every printed layer's unsupported extrusion.
    over_air : list of WallLayer
        The wall layers over air (bridging counted as support), in print order.
    samples : WallSamples
        The unsupported wall samples of the layers over air.
    """

    judged: int = 0
    supported: int = 0
    bridged: int = 0
    wall: int = 0
    wall_supported: int = 0
    layers: LayerSupport = field(default_factory=lambda: LayerSupport.joined([]))
    over_air: list[WallLayer] = field(default_factory=list)
    samples: WallSamples = field(default_factory=WallSamples.empty)


def layer_pass(dep: Deposits, model: ModelIndex, ok: np.ndarray, walls: np.ndarray,
               rules: Rules, to_part: np.ndarray | None) -> LayerFigures:
    """The per-layer figures of the deposits, chunk after chunk of whole layers.

    ``ok`` and ``walls`` (n_judged,) are the judged samples' strict support verdicts
    (:func:`support_pass`) and wall masks (:func:`wall_pass`); ``to_part`` moves
    platform-frame points into the part's frame (the wall layers' points).
    """
    out = LayerFigures()
    per_layer, samples = [], []
    stride = rules.stride
    for before, first, end in layer_chunks(dep):
        j0 = -(-first // stride) * stride
        if j0 >= end:
            continue  # no judged sample in these layers
        j1 = min(-(-end // stride) * stride, dep.n)  # the last judged one's piece ends here
        s = dep.samples(before, j1)
        judged = np.arange(j0, end, stride) - before
        rows = slice(j0 // stride, j0 // stride + len(judged))
        ok_c, wall = ok[rows], walls[rows]
        bridge = _bridging(model, s, judged, ok_c, rules)
        good = ok_c | bridge
        out.judged += len(judged)
        out.supported += int(good.sum())
        out.bridged += int((bridge & ~ok_c).sum())
        out.wall += int(wall.sum())
        out.wall_supported += int(good[wall].sum())
        per_layer.append(layer_support(s, judged, good, rules.line_width))
        points = WallLayerPoints(s.p[judged], s.seq[judged], s.subpart[judged],
                                 s.layer[judged], wall, ok_c)
        air, air_samples = wall_layers(replace(points, supported=good), to_part)
        out.over_air += air
        samples.append(WallSamples.joined([air_samples]))  # thinned as it goes
    out.layers = LayerSupport.joined(per_layer)
    out.samples = WallSamples.joined(samples)
    return out


def _wall(model: ModelIndex, points: np.ndarray, line_width: float
          ) -> tuple[np.ndarray, np.ndarray]:
    """(:meth:`~ModelIndex.nearest_bound`, wall mask) of points (n, 3): walls lie within
    ``WALL_SLACK`` line widths of the surface."""
    bound = model.nearest_bound(points, WALL_SLACK * line_width)
    return bound, model.within(points, WALL_SLACK * line_width, bound)


def _inside(model: ModelIndex, points: np.ndarray, bound: np.ndarray, slack: float
            ) -> np.ndarray:
    """Which points (n, 3) lie inside the model or within ``slack`` of its surface, (n,).

    ``bound`` is the points' :meth:`~ModelIndex.nearest_bound`. The column test is exact
    for points farther than ``model.inside_pitch / √2`` from the surface; with that below
    ``slack`` every closer point counts through the slack, so no ray is cast, and only the
    points the column test puts outside need their distance to the surface.
    """
    if len(points) == 0:
        return np.zeros(0, dtype=bool)
    if model.inside_pitch / math.sqrt(2.0) > slack:
        near = np.isfinite(model.distance(points, slack, bound))
        return model.inside(points) | near
    ok = model.parity_inside(points)
    out = np.flatnonzero(~ok)
    ok[out] = np.isfinite(model.distance(points[out], slack, bound[out]))
    return ok


def _bridging(model: ModelIndex, s: Samples, judged: np.ndarray, ok: np.ndarray,
              rules: Rules) -> np.ndarray:
    """Which judged samples (indices ``judged`` of ``s``, verdicts ``ok``) are unsupported
    over the previous layer's outline and bridge sparse infill
    (:func:`~slicer.replay.support.bridged`), (m,) bool; ``s`` holds the layer before the
    first judged one's.

    Over the outline: the bead's footprint at the previous layer's mid-height beneath the
    sample (``OUTLINE_DEPTH`` bead heights down its axis), its centre and the points
    ``FOOTPRINT`` widths from it along and across the bead, lies inside the model, exactly
    (no slack: under a ledge printed in thin layers that point lies a fraction of a layer
    below the ledge's underside). The points are offset across the axis only, so the
    part's top, however near, takes no part.
    """
    cand = ~ok
    idx = judged[cand]
    over = np.zeros(len(idx), dtype=bool)
    r = FOOTPRINT * rules.line_width
    for lo in range(0, len(idx), BRIDGE_CHUNK):  # (5 · chunk, 3) footprints at a time
        j = idx[lo:lo + BRIDGE_CHUNK]
        below = s.p[j] - OUTLINE_DEPTH * s.h[j, None] * s.u[j]
        along, across = bead_axes(s.u[j], s.step[j])
        points = np.concatenate([below, below + r * along, below - r * along,
                                 below + r * across, below - r * across])
        over[lo:lo + len(j)] = model.inside(points).reshape(5, len(j)).all(axis=0)
    cand[cand] = over
    mask = np.zeros(len(s), dtype=bool)
    mask[judged[cand]] = True
    return bridged(s, mask, rules.layer_height, rules.line_width,
                   rules.infill_density)[judged]


def collision_pass(parsed: ParsedGcode, dep: Deposits, geometry: MachineGeometry,
                   lengths: tuple[np.ndarray, np.ndarray], bead_area: float, head: Printhead,
                   platform_radius: float, angle_step: float) -> tuple[int, list[Collision]]:
    """Head collisions of the file (:func:`~slicer.replay.collide.find_collisions`): the
    printed material read from ``dep``, the head's samples taken ``TIP_CHUNK`` at a time."""
    material = printed_material(dep.n, dep.samples, (dep.low, dep.high))
    tips = _tip_chunks(parsed, geometry, lengths, bead_area, angle_step)
    return find_collisions(parsed, tips, material, head, platform_radius)


def _tip_chunks(parsed: ParsedGcode, geometry: MachineGeometry,
                lengths: tuple[np.ndarray, np.ndarray], bead_area: float, angle_step: float
                ) -> Iterator[tuple[Samples, Samples]]:
    """The head sampled along every positioned move, in chunks of moves in file order: the
    near samples (every ``TIP_SPACING``, for the nozzle) and the far ones (every
    ``FAR_TIP_SPACING``, for the carriage) of each chunk."""
    moves = positioned_moves(parsed, lengths)
    length, turn = lengths[0][moves], lengths[1][moves]
    count = (sample_counts(length, turn, TIP_SPACING, angle_step)
             + sample_counts(length, turn, FAR_TIP_SPACING, angle_step))
    for lo, hi in move_chunks(np.cumsum(count), TIP_CHUNK):
        near, far = (map_and_sample(parsed, geometry, moves[lo:hi], lengths, bead_area, step,
                                    angle_step, ends=True, beads=False)
                     for step in (TIP_SPACING, FAR_TIP_SPACING))
        yield near, far
