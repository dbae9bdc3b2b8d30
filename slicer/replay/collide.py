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

Neither the beads nor the tips are held all at once: the beads are read a chunk at a time
and only each voxel's first kept (:func:`printed_material`), and the tips come in chunks of
moves in file order (:func:`find_collisions`); a tip's verdict depends on no other tip, so
the answers are those of all tips at once.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

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
CHUNK = 1 << 18  # beads mapped to voxels at once


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

    ``points(lo, hi)`` gives points ``lo:hi`` (hi − lo, 3) and ``bounds`` (3,) bounds of
    them all (a minimum and maximum, or wider: floor is monotonic, so the voxels' bounds
    follow). A voxel's first point is the first of the first chunk that holds it, so the
    answer is the whole array's.
    """
    firsts = [lo + first for lo, first in _firsts_by_chunk(n, points, pitch, bounds)]
    return np.concatenate(firsts) if firsts else np.zeros(0, dtype=int)


def _firsts_by_chunk(n: int, points: Callable[[int, int], np.ndarray], pitch: float,
                     bounds: tuple[np.ndarray, np.ndarray] | None
                     ) -> Iterator[tuple[int, np.ndarray]]:
    """Per chunk ``lo:lo + CHUNK`` of :func:`first_in_voxels`: ``lo`` and the indices within
    it (ascending) of the points first in their voxel."""
    if n == 0 or bounds is None:
        return
    low = np.floor(bounds[0] / pitch).astype(np.int64)
    dims = np.floor(bounds[1] / pitch).astype(np.int64) - low + 1
    seen = np.zeros(0, dtype=np.int64)
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
        yield lo, np.sort(first)


@dataclass
class Material:
    """Printed material as the collision check sees it: the first bead (in print order) of
    every occupied voxel of ``NEAR_PITCH``.

    Attributes
    ----------
    index : (k,) int
        File-order index of each bead among the deposits, ascending.
    beads : (k, 3) float
        Their centres (tip − h/2 along the axis).
    move, subpart, layer : (k,) int32
        The move that laid each, its sub-part and layer.
    far : (j,) int
        Rows of the first bead of every voxel of ``FAR_PITCH``.
    """

    index: np.ndarray
    beads: np.ndarray
    move: np.ndarray
    subpart: np.ndarray
    layer: np.ndarray
    far: np.ndarray
    _trees: dict[bool, cKDTree] = field(default_factory=dict, repr=False)

    def tree(self, far: bool) -> cKDTree:
        """KD-tree of the near beads, or of the ``far`` ones (built on first use)."""
        if far not in self._trees:
            self._trees[far] = point_tree(self.beads[self.far] if far else self.beads)
        return self._trees[far]

    def at(self, deposit: int) -> int:
        """Row of the bead that is deposit ``deposit``."""
        return int(np.searchsorted(self.index, deposit))


def printed_material(n: int, chunk: Callable[[int, int], Samples],
                     bounds: tuple[np.ndarray, np.ndarray] | None) -> Material:
    """The :class:`Material` of ``n`` deposits read by ``chunk(lo, hi)`` (deposits ``lo:hi``
    as :class:`Samples`), ``CHUNK`` at a time; ``bounds`` bound their bead centres."""
    held: list[Samples] = []

    def centres(lo: int, hi: int) -> np.ndarray:
        held[:] = [chunk(lo, hi)]
        return bead_centres(held[0])

    parts = []
    for lo, first in _firsts_by_chunk(n, centres, NEAR_PITCH, bounds):
        s = held[0]
        parts.append((lo + first, _centres_at(s, first), s.move[first], s.subpart[first],
                      s.layer[first]))
    if not parts:
        e = np.zeros(0, dtype=np.int32)
        return Material(np.zeros(0, dtype=int), np.zeros((0, 3)), e, e, e,
                        np.zeros(0, dtype=int))
    index, beads, move, subpart, layer = (np.concatenate(p) for p in zip(*parts, strict=True))
    return Material(index, beads, move, subpart, layer,
                    voxel_representatives(beads, FAR_PITCH))


def bead_centres(deposits: Samples, lo: int = 0, hi: int | None = None) -> np.ndarray:
    """Centres of the beads of deposits ``lo:hi`` (tip − h/2 along the axis), (k, 3)."""
    sl = slice(lo, len(deposits) if hi is None else hi)
    return deposits.p[sl] - deposits.u[sl] * (deposits.h[sl, None] / 2.0)


def _centres_at(deposits: Samples, idx: np.ndarray) -> np.ndarray:
    """:func:`bead_centres` of the deposits ``idx`` (k,), (k, 3)."""
    return deposits.p[idx] - deposits.u[idx] * (deposits.h[idx, None] / 2.0)


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
                   reps: np.ndarray, part: HeadPart, tree: Callable[[], cKDTree]
                   ) -> list[tuple[int, int]]:
    """(tip, bead) of the earliest bead inside ``part`` at each colliding tip.

    Only the beads' voxel representatives are tested: ``reps`` (k,) their indices among the
    deposits (in print order), ``rep_beads`` (k, 3) their centres, ``rep_move`` (k,) the
    moves that laid them and ``tree()`` their KD-tree.

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
        ti, oi = ball_hits(tips, np.concatenate(scattered), rep_beads, rep_move, tree(),
                           part)
        hits.extend(zip(ti.tolist(), reps[oi].tolist(), strict=True))
    return hits


def find_collisions(parsed: ParsedGcode, tips: Iterable[tuple[Samples, Samples]],
                    material: Material, head: Printhead, platform_radius: float
                    ) -> tuple[int, list[Collision]]:
    """Count colliding tip samples and describe the first of each (sub-part, layer, obstacle).

    ``tips`` are the head's samples in chunks of moves, in file order: (near, far) of each.
    The nozzle (the head's first segment) is checked at the near tips against ``material``'s
    beads (one earliest bead per ``NEAR_PITCH`` voxel); the rest of the head at the sparser
    far tips against its ``FAR_PITCH`` beads: the check resolves material to that pitch.

    Returns
    -------
    count : int
        Colliding tip samples.
    reports : list of Collision
        At most ``MAX_REPORTS``, in file order.
    """
    log = _Reports(parsed, material)
    for near, far_tips in tips:
        log.add(_chunk_hits(near, far_tips, material, head, platform_radius))
    return log.count, log.reports


def _chunk_hits(near: Samples, far_tips: Samples, material: Material, head: Printhead,
                platform_radius: float) -> list[tuple[Samples, int, int]]:
    """(tips, tip, deposit hit or -1 for the platform) of each colliding tip of a chunk."""
    segs = head.segments
    m = material
    found = [(near, t, o) for t, o in _material_hits(
        near, m.beads, m.move, m.index, HeadPart(segs[:1]), lambda: m.tree(False))]
    if len(segs) > 1:
        found += [(far_tips, t, o) for t, o in _material_hits(
            far_tips, m.beads[m.far], m.move[m.far], m.index[m.far], HeadPart(segs[1:]),
            lambda: m.tree(True))]
    found += [(near, int(t), -1) for t in np.flatnonzero(platform_hits(near, head,
                                                                        platform_radius))]
    return found


@dataclass
class _Reports:
    """Colliding tips counted, and the first of each (sub-part, layer, obstacle) described,
    chunk after chunk in file order."""

    parsed: ParsedGcode
    material: Material
    count: int = 0
    reports: list[Collision] = field(default_factory=list)
    seen: set[tuple[int, int, bool]] = field(default_factory=set)

    def add(self, found: list[tuple[Samples, int, int]]) -> None:
        found.sort(key=lambda x: (int(x[0].move[x[1]]), x[2]))
        self.count += len({(id(tips), t) for tips, t, _ in found})
        m = self.material
        for tips, t, o in found:
            move = int(tips.move[t])
            key = (int(tips.subpart[t]), int(tips.layer[t]), o < 0)
            if key in self.seen or len(self.reports) >= MAX_REPORTS:
                continue
            self.seen.add(key)
            row = m.at(o) if o >= 0 else -1
            self.reports.append(Collision(
                int(self.parsed.line[move]), key[0], key[1],
                "platform" if o < 0 else "printed part",
                int(m.subpart[row]) if o >= 0 else -1, int(m.layer[row]) if o >= 0 else -1,
                bool(self.parsed.transition[move])))
