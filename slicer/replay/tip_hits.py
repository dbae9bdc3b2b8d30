"""Which earlier beads lie inside the head placed at a tip: the exact test of the collision check.

:func:`earliest_hits` tests (tip, bead) pairs found by any search; :func:`ball_hits` finds
them for scattered tips (those of moves that turn the table, each with its own nozzle axis)
by one ball query per tip around the head part, where grouping tips by axis does not pay.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from slicer.replay.samples import Samples

BALL_BATCH = 256  # tips per ball query (bounds the candidate lists held at once)


@dataclass(frozen=True)
class HeadPart:
    """Some consecutive segments of a head: (start, end, r_start, r_end) above the tip."""

    segments: tuple[tuple[float, float, float, float], ...]

    @property
    def top(self) -> float:
        return self.segments[-1][1]

    @property
    def bottom(self) -> float:
        return self.segments[0][0]

    @property
    def max_radius(self) -> float:
        return max(max(r0, r1) for _, _, r0, r1 in self.segments)

    def widest_below(self, h: np.ndarray) -> np.ndarray:
        """Largest radius of the part between its bottom and heights ``h`` above the tip
        (0 where ``h`` is at or below the bottom); the radius runs linearly along each
        segment, so the largest lies at a segment's end."""
        out = np.zeros(h.shape)
        for a, b, r0, r1 in self.segments:
            top = np.minimum(h, b)
            wide = np.maximum(r0, r0 + (r1 - r0) * (top - a) / (b - a))
            out = np.where(h > a, np.maximum(out, wide), out)
        return out

    def radius_at(self, h: np.ndarray) -> np.ndarray:
        """Radius at heights ``h`` above the tip; -1 outside this part."""
        out = np.full(h.shape, -1.0)
        for a, b, r0, r1 in self.segments:
            m = (h > a) & (h <= b)
            out[m] = r0 + (r1 - r0) * (h[m] - a) / (b - a)
        return out


def earliest_hits(tips: Samples, ti: np.ndarray, beads: np.ndarray, bead_move: np.ndarray,
                  oi: np.ndarray, u: np.ndarray, part: HeadPart
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The earliest bead inside the head part for each tip of the candidate pairs.

    Parameters
    ----------
    tips : Samples
    ti, oi : (k,) int
        Candidate pairs: tip index and bead index (beads in print order).
    beads : (b, 3) float
    bead_move : (b,) int
        Move that laid each bead; only beads of moves before the tip's count.
    u : (3,) or (k, 3) float
        Nozzle axis of the tips (one for all, or one per pair).
    part : HeadPart

    Returns
    -------
    (tip, bead) : (m,) int each
        One pair per colliding tip, with the smallest bead index, sorted by tip.
    """
    rel = beads[oi] - tips.p[ti]
    u = np.broadcast_to(u, rel.shape)
    h = np.einsum("ij,ij->i", rel, u)
    rho = np.linalg.norm(rel - h[:, None] * u, axis=1)
    hit = (bead_move[oi] < tips.move[ti]) & (rho < part.radius_at(h))
    ti, oi = ti[hit], oi[hit]
    order = np.lexsort((oi, ti))
    ti, oi = ti[order], oi[order]
    first = np.r_[True, ti[1:] != ti[:-1]] if len(ti) else np.zeros(0, dtype=bool)
    return ti[first], oi[first]


def ball_hits(tips: Samples, idx: np.ndarray, beads: np.ndarray, bead_move: np.ndarray,
              tree: cKDTree, part: HeadPart) -> tuple[np.ndarray, np.ndarray]:
    """:func:`earliest_hits` of tips ``idx`` against the beads of ``tree`` (of ``beads``).

    The candidates of a tip are the beads in the ball around the middle of the head part
    that holds all of it (radius √(half height² + largest radius²)).
    """
    half = 0.5 * (part.top - part.bottom)
    radius = math.hypot(half, part.max_radius)
    out_t, out_o = [np.zeros(0, dtype=np.intp)], [np.zeros(0, dtype=np.intp)]
    for lo in range(0, len(idx), BALL_BATCH):
        batch = idx[lo:lo + BALL_BATCH]
        centre = tips.p[batch] + tips.u[batch] * (part.bottom + half)
        near = tree.query_ball_point(centre, radius, return_sorted=False)
        counts = np.fromiter((len(x) for x in near), dtype=np.intp, count=len(batch))
        if counts.sum() == 0:
            continue
        ti = np.repeat(batch, counts)
        oi = np.concatenate([np.asarray(x, dtype=np.intp) for x in near if len(x)])
        t, o = earliest_hits(tips, ti, beads, bead_move, oi, tips.u[ti], part)
        out_t.append(t)
        out_o.append(o)
    return np.concatenate(out_t), np.concatenate(out_o)
