"""Vertical lines on a regular xy grid and where they cross a closed mesh (scanline rasterised).

Each triangle is rasterised row by row: for every grid row inside its xy projection the
x-interval it covers is computed from its edges, so a long thin triangle costs the grid nodes
it covers, never its bounding box. The half-open fill rule (``lo ≤ x < hi``, edges evaluated
in one canonical direction) assigns a node on an edge shared by two triangles to exactly one
of them, so crossing counts (and parities) are exact.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from slicer.replay.unique import sorted_unique

CHUNK_CROSSINGS = 1 << 18  # crossings computed at once when the grid is built
_JITTER = np.array([1.234567e-7, 2.345678e-7])  # moves grid lines off axis-aligned edges


def _spans(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(owner, k) for ``n[i]`` consecutive entries per owner i: owner index and 0..n[i]-1."""
    owner = np.repeat(np.arange(len(n)), n)
    return owner, np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)


def _sorted_xy(tris: np.ndarray) -> np.ndarray:
    """xy of each triangle's vertices (t, 3, 3) sorted by y, then x: (t, 3, 2).

    Every edge then runs from its lower vertex in that order, the canonical direction."""
    xy = tris[:, :, :2]
    order = np.lexsort((xy[:, :, 0], xy[:, :, 1]), axis=1)
    return np.take_along_axis(xy, order[:, :, None], axis=1)


def _edge_x(p: np.ndarray, q: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """x where the edges p → q (k, 2) cross rows ``y`` (k,), and whether they do
    (``p.y ≤ y < q.y``)."""
    dy = q[:, 1] - p[:, 1]
    on = (p[:, 1] <= y) & (y < q[:, 1])
    return p[:, 0] + (y - p[:, 1]) / np.where(dy > 0, dy, 1.0) * (q[:, 0] - p[:, 0]), on


def _row_intervals(v: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """x-interval each triangle covers on its row ``y`` (k,): (lo, hi), empty (inf, -inf)
    off it.

    ``v`` (k, 3, 2) are the triangles' vertices from :func:`_sorted_xy`. A row crosses the
    long edge v0 → v2 and, below v1, the edge v0 → v1, else v1 → v2 (the third edge is not
    on the row by the half-open rule).
    """
    x_long, on_long = _edge_x(v[:, 0], v[:, 2], y)
    upper = (y >= v[:, 1, 1])[:, None]
    x_short, on_short = _edge_x(np.where(upper, v[:, 1], v[:, 0]),
                                np.where(upper, v[:, 2], v[:, 1]), y)
    both = on_long & on_short
    lo = np.where(both, np.minimum(x_long, x_short),
                  np.where(on_long, x_long, np.where(on_short, x_short, np.inf)))
    hi = np.where(both, np.maximum(x_long, x_short),
                  np.where(on_long, x_long, np.where(on_short, x_short, -np.inf)))
    return lo, hi


@dataclass
class ColumnGrid:
    """Crossings of the vertical lines through ``origin + (i, j) · pitch`` with a mesh.

    Attributes
    ----------
    origin : (2,) float
        xy of node (0, 0) (jitter included).
    pitch : float
    dims : (2,) int
        Nodes along x and y.
    key : (k,) float
        Sorted ``column · span + (z − z0)`` of every crossing (column = i · dims[1] + j).
    z0, span : float
        Offset and per-column stride of ``key``.
    """

    origin: np.ndarray
    pitch: float
    dims: np.ndarray
    key: np.ndarray
    z0: float
    span: float

    @classmethod
    def build(cls, tris: np.ndarray, pitch: float) -> ColumnGrid:
        """Rasterise ``tris`` (t, 3, 3) onto a grid of ``pitch`` covering their xy extent."""
        lo, hi = tris.reshape(-1, 3).min(axis=0), tris.reshape(-1, 3).max(axis=0)
        origin = lo[:2] - pitch + _JITTER
        dims = np.ceil((hi[:2] - origin) / pitch).astype(np.int64) + 2
        z0, span = float(lo[2]) - 1.0, float(hi[2] - lo[2]) + 2.0
        total, batches = _crossings(tris, origin, pitch, dims)
        key, n = np.empty(total), 0  # filled in place: one array of the keys at any time
        for col, z in batches:
            key[n:n + len(col)] = col * span + (z - z0)
            n += len(col)
        key.resize(n, refcheck=False)
        key.sort()
        return cls(origin, pitch, dims, key, z0, span)

    def nearest_column(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Column of the node nearest each point, and whether it lies on the grid."""
        ij = np.rint((xy - self.origin) / self.pitch).astype(np.int64)
        ok = np.all((ij >= 0) & (ij < self.dims), axis=1)
        ij = np.where(ok[:, None], ij, 0)
        return ij[:, 0] * self.dims[1] + ij[:, 1], ok

    def crossings_above(self, col: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Crossings of column ``col`` above height ``z`` (both (n,)), (n,) int."""
        end = np.searchsorted(self.key, (col + 1) * self.span, side="left")
        return end - np.searchsorted(self.key, col * self.span + (z - self.z0), side="right")

    def parity_inside(self, points: np.ndarray) -> np.ndarray:
        """Inside test of each point (n, 3) along the line through its nearest node.

        Exact for points farther than ``pitch / √2`` from the surface (the point and the
        node's line at its height are then on the same side); off-grid points are outside.
        """
        col, ok = self.nearest_column(points[:, :2])
        return ok & (self.crossings_above(col, points[:, 2]) % 2 == 1)

    def node_xy(self, col: np.ndarray) -> np.ndarray:
        """xy of the nodes of columns ``col``, (n, 2)."""
        ij = np.column_stack([col // self.dims[1], col % self.dims[1]])
        return self.origin + ij * self.pitch


def _crossings(tris: np.ndarray, origin: np.ndarray, pitch: float, dims: np.ndarray
               ) -> tuple[int, Iterator[tuple[np.ndarray, np.ndarray]]]:
    """(column, z) of the crossings of the grid lines with the triangles, (k,) each, by
    batches of at most about ``CHUNK_CROSSINGS`` (a large flat face crosses millions of
    lines: its temporaries stay bounded), after an upper bound of their total count."""
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    t = tris[np.abs(n[:, 2]) > 1e-12]
    n = n[np.abs(n[:, 2]) > 1e-12]
    y = t[:, :, 1]
    j0 = np.ceil((y.min(axis=1) - origin[1]) / pitch).astype(np.int64)
    j1 = np.ceil((y.max(axis=1) - origin[1]) / pitch).astype(np.int64)  # exclusive
    owner, k = _spans(np.maximum(j1 - j0, 0))
    j = j0[owner] + k
    yr = origin[1] + j * pitch
    lo, hi = _row_intervals(_sorted_xy(t)[owner], yr)
    i0 = np.ceil((lo - origin[0]) / pitch).astype(np.int64)
    i1 = np.ceil((hi - origin[0]) / pitch).astype(np.int64)  # exclusive
    width = np.maximum(i1 - i0, 0)
    ends = np.cumsum(width)

    def batches() -> Iterator[tuple[np.ndarray, np.ndarray]]:
        first = 0
        while first < len(width):  # rows in batches of about CHUNK_CROSSINGS crossings
            last = max(int(np.searchsorted(ends, ends[first] - width[first] + CHUNK_CROSSINGS,
                                           side="right")), first + 1)
            rows = slice(first, last)
            first = last
            row, kk = _spans(width[rows])
            i = i0[rows][row] + kk
            tri = owner[rows][row]
            jr = j[rows][row]
            x, yy = origin[0] + i * pitch, yr[rows][row]
            a, nn = t[tri, 0], n[tri]
            z = a[:, 2] - (nn[:, 0] * (x - a[:, 0]) + nn[:, 1] * (yy - a[:, 1])) / nn[:, 2]
            ok = (i >= 0) & (i < dims[0]) & (jr >= 0) & (jr < dims[1])
            yield (i * dims[1] + jr)[ok], z[ok]

    return int(ends[-1]) if len(ends) else 0, batches()


def volume_grid(tris: np.ndarray, pitch: float) -> np.ndarray:
    """Nodes of a regular grid of ``pitch`` that lie inside the closed mesh, (m, 3)."""
    grid = ColumnGrid.build(tris, pitch)
    lo, hi = tris.reshape(-1, 3).min(axis=0), tris.reshape(-1, 3).max(axis=0)
    zs = np.arange(lo[2] + pitch / 2, hi[2], pitch)
    cols = sorted_unique(np.floor(grid.key / grid.span).astype(np.int64))
    qcol = np.repeat(cols, len(zs))
    qz = np.tile(zs, len(cols))
    mask = grid.crossings_above(qcol, qz) % 2 == 1
    return np.column_stack([grid.node_xy(qcol[mask]), qz[mask]])
