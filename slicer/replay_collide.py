"""Head collisions of a replayed file: with material printed before, and with the platform.

Tips are sampled along every positioned move (≤ ``spacing`` mm, ≤ ``angle_step``° apart, move
ends included). Printed material is the set of deposited bead centres (tip − h/2 along the
axis) of layers up to the tip's own layer in print order: the current layer lies below the
tip, later layers are not there yet. A tip collides when a bead centre lies inside the head
(:class:`~slicer.printhead.Printhead`) placed there, or when the lowest point of the head
dips below the platform plane (z = 0) within the platform radius.

Tips are grouped by nozzle axis; in each group only material above the lowest tip and below
the highest tip plus the head height can matter, which is usually none.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from slicer.gcode_reader import ParsedGcode
from slicer.printhead import Printhead
from slicer.replay_samples import Samples

PLATFORM_TOL = 1e-3  # mm below z = 0 that still counts as touching, not entering
MAX_REPORTS = 20


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
    u = tips.u
    down = np.array([0.0, 0.0, 1.0]) - u[:, 2:3] * u
    norm = np.linalg.norm(down, axis=1, keepdims=True)
    down = np.where(norm > 1e-12, down / np.where(norm > 1e-12, norm, 1.0), 0.0)
    hit = np.zeros(len(tips), dtype=bool)
    for s, _, r0, r1 in head.segments:
        for hgt, r in ((s, r0), (_, r1)):
            low = tips.p + hgt * u - r * down
            hit |= (low[:, 2] < -PLATFORM_TOL) & (np.linalg.norm(low[:, :2], axis=1) <= radius)
    return hit


def _frame(u: np.ndarray) -> np.ndarray:
    ref = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(u, ref)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(u, e1)])


def _group_hits(tips: Samples, sel: np.ndarray, beads: np.ndarray, bead_seq: np.ndarray,
                head: Printhead) -> tuple[np.ndarray, np.ndarray]:
    """(tip index, bead index) of the first hit of each colliding tip in one axis group.

    Beads are in print order (``bead_seq`` non-decreasing). A tip can only hit beads of its
    own layer or earlier that lie above it: the running maximum of bead height along the
    axis rules out almost every tip at once.
    """
    u = tips.u[sel[0]]
    hz_o = beads @ u
    top = np.maximum.accumulate(hz_o) if len(hz_o) else hz_o
    end = np.searchsorted(bead_seq, tips.seq[sel], side="right")
    hz_t = tips.p[sel] @ u
    risky = (end > 0) & (hz_t < top[np.maximum(end, 1) - 1])
    out_t, out_o = [np.zeros(0, dtype=int)], [np.zeros(0, dtype=int)]
    frame = _frame(u)
    for n_beads in np.unique(end[risky]):
        group = sel[risky & (end == n_beads)]
        ht = tips.p[group] @ u
        hz = hz_o[:n_beads]
        cand = np.flatnonzero((hz > ht.min()) & (hz < ht.max() + head.height))
        if len(cand):
            ti, oi = _pair_hits(tips, group, beads, cand, u, frame, head)
            out_t.append(ti)
            out_o.append(oi)
    return np.concatenate(out_t), np.concatenate(out_o)


def _pair_hits(tips: Samples, group: np.ndarray, beads: np.ndarray, cand: np.ndarray,
               u: np.ndarray, frame: np.ndarray, head: Printhead
               ) -> tuple[np.ndarray, np.ndarray]:
    """First bead inside the head for each tip of ``group`` among beads ``cand``."""
    tree = cKDTree(beads[cand] @ frame.T)
    near = tree.query_ball_point(tips.p[group] @ frame.T, head.max_radius,
                                 return_sorted=False)
    counts = np.fromiter((len(x) for x in near), dtype=np.intp, count=len(group))
    if counts.sum() == 0:
        return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
    ti = np.repeat(group, counts)
    oi = cand[np.concatenate([np.asarray(x, dtype=np.intp) for x in near if len(x)])]
    rel = beads[oi] - tips.p[ti]
    h = rel @ u
    rho = np.linalg.norm(rel - h[:, None] * u, axis=1)
    hit = (h > 0) & (rho < head.radius_at(h))
    ti, oi = ti[hit], oi[hit]
    first = np.unique(ti, return_index=True)[1]
    return ti[first], oi[first]


def find_collisions(parsed: ParsedGcode, tips: Samples, deposits: Samples, head: Printhead,
                    platform_radius: float) -> tuple[int, list[Collision]]:
    """Count colliding tips and describe the first of each (sub-part, layer, obstacle).

    Returns
    -------
    count : int
        Colliding tip samples.
    reports : list of Collision
        At most ``MAX_REPORTS``, in file order.
    """
    beads = deposits.p - deposits.u * (deposits.h[:, None] / 2.0)
    keys = np.round(tips.u, 9)
    _, group = np.unique(keys, axis=0, return_inverse=True)
    hits: list[tuple[int, int]] = []
    for g in np.unique(group):
        ti, oi = _group_hits(tips, np.flatnonzero(group == g), beads, deposits.seq, head)
        hits.extend(zip(ti.tolist(), oi.tolist(), strict=True))
    plat = np.flatnonzero(platform_hits(tips, head, platform_radius))
    hits.extend((int(t), -1) for t in plat)
    hits.sort()
    reports, seen = [], set()
    for t, o in hits:
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
    return len({t for t, _ in hits}), reports
