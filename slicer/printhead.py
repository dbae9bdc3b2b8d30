"""The printhead as solids of revolution about the nozzle axis, measured from the nozzle tip.

One model serves every collision judgement: the choice of cut planes and build order, the A/C
of each layer, the moves between sub-parts and the replay check. The default is the paper's
machine: a long nozzle as a 30° cone up to 12 mm, then heater block and carriage as a cylinder
of radius 15 mm from 12 to 50 mm above the tip.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree

Segment = tuple[float, float, float, float]  # start, end (height above tip), r_start, r_end

_DEFAULT_SEGMENTS: tuple[Segment, ...] = (
    (0.0, 12.0, 0.5, 0.5 + 12.0 * math.tan(math.radians(30.0))),
    (12.0, 50.0, 15.0, 15.0),
)


class PrintheadError(ValueError):
    """A printhead description that is not a stack of segments from the tip up."""


@dataclass(frozen=True)
class Printhead:
    """Stacked conical frusta about the nozzle axis.

    Parameters
    ----------
    segments : tuple of (start, end, r_start, r_end)
        Heights above the tip (mm, ascending, contiguous from 0) and radii at each end.
    """

    segments: tuple[Segment, ...] = _DEFAULT_SEGMENTS

    def __post_init__(self) -> None:
        if not self.segments:
            raise PrintheadError("a printhead needs at least one segment")
        prev = 0.0
        for i, (s, e, r0, r1) in enumerate(self.segments):
            if s != prev or e <= s or r0 < 0 or r1 < 0:
                raise PrintheadError(f"segment {i} ({s}, {e}, {r0}, {r1}) must start at {prev}, "
                                     "end above its start and have radii >= 0")
            prev = e

    @classmethod
    def default(cls) -> Printhead:
        """The paper's machine."""
        return cls()

    @classmethod
    def from_records(cls, records: Iterable[Mapping[str, float]]) -> Printhead:
        """From config records with keys start, end, r_start, r_end."""
        return cls(tuple((float(r["start"]), float(r["end"]), float(r["r_start"]),
                          float(r["r_end"])) for r in records))

    @property
    def height(self) -> float:
        """Top of the modelled head above the tip, mm."""
        return self.segments[-1][1]

    @property
    def max_radius(self) -> float:
        """Largest radius of the head, mm."""
        return max(max(r0, r1) for _, _, r0, r1 in self.segments)

    @property
    def reach(self) -> float:
        """Radius of a ball about the tip that holds the whole head, mm."""
        return math.hypot(self.height, self.max_radius)

    def radius_at(self, height: ArrayLike) -> np.ndarray:
        """Head radius at heights above the tip; -1 where there is no head (h < 0, h > top)."""
        h = np.asarray(height, dtype=float)
        out = np.full(h.shape, -1.0)
        for s, e, r0, r1 in self.segments:
            m = (h >= s) & (h <= e)
            out[m] = r0 + (r1 - r0) * (h[m] - s) / (e - s)
        return out

    def contains(self, points: ArrayLike, tip: ArrayLike, axis: ArrayLike) -> np.ndarray:
        """Which points lie strictly inside the head placed at ``tip`` along ``axis``.

        Parameters
        ----------
        points : (n, 3) float
        tip : (3,) float
            Nozzle tip.
        axis : (3,) float
            Direction from the tip up the nozzle (need not be unit).

        Returns
        -------
        (n,) bool
        """
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        rel = p - np.asarray(tip, dtype=float).reshape(3)
        return self._inside(rel, _unit(axis))

    def _inside(self, rel: np.ndarray, u: np.ndarray) -> np.ndarray:
        h = rel @ u
        r = np.linalg.norm(rel - h[:, None] * u, axis=1)
        return (h > 0.0) & (r < self.radius_at(h))

    def collisions(self, points: ArrayLike, tips: ArrayLike, axis: ArrayLike,
                   tree: cKDTree | None = None) -> np.ndarray:
        """For each tip, whether any obstacle point is inside the head there.

        Parameters
        ----------
        points : (n, 3) float
            Obstacle samples (printed material).
        tips : (m, 3) float
        axis : (3,) or (m, 3) float
            Nozzle axis, one for all tips or one per tip.
        tree : cKDTree, optional
            A prebuilt tree over ``points``.

        Returns
        -------
        (m,) bool
        """
        pts = np.asarray(points, dtype=float).reshape(-1, 3)
        t = np.asarray(tips, dtype=float).reshape(-1, 3)
        if len(pts) == 0 or len(t) == 0:
            return np.zeros(len(t), dtype=bool)
        axes = np.broadcast_to(np.asarray(axis, dtype=float).reshape(-1, 3), t.shape)
        axes = axes / np.linalg.norm(axes, axis=1, keepdims=True)
        tree = cKDTree(pts) if tree is None else tree
        near = tree.query_ball_point(t, self.reach, return_sorted=False)
        counts = np.fromiter((len(x) for x in near), dtype=np.intp, count=len(t))
        if counts.sum() == 0:
            return np.zeros(len(t), dtype=bool)
        owner = np.repeat(np.arange(len(t)), counts)
        idx = np.concatenate([np.asarray(x, dtype=np.intp) for x in near])
        rel = pts[idx] - t[owner]
        h = np.einsum("ij,ij->i", rel, axes[owner])
        r = np.linalg.norm(rel - h[:, None] * axes[owner], axis=1)
        hit = (h > 0.0) & (r < self.radius_at(h))
        return np.bincount(owner[hit], minlength=len(t)) > 0

    def first_collision(self, points: ArrayLike, tips: ArrayLike,
                        axis: ArrayLike) -> int | None:
        """Index of the first tip at which the head holds an obstacle point, else ``None``."""
        hits = np.flatnonzero(self.collisions(points, tips, axis))
        return int(hits[0]) if len(hits) else None

    def lowest_point(self, tip: ArrayLike, axis: ArrayLike) -> float:
        """Lowest z any part of the head reaches at ``tip`` with ``axis`` (platform test)."""
        u = _unit(axis)
        sin_tilt = math.sqrt(max(0.0, 1.0 - u[2] ** 2))
        z = float(np.asarray(tip, dtype=float).reshape(3)[2])
        return min(z + s * u[2] - r * sin_tilt for s, e, r0, r1 in self.segments
                   for s, r in ((s, r0), (e, r1)))


def _unit(v: ArrayLike) -> np.ndarray:
    u = np.asarray(v, dtype=float).reshape(3)
    n = float(np.linalg.norm(u))
    if n == 0.0 or not math.isfinite(n):
        raise PrintheadError(f"axis {u.tolist()} has no direction")
    return u / n
