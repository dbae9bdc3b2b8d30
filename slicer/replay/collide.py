"""Head collisions of a replayed file: with material printed before, and with the platform.

Tips are sampled along every positioned move (≤ ``spacing`` mm, ≤ ``angle_step``° apart, move
ends included). Printed material is the set of deposited bead centres (tip − h/2 along the
axis) laid by the moves before the tip's move: material of the current layer lies below the
tip, and nothing later is there yet. A tip collides when a bead centre lies inside the head
(:class:`~slicer.printhead.Printhead`) placed there, or when the lowest point of the head
dips below the platform plane (z = 0) within the platform radius.

Tips are grouped by nozzle axis; in each group only material above the lowest tip and below
the highest tip plus the head height can matter, which is usually none. Tips of moves that
turn the table each have an axis of their own: those are checked one by one against the beads
in a ball around the head (:mod:`.tip_hits`). A colliding tip reports the earliest bead
it hits.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from slicer.gcode import ParsedGcode
from slicer.printhead import Printhead
from slicer.replay.kdtree import point_tree
from slicer.replay.samples import Samples
from slicer.replay.tip_hits import HeadPart, ball_hits, earliest_hits

PLATFORM_TOL = 1e-3  # mm below z = 0 that still counts as touching, not entering
MAX_REPORTS = 20
NEAR_PITCH = 0.5  # mm: bead resolution for the nozzle cone
FAR_PITCH = 4 * NEAR_PITCH  # mm: bead resolution for the carriage (nests in NEAR_PITCH)
SMALL_GROUP = 16  # tips of one axis checked by ball queries rather than as a group
CHUNK = 1 << 20  # beads mapped to voxels at once


@dataclass(frozen=True)
class Collision:
    """One colliding tip: where (file line, sub-part, layer) and what it hits."""

    line: int
    subpart: int
    layer: int
    obstacle: str  # "printed part" or "platform"
    obstacle_subpart: int
    obstacle_layer: int
    in_transition: bool

    def message(self) -> str:
        """One line naming the sub-part, the layer and the obstacle."""
        where = (f"sub-part {self.subpart}, transition" if self.in_transition or self.layer < 0
                 else f"sub-part {self.subpart}, layer {self.layer}")
        what = "the platform" if self.obstacle == "platform" else (
            f"the printed part (sub-part {self.obstacle_subpart}, layer {self.obstacle_layer})")
        return f"line {self.line}: {where}: the head hits {what}"


def platform_hits(tips: Samples, head: Printhead, radius: float) -> np.ndarray:
    """Tips where some part of the head goes below z = 0 over the platform, (n,) bool."""
    u, z = tips.u, tips.p[:, 2]
    # down: the unit vector across the axis towards +z, (e_z − u_z u) / √(1 − u_z²); its z
    # is √(1 − u_z²), so the lowest points are found from z and u_z alone
    sin = np.sqrt(np.maximum(1.0 - u[:, 2] ** 2, 0.0))
    hit = np.zeros(len(tips), dtype=bool)
    for s, _, r0, r1 in head.segments:
        for hgt, r in ((s, r0), (_, r1)):
            low = np.flatnonzero(z + hgt * u[:, 2] - r * np.where(sin > 1e-12, sin, 0.0)
                                 < -PLATFORM_TOL)
            uz, su = u[low, 2:3], sin[low, None]
            down = np.where(su > 1e-12, -uz * u[low, :2] / np.where(su > 1e-12, su, 1.0), 0.0)
            xy = tips.p[low, :2] + hgt * u[low, :2] - r * down
            hit[low] |= np.linalg.norm(xy, axis=1) <= radius
    return hit


def _frame(u: np.ndarray) -> np.ndarray:
    ref = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(u, ref)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(u, e1)])


def voxel_representatives(beads: np.ndarray, pitch: float) -> np.ndarray:
    """Index of the first bead in each occupied voxel of ``pitch``, ascending, (k,).

    With the beads (n, 3) in print order, that is the earliest one. Voxels of a pitch that
    is a power of two times this one nest exactly (the scalings are exact), so the first
    beads of a coarser grid are found among this grid's representatives.
    """
    return first_in_voxels(len(beads), lambda lo, hi: beads[lo:hi], pitch,
                           (beads.min(axis=0), beads.max(axis=0)) if len(beads) else None)


def first_in_voxels(n: int, points: Callable[[int, int], np.ndarray], pitch: float,
                    bounds: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
    """:func:`voxel_representatives` of ``n`` points handed over ``CHUNK`` at a time.

    ``points(lo, hi)`` gives points ``lo:hi`` (hi − lo, 3) and ``bounds`` their (3,) minimum
    and maximum (floor is monotonic, so the voxels' bounds follow). A voxel's first point is
    the first of the first chunk that holds it, so the answer is the whole array's.
    """
    if n == 0 or bounds is None:
        return np.zeros(0, dtype=int)
    low = np.floor(bounds[0] / pitch).astype(np.int64)
    dims = np.floor(bounds[1] / pitch).astype(np.int64) - low + 1
    seen = np.zeros(0, dtype=np.int64)
    out = []
    for lo in range(0, n, CHUNK):
        cell = np.floor(points(lo, min(lo + CHUNK, n)) / pitch).astype(np.int64)
        cell -= low
        key = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]
        del cell
        key, first = np.unique(key, return_index=True)
        if len(seen):
            at = np.minimum(np.searchsorted(seen, key), len(seen) - 1)
            new = seen[at] != key
            key, first = key[new], first[new]
            seen = np.sort(np.concatenate([seen, key]))
        else:
            seen = key
        out.append(np.sort(first) + lo)
    return np.concatenate(out)


def bead_centres(deposits: Samples, lo: int = 0, hi: int | None = None) -> np.ndarray:
    """Centres of the beads of deposits ``lo:hi`` (tip − h/2 along the axis), (k, 3)."""
    sl = slice(lo, len(deposits) if hi is None else hi)
    return deposits.p[sl] - deposits.u[sl] * (deposits.h[sl, None] / 2.0)


def _centres_at(deposits: Samples, idx: np.ndarray) -> np.ndarray:
    """:func:`bead_centres` of the deposits ``idx`` (k,), (k, 3)."""
    return deposits.p[idx] - deposits.u[idx] * (deposits.h[idx, None] / 2.0)


def _bead_bounds(deposits: Samples) -> tuple[np.ndarray, np.ndarray] | None:
    """(3,) minimum and maximum of the bead centres, by chunks."""
    if len(deposits) == 0:
        return None
    lows, highs = [], []
    for lo in range(0, len(deposits), CHUNK):
        b = bead_centres(deposits, lo, lo + CHUNK)
        lows.append(b.min(axis=0))
        highs.append(b.max(axis=0))
    return np.min(lows, axis=0), np.max(highs, axis=0)


def _group_hits(tips: Samples, sel: np.ndarray, beads: np.ndarray, bead_move: np.ndarray,
                part: HeadPart) -> tuple[np.ndarray, np.ndarray]:
    """(tip index, bead index) of the earliest hit of each colliding tip in one axis group.

    Beads are in print order (``bead_move`` non-decreasing). A tip can only hit beads laid
    by earlier moves that lie above it: the running maximum of bead height along the axis
    rules out almost every tip at once; the rest are checked one layer at a time.
    """
    u = tips.u[sel[0]]
    end = np.searchsorted(bead_move, tips.move[sel], side="left")
    hz_o = beads[:int(end.max())] @ u  # later beads are never in a tip's way
    top = np.maximum.accumulate(hz_o) if len(hz_o) else hz_o
    hz_t = tips.p[sel] @ u
    risky = (end > 0) & (hz_t + part.bottom < top[np.maximum(end, 1) - 1])
    out_t, out_o = [np.zeros(0, dtype=int)], [np.zeros(0, dtype=int)]
    frame = _frame(u)
    idx = np.flatnonzero(risky)
    if len(idx) == 0:
        return out_t[0], out_o[0]
    idx = idx[np.argsort(tips.seq[sel[idx]], kind="stable")]
    seqs = tips.seq[sel[idx]]
    cuts = np.flatnonzero(np.r_[True, seqs[1:] != seqs[:-1], True])
    for lo, hi in itertools.pairwise(cuts):
        batch = idx[lo:hi]
        group = sel[batch]
        ht = hz_t[batch]
        n = int(end[batch].max())
        hz = hz_o[:n]
        cand = np.flatnonzero((hz > ht.min() + part.bottom) & (hz < ht.max() + part.top))
        if len(cand):
            reach = part.widest_below(hz[cand].max() - ht)  # the cone narrows to the tip
            ti, oi = _pair_hits(tips, group[reach > 0], beads, bead_move, cand, u, frame,
                                part, reach[reach > 0])
            out_t.append(ti)
            out_o.append(oi)
    return np.concatenate(out_t), np.concatenate(out_o)


def _pair_hits(tips: Samples, group: np.ndarray, beads: np.ndarray, bead_move: np.ndarray,
               cand: np.ndarray, u: np.ndarray, frame: np.ndarray, part: HeadPart,
               reach: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Earliest bead inside the head part for each tip of ``group`` among ``cand``, searched
    within ``reach`` (per tip) of its axis."""
    if len(group) == 0:
        return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
    tree = point_tree(beads[cand] @ frame.T)
    near = tree.query_ball_point(tips.p[group] @ frame.T, reach, return_sorted=False)
    counts = np.fromiter((len(x) for x in near), dtype=np.intp, count=len(group))
    if counts.sum() == 0:
        return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
    ti = np.repeat(group, counts)
    oi = cand[np.concatenate([np.asarray(x, dtype=np.intp) for x in near if len(x)])]
    return earliest_hits(tips, ti, beads, bead_move, oi, u, part)


def axis_groups(u: np.ndarray) -> np.ndarray:
    """Group id of each unit axis (n, 3), equal for axes equal to 1e-9, (n,) int."""
    q = np.round(u * 1e9).astype(np.int64)
    key = q[:, 0] * 1_000_003 ** 2 + q[:, 1] * 1_000_003 + q[:, 2]  # wraps: a hash
    _, first, group = np.unique(key, return_index=True, return_inverse=True)
    if np.array_equal(q[first][group], q):
        return group.ravel()
    return np.unique(q, axis=0, return_inverse=True)[1].ravel()  # a hash collision


def _material_hits(tips: Samples, rep_beads: np.ndarray, rep_move: np.ndarray,
                   reps: np.ndarray, part: HeadPart) -> list[tuple[int, int]]:
    """(tip, bead) of the earliest bead inside ``part`` at each colliding tip.

    Only the beads' voxel representatives are tested: ``reps`` (k,) their indices among the
    deposits (in print order), ``rep_beads`` (k, 3) their centres and ``rep_move`` (k,) the
    moves that laid them.

    Tips sharing their axis with more than ``SMALL_GROUP`` others are checked by axis group
    (:func:`_group_hits`, whose set-up costs a pass over the beads), the others by a ball
    query each (:func:`~slicer.replay.tip_hits.ball_hits`).
    """
    hits: list[tuple[int, int]] = []
    if len(tips) == 0:
        return hits
    group = axis_groups(tips.u)
    order = np.argsort(group, kind="stable")
    cuts = np.flatnonzero(np.r_[True, group[order][1:] != group[order][:-1], True])
    scattered = []
    for lo, hi in itertools.pairwise(cuts):
        if hi - lo <= SMALL_GROUP:
            scattered.append(order[lo:hi])
            continue
        ti, oi = _group_hits(tips, order[lo:hi], rep_beads, rep_move, part)
        hits.extend(zip(ti.tolist(), reps[oi].tolist(), strict=True))
    if scattered and len(reps):
        ti, oi = ball_hits(tips, np.concatenate(scattered), rep_beads, rep_move,
                           point_tree(rep_beads), part)
        hits.extend(zip(ti.tolist(), reps[oi].tolist(), strict=True))
    return hits


def find_collisions(parsed: ParsedGcode, near: Samples, far_tips: Samples, deposits: Samples,
                    head: Printhead, platform_radius: float) -> tuple[int, list[Collision]]:
    """Count colliding tip samples and describe the first of each (sub-part, layer, obstacle).

    The nozzle (the head's first segment) is checked at tips ``near`` against beads kept at
    ``NEAR_PITCH``; the rest of the head at the sparser tips ``far_tips`` against ``FAR_PITCH``
    (one earliest bead per voxel: the check resolves material to that pitch).

    Returns
    -------
    count : int
        Colliding tip samples.
    reports : list of Collision
        At most ``MAX_REPORTS``, in file order.
    """
    segs = head.segments
    # the beads are found by chunks and only the voxels' first ones kept: (n, 3) arrays of
    # every bead would cost as much as the samples again
    reps = first_in_voxels(len(deposits), lambda lo, hi: bead_centres(deposits, lo, hi),
                           NEAR_PITCH, _bead_bounds(deposits))
    beads = _centres_at(deposits, reps)
    found = [(near, t, o) for t, o in _material_hits(near, beads, deposits.move[reps], reps,
                                                      HeadPart(segs[:1]))]
    if len(segs) > 1:
        far = voxel_representatives(beads, FAR_PITCH)
        found += [(far_tips, t, o) for t, o in _material_hits(
            far_tips, beads[far], deposits.move[reps[far]], reps[far], HeadPart(segs[1:]))]
    found += [(near, int(t), -1) for t in np.flatnonzero(platform_hits(near, head,
                                                                        platform_radius))]
    found.sort(key=lambda x: (int(x[0].move[x[1]]), x[2]))
    reports: list[Collision] = []
    seen: set[tuple[int, int, bool]] = set()
    for tips, t, o in found:
        m = int(tips.move[t])
        key = (int(tips.subpart[t]), int(tips.layer[t]), o < 0)
        if key in seen or len(reports) >= MAX_REPORTS:
            continue
        seen.add(key)
        reports.append(Collision(int(parsed.line[m]), key[0], key[1],
                                 "platform" if o < 0 else "printed part",
                                 int(deposits.subpart[o]) if o >= 0 else -1,
                                 int(deposits.layer[o]) if o >= 0 else -1,
                                 bool(parsed.transition[m])))
    return len({(id(tips), t) for tips, t, _ in found}), reports
