"""Moves of a parsed file as platform-frame samples: deposited beads and nozzle tip positions.

The firmware interpolates all joints linearly, so a sample at fraction s of a move is the
joint pose ``start + s (end - start)`` mapped back through the inverse kinematics: exact for
any move, including those that turn the table.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from kinematics.machine import MachineGeometry
from slicer.gcode import GcodeFormatError, ParsedGcode
from slicer.gcode.markers import KINEMATICS

CHUNK_SAMPLES = 1 << 18  # samples computed at once (their temporaries stay bounded)


@dataclass
class Samples:
    """Points along moves in the platform frame.

    Attributes
    ----------
    p : (n, 3) float
        Nozzle tip positions, mm.
    u : (n, 3) float
        Nozzle axis (machine +Z) in the platform frame, unit.
    h : (n,) float
        Local bead height from the extruded filament (0 for travel), mm.
    step : (n, 3) float
        Vector to the next sample on the same move: a sample stands for the bead centreline
        ``p + τ · step``, ``|τ| ≤ 1/2`` (the chord, on moves that turn the table).
    move : (n,) int32
        Index of the move each sample lies on.
    seq, subpart, layer : (n,) int32
        Layer in print order, sub-part and layer index of that move.
    """

    p: np.ndarray
    u: np.ndarray
    h: np.ndarray
    step: np.ndarray
    move: np.ndarray
    seq: np.ndarray
    subpart: np.ndarray
    layer: np.ndarray

    def __len__(self) -> int:
        return len(self.p)

    def take(self, mask: np.ndarray | slice) -> Samples:
        """The samples where ``mask`` holds (or those of a slice: views)."""
        return Samples(self.p[mask], self.u[mask], self.h[mask], self.step[mask],
                       self.move[mask],
                       self.seq[mask], self.subpart[mask], self.layer[mask])


def geometry_from_header(parsed: ParsedGcode) -> MachineGeometry:
    """The machine geometry of ``;HOSTD_KINEMATICS``."""
    kin = parsed.require(KINEMATICS)
    if kin.get("type") != "xyzac-trt":
        raise GcodeFormatError(f"unsupported kinematics type {kin.get('type')!r}")
    try:
        c_lim = kin.get("c_limits")
        return MachineGeometry(_point(kin["table_origin"]), _point(kin["a_pivot"]),
                               _limits(kin.get("a_limits", (-90.0, 90.0))),
                               None if c_lim is None else _limits(c_lim))
    except (KeyError, TypeError, ValueError) as exc:
        raise GcodeFormatError(f";HOSTD_KINEMATICS: bad or missing key {exc}") from None


def _point(value: Iterable[Any]) -> tuple[float, float, float]:
    """Three numbers as floats (ValueError for another count)."""
    x, y, z = map(float, value)
    return x, y, z


def _limits(value: Iterable[Any]) -> tuple[float, float]:
    """``[min, max]`` as floats (ValueError for another count)."""
    lo, hi = map(float, value)
    return lo, hi


def nozzle_axes(a: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Machine +Z in the platform frame for table angles (degrees), (n, 3).

    The last row of ``Rx(A) · Rz(C)`` (:func:`kinematics.transform.table_rotation`):
    ``(sin A sin C, sin A cos C, cos A)``.
    """
    ar, cr = np.radians(a), np.radians(c)
    sa = np.sin(ar)
    return np.column_stack([sa * np.sin(cr), sa * np.cos(cr), np.cos(ar)])


def inverse(m: np.ndarray, a: np.ndarray, c: np.ndarray, geometry: MachineGeometry
            ) -> np.ndarray:
    """Platform-frame points under machine positions ``m`` (n, 3) at angles A, C (degrees).

    :func:`kinematics.transform.inverse` in closed form, ``p = Rz(-C) (Rx(-A) (m - q) + q -
    t)``, without building rotation matrices.
    """
    ar, cr = np.radians(a), np.radians(c)
    sa, ca, sc, cc = np.sin(ar), np.cos(ar), np.sin(cr), np.cos(cr)
    q, t = np.asarray(geometry.q, dtype=float), np.asarray(geometry.t, dtype=float)
    v = m - q
    x = v[:, 0] + (q[0] - t[0])
    y = ca * v[:, 1] + sa * v[:, 2] + (q[1] - t[1])
    z = ca * v[:, 2] - sa * v[:, 1] + (q[2] - t[2])
    return np.column_stack([cc * x + sc * y, cc * y - sc * x, z])


def _fractions(count: np.ndarray, ends: bool) -> tuple[np.ndarray, np.ndarray]:
    """Owner index and fraction (k + 0.5) / count (or (k + 1) / count with ``ends``)."""
    owner = np.repeat(np.arange(len(count)), count)
    k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    return owner, (k + (1.0 if ends else 0.5)) / count[owner]


def move_lengths(parsed: ParsedGcode) -> tuple[np.ndarray, np.ndarray]:
    """Machine-frame XYZ length and largest A/C change of every move (unknown start → 0)."""
    delta = parsed.end - parsed.start
    delta[np.isnan(delta)] = 0.0
    xyz = delta[:, :3]
    return np.sqrt(np.einsum("ij,ij->i", xyz, xyz)), np.abs(delta[:, 3:5]).max(axis=1)


@dataclass
class MappedMoves:
    """Some moves with their ends mapped into the platform frame, ready to be sampled.

    Attributes
    ----------
    moves : (m,) int
        Indices of the moves in the file.
    start, end : (m, 5) float
        Joint poses [X, Y, Z, A, C] before and after each move.
    length, turn : (m,) float
        Machine-frame XYZ length and largest A/C change, mm and degrees.
    p0, p1 : (m, 3) float
        Tip at the start and end of each move in the platform frame.
    u0 : (m, 3) float
        Nozzle axis at the start of each move.
    h : (m,) float
        Bead height from the extruded filament (0 for travel), mm.
    """

    moves: np.ndarray
    start: np.ndarray
    end: np.ndarray
    length: np.ndarray
    turn: np.ndarray
    p0: np.ndarray
    p1: np.ndarray
    u0: np.ndarray
    h: np.ndarray


def map_moves(parsed: ParsedGcode, geometry: MachineGeometry, moves: np.ndarray,
              lengths: tuple[np.ndarray, np.ndarray], bead_area: float,
              h_range: tuple[float, float] | None = None) -> MappedMoves:
    """Map the ends of ``moves`` (indices) back to the platform frame.

    ``lengths`` is :func:`move_lengths` of the file. ``bead_area`` is filament area / line
    width: bead height = E · bead_area / length. ``h_range`` clips bead heights: a file does
    not record bead widths, so a narrow bead reads as a thin one.
    """
    length, turn = lengths[0][moves], lengths[1][moves]
    start, end = parsed.start[moves], parsed.end[moves]
    # fixed angles make the inverse affine: map the move ends once and interpolate
    p0 = inverse(start[:, :3], start[:, 3], start[:, 4], geometry)
    p1 = inverse(end[:, :3], end[:, 3], end[:, 4], geometry)
    safe_len = np.where(length > 0, length, math.inf)
    h = np.maximum(parsed.e[moves], 0.0) * bead_area / safe_len
    if h_range is not None:
        h = np.where(h > 0, np.clip(h, *h_range), 0.0)
    return MappedMoves(moves, start, end, length, turn, p0, p1,
                       nozzle_axes(start[:, 3], start[:, 4]), h)


def sample_moves(parsed: ParsedGcode, geometry: MachineGeometry, mapped: MappedMoves,
                 spacing: float, angle_step: float, ends: bool = False, beads: bool = True
                 ) -> Samples:
    """Samples along the ``mapped`` moves at most ``spacing`` mm and ``angle_step``° apart.

    Samples sit at the middles of equal pieces, or at their ends (move end included) with
    ``ends``. Samples of moves that turn the table go through the inverse kinematics each.
    Without ``beads`` (head samples) ``h`` and ``step`` are read-only zeros of no memory.
    The move and layer numbers are int32.
    """
    count = sample_counts(mapped.length, mapped.turn, spacing, angle_step)
    out = _empty_samples(int(count.sum()), beads)
    ends_at = np.cumsum(count)
    for lo, hi in move_chunks(ends_at):  # the temporaries of a chunk stay bounded
        rows = slice(int(ends_at[lo] - count[lo]), int(ends_at[hi - 1]))
        _sample_chunk(parsed, geometry, mapped, slice(lo, hi), count[lo:hi], ends, out, rows)
    return out


def map_and_sample(parsed: ParsedGcode, geometry: MachineGeometry, moves: np.ndarray,
                   lengths: tuple[np.ndarray, np.ndarray], bead_area: float, spacing: float,
                   angle_step: float, h_range: tuple[float, float] | None = None,
                   ends: bool = False, beads: bool = True) -> Samples:
    """``sample_moves(parsed, geometry, map_moves(parsed, geometry, moves, lengths,
    bead_area, h_range), spacing, angle_step, ends, beads)``, the same samples, mapping
    the moves (m,) a chunk at a time: the mapped moves' arrays (about 250 bytes a move
    with their temporaries) never exist for all moves at once."""
    count = sample_counts(lengths[0][moves], lengths[1][moves], spacing, angle_step)
    out = _empty_samples(int(count.sum()), beads)
    ends_at = np.cumsum(count)
    for lo, hi in move_chunks(ends_at):
        rows = slice(int(ends_at[lo] - count[lo]), int(ends_at[hi - 1]))
        mapped = map_moves(parsed, geometry, moves[lo:hi], lengths, bead_area, h_range)
        _sample_chunk(parsed, geometry, mapped, slice(0, hi - lo), count[lo:hi], ends, out,
                      rows)
    return out


def sample_counts(length: np.ndarray, turn: np.ndarray, spacing: float, angle_step: float
                  ) -> np.ndarray:
    """Samples per move of XYZ ``length`` and A/C ``turn`` (m,), int64 (m,)."""
    count = np.maximum(1, np.ceil(np.maximum(length / spacing, turn / angle_step)))
    return count.astype(np.int64)


def _empty_samples(n: int, beads: bool) -> Samples:
    """Room for ``n`` samples; without ``beads``, ``h`` and ``step`` are read-only zeros."""
    return Samples(np.empty((n, 3)), np.empty((n, 3)),
                   np.empty(n) if beads else np.broadcast_to(0.0, (n,)),
                   np.empty((n, 3)) if beads else np.broadcast_to(0.0, (n, 3)),
                   np.empty(n, np.int32), np.empty(n, np.int32), np.empty(n, np.int32),
                   np.empty(n, np.int32))


def move_chunks(ends_at: np.ndarray, size: int | None = None) -> list[tuple[int, int]]:
    """Consecutive move ranges [lo, hi) of about ``size`` (default ``CHUNK_SAMPLES``)
    samples each (at least one move); ``ends_at`` (m,) is the cumulative sample count."""
    size = CHUNK_SAMPLES if size is None else size
    out, lo = [], 0
    while lo < len(ends_at):
        start = ends_at[lo - 1] if lo else 0
        hi = max(int(np.searchsorted(ends_at, start + size, side="right")), lo + 1)
        out.append((lo, hi))
        lo = hi
    return out


def _sample_chunk(parsed: ParsedGcode, geometry: MachineGeometry, mapped: MappedMoves,
                  moves: slice, count: np.ndarray, ends: bool, out: Samples, rows: slice
                  ) -> None:
    """Fill ``out[rows]`` with the samples of ``mapped``'s ``moves`` (``count`` (k,) each)."""
    owner, s = _fractions(count, ends)
    owner += moves.start
    mv = mapped
    p = mv.p0[owner] + (mv.p1 - mv.p0)[owner] * s[:, None]
    u = mv.u0[owner]
    turning = np.flatnonzero(mv.turn[owner] > 0)
    if len(turning):
        o = owner[turning]
        j = mv.start[o] + (mv.end[o] - mv.start[o]) * s[turning, None]
        p[turning] = inverse(j[:, :3], j[:, 3], j[:, 4], geometry)
        u[turning] = nozzle_axes(j[:, 3], j[:, 4])
    out.p[rows], out.u[rows] = p, u
    m = mv.moves[owner]
    out.move[rows] = m
    if out.h.flags.writeable:
        out.h[rows] = mv.h[owner]
        out.step[rows] = ((mv.p1[moves] - mv.p0[moves]) / count[:, None])[owner - moves.start]
    out.seq[rows], out.subpart[rows] = parsed.layer_seq[m], parsed.subpart[m]
    out.layer[rows] = parsed.layer[m]


def sample_count(length: np.ndarray, turn: np.ndarray, spacing: float, angle_step: float
                 ) -> int:
    """How many samples :func:`sample_moves` takes of moves of XYZ ``length`` and A/C
    ``turn`` (both (m,)), without taking them."""
    return int(sample_counts(length, turn, spacing, angle_step).sum())


def extruding_moves(parsed: ParsedGcode, lengths: tuple[np.ndarray, np.ndarray] | None = None
                    ) -> np.ndarray:
    """Indices of moves that deposit material (E > 0 while X/Y/Z move from a known pose).

    ``lengths`` is :func:`move_lengths` of the file (computed when not given).
    """
    length, _ = lengths or move_lengths(parsed)
    known = np.isfinite(parsed.start).all(axis=1)
    return np.flatnonzero((parsed.e > 0) & (length > 1e-9) & known)


def positioned_moves(parsed: ParsedGcode, lengths: tuple[np.ndarray, np.ndarray] | None = None
                     ) -> np.ndarray:
    """Indices of all moves from a known pose that move X/Y/Z or turn the table.

    ``lengths`` is :func:`move_lengths` of the file (computed when not given).
    """
    length, turn = lengths or move_lengths(parsed)
    known = np.isfinite(parsed.start).all(axis=1) & np.isfinite(parsed.end).all(axis=1)
    return np.flatnonzero(known & ((length > 1e-9) | (turn > 1e-9)))
