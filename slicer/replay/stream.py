"""A file's deposits sampled a piece at a time, never all at once.

:class:`Deposits` knows, for every extruding move, how many samples it takes (every half line
width, :func:`~slicer.replay.samples.map_and_sample`), where its first one stands in the file's
sample order and the platform-frame z range they span: a few numbers a move, no sample. From
that it samples any range of the file order (:meth:`Deposits.samples`) or every move that
reaches a band of z (:meth:`Deposits.in_band`). A move's samples are computed from that move
alone, element by element, so they are the same numbers whichever moves are sampled with it.

The replay check walks the deposits twice this way (:mod:`.check`):

* by *tiles*, boxes of the platform frame (:func:`tiles`), each with the samples of a *halo*
  around it: the support and coverage searches look for material within a few millimetres
  of a point, so a point's tile and halo hold every sample its search can find, and its
  answer is the one a search among all samples gives. The tiles halve the deposits' box
  along its longest side, where half the samples lie on either side, until a tile with its
  halo holds ``TILE_SAMPLES`` or fewer: a tall part is cut across its height, a wide flat one
  across its width (slabs of z alone would be mostly halo there);
* by *chunks* of whole layers in file order (:func:`layer_chunks`), with the layer before the
  first: the figures per layer, the bridging over the previous layer and the wall distances.

The peak memory is then that of a tile or a chunk (``TILE_SAMPLES``, ``CHUNK_SAMPLES``), plus
a few bytes per sample for the verdicts kept for the whole file and a few dozen per move.

A file of at most ``HOLD_SAMPLES`` samples is sampled once and held (:attr:`Deposits.held`):
the walks then take their pieces of it, and its support and coverage are searched in one
tile. Those are the same samples, so the figures are the same; the file is checked as fast
as when every stage held all of them, which re-sampling every piece made about a third
slower on the sample pipes (0.8 M samples).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kinematics.machine import MachineGeometry
from slicer.gcode import ParsedGcode
from slicer.replay.samples import (
    Samples,
    extruding_moves,
    map_and_sample,
    map_moves,
    sample_counts,
    sample_moves,
)

TILE_SAMPLES = 1 << 19  # samples a tile and its halo hold (about; at least one cell)
HOLD_SAMPLES = 1 << 20  # a file of at most this many samples is sampled once and held
CHUNK_SAMPLES = 1 << 19  # samples of the whole layers of a file-order chunk (about)
MAP_MOVES = 1 << 16  # moves mapped at once while the deposits are measured
MAX_CELLS = 1 << 21  # cells of the sample histogram the tiles are cut from
PAD = 1e-3  # mm: a move's box is widened by this (it is kept in float32)


@dataclass
class Deposits:
    """The extruding moves of a file and where their samples lie, without the samples.

    Attributes
    ----------
    parsed, geometry
        The file and its kinematics.
    bead_area, spacing, h_range
        As :func:`~slicer.replay.samples.map_and_sample` takes them.
    moves : (m,) int
        The extruding moves (file indices).
    start : (m + 1,) int64
        File-order index of each move's first sample; ``start[-1]`` is their number.
    box_low, box_high : (m, 3) float32
        Platform-frame box of each move's samples, widened by ``PAD``.
    h_max : float
        Largest bead height, mm (0 without deposits).
    low, high : (3,) float
        Bounds of every sample and bead centre (widened by ``h_max``), mm.
    held : Samples or None
        Every sample, for a file of at most ``HOLD_SAMPLES`` (else None).
    """

    parsed: ParsedGcode
    geometry: MachineGeometry
    bead_area: float
    spacing: float
    h_range: tuple[float, float]
    angle_step: float
    lengths: tuple[np.ndarray, np.ndarray]
    moves: np.ndarray
    start: np.ndarray
    box_low: np.ndarray
    box_high: np.ndarray
    h_max: float
    low: np.ndarray
    high: np.ndarray
    held: Samples | None = None

    @property
    def n(self) -> int:
        """How many samples the deposits take."""
        return int(self.start[-1])

    @property
    def deposited_mm(self) -> float:
        """Machine-frame length of the extruding moves, mm."""
        return float(self.lengths[0][self.moves].sum())

    def _sample(self, positions: np.ndarray) -> Samples:
        """The samples of the moves at ``positions`` (increasing) of :attr:`moves`."""
        return map_and_sample(self.parsed, self.geometry, self.moves[positions], self.lengths,
                              self.bead_area, self.spacing, self.angle_step, self.h_range)

    def samples(self, lo: int, hi: int) -> Samples:
        """Samples ``lo:hi`` of the file order."""
        if self.held is not None:
            return self.held.take(slice(lo, hi))
        a = int(np.searchsorted(self.start, lo, side="right")) - 1
        b = int(np.searchsorted(self.start, hi, side="left"))
        if hi <= lo:
            return self._sample(np.zeros(0, dtype=np.int64))
        s = self._sample(np.arange(max(a, 0), b))
        first = int(self.start[max(a, 0)])
        return s.take(slice(lo - first, hi - first))

    def in_box(self, low: np.ndarray, high: np.ndarray) -> tuple[Samples, np.ndarray]:
        """Every sample in the box [low, high) (each (3,)), and its file-order index, (k,)."""
        if self.held is not None:
            keep = np.flatnonzero(inside_box(self.held.p, low, high))
            if len(keep) == self.n:  # the one tile of a held file: no copy
                return self.held, keep
            return self.held.take(keep), keep
        pos = np.flatnonzero(np.all((self.box_high >= low - PAD) & (self.box_low < high + PAD),
                                    axis=1))
        s = self._sample(pos)
        count = np.diff(self.start)[pos]
        index = (np.repeat(self.start[pos] - np.cumsum(count) + count, count)
                 + np.arange(int(count.sum())))
        keep = inside_box(s.p, low, high)
        return s.take(keep), index[keep]

    def layer_starts(self) -> tuple[np.ndarray, np.ndarray]:
        """File-order index of each layer's first sample (k,) and its layer in print order
        (``Samples.seq``), (k,); layers follow each other in the file."""
        seq = self.parsed.layer_seq[self.moves]
        first = np.flatnonzero(np.r_[True, seq[1:] != seq[:-1]]) if len(seq) else np.zeros(
            0, dtype=np.int64)
        return self.start[first], seq[first]


def measure(parsed: ParsedGcode, geometry: MachineGeometry,
            lengths: tuple[np.ndarray, np.ndarray], bead_area: float, spacing: float,
            angle_step: float, h_range: tuple[float, float]) -> Deposits:
    """The :class:`Deposits` of ``parsed``: its extruding moves mapped ``MAP_MOVES`` at a
    time (the ends of a move that keeps its angles bound its samples; one that turns the
    table is sampled to find them)."""
    moves = extruding_moves(parsed, lengths)
    count = sample_counts(lengths[0][moves], lengths[1][moves], spacing, angle_step)
    start = np.r_[0, np.cumsum(count)].astype(np.int64)
    box_low, box_high = np.empty((len(moves), 3), np.float32), np.empty((len(moves), 3),
                                                                         np.float32)
    low, high = np.full(3, np.inf), np.full(3, -np.inf)
    h_max = 0.0
    for lo in range(0, len(moves), MAP_MOVES):
        part = slice(lo, lo + MAP_MOVES)
        mapped = map_moves(parsed, geometry, moves[part], lengths, bead_area, h_range)
        a, b = np.minimum(mapped.p0, mapped.p1), np.maximum(mapped.p0, mapped.p1)
        turning = np.flatnonzero(mapped.turn > 0)
        if len(turning):  # the path bends: bounded by its samples
            a[turning], b[turning] = _turning_bounds(parsed, geometry, mapped, turning,
                                                     spacing, angle_step)
        box_low[part], box_high[part] = a - PAD, b + PAD
        if len(a):
            low, high = np.minimum(low, a.min(axis=0)), np.maximum(high, b.max(axis=0))
            h_max = max(h_max, float(mapped.h.max()))
    dep = Deposits(parsed, geometry, bead_area, spacing, h_range, angle_step, lengths, moves,
                   start, box_low, box_high, h_max, low - h_max - PAD, high + h_max + PAD)
    if dep.n <= HOLD_SAMPLES:
        dep.held = dep.samples(0, dep.n)
    return dep


def _turning_bounds(parsed: ParsedGcode, geometry: MachineGeometry, mapped: object,
                    rows: np.ndarray, spacing: float, angle_step: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """(3,)-wise minimum and maximum of the samples of the mapped moves ``rows``, (k, 3)
    each."""
    from slicer.replay.samples import MappedMoves

    assert isinstance(mapped, MappedMoves)
    sub = MappedMoves(*(getattr(mapped, f)[rows] for f in (
        "moves", "start", "end", "length", "turn", "p0", "p1", "u0", "h")))
    s = sample_moves(parsed, geometry, sub, spacing, angle_step)
    count = sample_counts(sub.length, sub.turn, spacing, angle_step)
    first = np.r_[0, np.cumsum(count)[:-1]]
    return np.minimum.reduceat(s.p, first, axis=0), np.maximum.reduceat(s.p, first, axis=0)


def inside_box(p: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """Which points (k, 3) lie in the box [low, high), (k,) bool."""
    return np.all((p >= low) & (p < high), axis=1)


@dataclass(frozen=True)
class Tile:
    """A box [low, high) of the platform frame (its outer faces at ±∞: the tiles own every
    point)."""

    low: np.ndarray
    high: np.ndarray


def tiles(dep: Deposits, halo: float, size: int | None = None) -> list[Tile]:
    """Boxes that cover every sample, each holding with its ``halo`` about ``size``
    (default ``TILE_SAMPLES``) samples or fewer (or one cell of the histogram, whatever it
    holds). The samples are counted on a histogram of cells at least ``halo`` wide, at their
    moves' middles (which balances the tiles; the halo makes them exact)."""
    size = TILE_SAMPLES if size is None else size
    if dep.n == 0 or dep.held is not None:  # held: searched whole
        return [Tile(np.full(3, -math.inf), np.full(3, math.inf))]
    lo = dep.box_low.min(axis=0).astype(float)
    extent = dep.box_high.max(axis=0).astype(float) - lo
    cell = max(halo, float(np.prod(np.maximum(extent, halo)) / MAX_CELLS) ** (1.0 / 3.0))
    dims = np.ceil(extent / cell).astype(np.int64) + 1
    mid = 0.5 * (dep.box_low.astype(float) + dep.box_high.astype(float))
    ijk = np.clip(((mid - lo) / cell).astype(np.int64), 0, dims - 1)
    hist = np.bincount(np.ravel_multi_index(ijk.T, dims), weights=np.diff(dep.start),
                       minlength=int(np.prod(dims))).reshape(dims)
    reach = math.ceil(halo / cell)
    leaves, todo = [], [(np.zeros(3, np.int64), dims)]
    while todo:
        a, b = todo.pop()
        ga, gb = np.maximum(a - reach, 0), np.minimum(b + reach, dims)
        if hist[ga[0]:gb[0], ga[1]:gb[1], ga[2]:gb[2]].sum() <= size or np.all(b - a <= 1):
            leaves.append((a, b))
            continue
        todo += _halves(hist, a, b)
    return [Tile(np.where(a > 0, lo + a * cell, -math.inf),
                 np.where(b < dims, lo + b * cell, math.inf)) for a, b in leaves]


def _halves(hist: np.ndarray, a: np.ndarray, b: np.ndarray
            ) -> list[tuple[np.ndarray, np.ndarray]]:
    """The cell box [a, b) of ``hist`` cut across its longest side where half its samples
    lie on either side (at least one cell each)."""
    axis = int(np.argmax(b - a))
    sub = hist[a[0]:b[0], a[1]:b[1], a[2]:b[2]]
    profile = np.cumsum(sub.sum(axis=tuple(i for i in range(3) if i != axis)))
    k = int(np.searchsorted(profile, 0.5 * profile[-1], side="left")) + 1
    cut = a[axis] + min(max(k, 1), b[axis] - a[axis] - 1)
    b1, a2 = b.copy(), a.copy()
    b1[axis], a2[axis] = cut, cut
    return [(a, b1), (a2, b)]


def layer_chunks(dep: Deposits, size: int | None = None) -> list[tuple[int, int, int]]:
    """File-order chunks of whole layers, of about ``size`` (default ``CHUNK_SAMPLES``)
    samples or one layer: ``(before, first, end)``, the first sample of the layer before the
    chunk (of its first layer when none), of the chunk's first layer, and of the layer after
    its last (``dep.n`` for the last)."""
    size = CHUNK_SAMPLES if size is None else size
    starts, _ = dep.layer_starts()
    ends = np.r_[starts[1:], dep.n] if len(starts) else starts
    out, i = [], 0
    while i < len(starts):
        j = max(int(np.searchsorted(ends, starts[i] + size, side="right")), i + 1)
        out.append((int(starts[i - 1] if i else starts[0]), int(starts[i]), int(ends[j - 1])))
        i = j
    return out
