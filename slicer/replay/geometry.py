"""Mesh queries of the replay check: distance to the surface and inside test, built once per model.

:class:`ModelIndex` keeps

* a KD-tree of *surface samples* (:func:`surface_samples`): every surface point lies within
  ``cover = SURFACE_COVER`` of one. The nearest sample bounds a point's distance d to the
  surface: ``d0 − cover ≤ d ≤ d0``. Only points whose bound straddles a threshold are
  resolved exactly, against the triangles of the samples within ``threshold + cover``;
* a :class:`~slicer.replay.columns.ColumnGrid` of vertical lines at ``inside_pitch``: a
  point farther than ``inside_pitch / √2`` from the surface is inside exactly when the line
  through its nearest node crosses the mesh an odd number of times above it;
* the mesh as a ``manifold3d`` solid, whose ray cast decides the few points closer than that.
"""

from __future__ import annotations

import math

import manifold3d as m3
import numpy as np

from slicer.replay.columns import ColumnGrid
from slicer.replay.kdtree import point_tree
from slicer.replay.unique import sorted_unique

SURFACE_COVER = 0.15  # mm: every surface point lies this close to a surface sample
SURFACE_LEAF = 32  # surface samples per KD-tree leaf (faster than 16 on the wall queries)
CHUNK_POINTS = 1 << 18  # surface samples computed at once
EXACT_CHUNK = 1 << 15  # points resolved exactly at once (their neighbour lists are Python's)
INSIDE_PITCH = 0.05  # mm: default spacing of the vertical lines of the inside test
_UP = np.array([0.0, 0.0, 1.0])


def _segment_d2(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    den = np.einsum("ij,ij->i", ab, ab)
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.where(den > 0, den, 1.0), 0.0, 1.0)
    d = p - a - t[:, None] * ab
    return np.einsum("ij,ij->i", d, d)


def triangle_d2(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Squared distance from each point (k, 3) to its triangle (a, b, c each (k, 3)), (k,)."""
    ab, ac, ap = b - a, c - a, p - a
    d00 = np.einsum("ij,ij->i", ab, ab)
    d01 = np.einsum("ij,ij->i", ab, ac)
    d11 = np.einsum("ij,ij->i", ac, ac)
    d20 = np.einsum("ij,ij->i", ap, ab)
    d21 = np.einsum("ij,ij->i", ap, ac)
    den = d00 * d11 - d01 * d01
    good = den > 1e-18
    sden = np.where(good, den, 1.0)
    v = (d11 * d20 - d01 * d21) / sden
    w = (d00 * d21 - d01 * d20) / sden
    interior = np.flatnonzero(good & (v >= 0) & (w >= 0) & (v + w <= 1))
    n = np.cross(ab[interior], ac[interior])
    nn = np.einsum("ij,ij->i", n, n)
    out = np.empty(len(p))
    out[interior] = (np.einsum("ij,ij->i", ap[interior], n) ** 2
                     / np.where(nn > 0, nn, 1.0))
    rim = np.ones(len(p), dtype=bool)
    rim[interior] = False
    pr, ar, br, cr = p[rim], a[rim], b[rim], c[rim]
    out[rim] = np.minimum(np.minimum(_segment_d2(pr, ar, br), _segment_d2(pr, br, cr)),
                          _segment_d2(pr, cr, ar))
    return out


def surface_samples(tris: np.ndarray, cover: float) -> tuple[np.ndarray, np.ndarray]:
    """Points on the triangles (t, 3, 3) such that every surface point lies within ``cover``.

    Each triangle is cut by rows parallel to its longest edge, ``cover / √2`` apart from that
    edge to the opposite vertex, with points ``√2 · cover`` apart along each row (ends
    included). The opposite vertex projects inside the longest edge, so a row's segment
    contains the projection of every point between it and the next row: a point drops at
    most ``cover / √2`` to a row, then runs at most ``cover / √2`` along it. The count is
    about area / cover² plus a row per ``cover`` of height, slivers included.

    A triangle whose vertices all lie within ``cover`` of its centroid is sampled by the
    centroid alone (the farthest point of a triangle from any point is a vertex).

    Returns
    -------
    points : (m, 3) float
    owner : (m,) int
        The triangle each point lies on.
    """
    centre = tris.mean(axis=1)
    small = np.linalg.norm(tris - centre[:, None], axis=2).max(axis=1) <= cover
    start, end, count, tri = _rows(tris[~small], cover)
    n0 = int(small.sum())
    ends = np.cumsum(count)
    points = np.empty((n0 + (int(ends[-1]) if len(ends) else 0), 3))
    owner = np.empty(len(points), dtype=np.int64)
    points[:n0], owner[:n0] = centre[small], np.flatnonzero(small)
    big = np.flatnonzero(~small)
    first = 0
    while first < len(count):  # rows in batches of about CHUNK_POINTS points
        last = max(int(np.searchsorted(ends, ends[first] - count[first] + CHUNK_POINTS,
                                       side="right")), first + 1)
        rows = slice(first, last)
        out = slice(n0 + int(ends[first] - count[first]), n0 + int(ends[last - 1]))
        first = last
        row, i = _spans(count[rows])
        f = (i / np.maximum(count[rows][row] - 1, 1))[:, None]
        a, b = start[rows][row], end[rows][row]
        points[out], owner[out] = a + f * (b - a), big[tri[rows][row]]
    return points, owner


def _rows(tris: np.ndarray, cover: float
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The rows of :func:`surface_samples` on the triangles (t, 3, 3): start and end
    (r, 3), their number of points (r,) and triangle (r,)."""
    gap_v, gap_h = cover / math.sqrt(2.0), cover * math.sqrt(2.0)
    edge = np.stack([np.linalg.norm(tris[:, (i + 2) % 3] - tris[:, (i + 1) % 3], axis=1)
                     for i in range(3)], axis=1)  # edge i lies opposite vertex i
    k = edge.argmax(axis=1)
    rows = np.arange(len(tris))
    apex, p0, p1 = (tris[rows, (k + i) % 3] for i in range(3))
    base = edge[rows, k]
    height = np.linalg.norm(np.cross(p1 - p0, apex - p0), axis=1) / np.maximum(base, 1e-300)
    m = np.maximum(np.ceil(height / gap_v), 1).astype(np.int64)
    tri, j = _spans(m + 1)
    t = (j / m[tri])[:, None]
    start = p0[tri] + t * (apex[tri] - p0[tri])
    end = p1[tri] + t * (apex[tri] - p1[tri])
    count = np.ceil(base[tri] * (1.0 - t[:, 0]) / gap_h - 1e-9).astype(np.int64) + 1
    return start, end, count, tri


def _spans(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(owner, k) for ``n[i]`` consecutive entries per owner i: owner index and 0..n[i]-1."""
    owner = np.repeat(np.arange(len(n)), n)
    return owner, np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)


def _solid(vertices: np.ndarray, faces: np.ndarray) -> m3.Manifold | None:
    """The mesh as a manifold3d solid, or None when it is not a valid manifold."""
    solid = m3.Manifold(m3.Mesh64(np.ascontiguousarray(vertices, dtype=np.float64),
                                  np.ascontiguousarray(faces, dtype=np.uint64)))
    return solid if solid.status() == m3.Error.NoError and not solid.is_empty() else None


class ModelIndex:
    """Distance and inside queries against one closed mesh (see the module docstring).

    Parameters
    ----------
    vertices : (v, 3) float
    faces : (t, 3) int
    inside_pitch : float
        Spacing of the vertical lines of the inside test, mm.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray,
                 inside_pitch: float = INSIDE_PITCH) -> None:
        self.tris = np.asarray(vertices, dtype=float)[np.asarray(faces)]
        points, self._owner = surface_samples(self.tris, SURFACE_COVER)
        self._tree = point_tree(points, SURFACE_LEAF)
        self.cover = SURFACE_COVER
        self._top = float(self.tris[:, :, 2].max()) + 1.0
        self.inside_pitch = inside_pitch
        self._columns = ColumnGrid.build(self.tris, inside_pitch)
        self._mesh = (vertices, faces)
        self._solid_cache: list[m3.Manifold | None] = []
        # the coverage grid and its shell mask per shell depth (.coverage.shell_grid)
        self.grids: dict[float, tuple[np.ndarray, np.ndarray]] = {}

    def nearest_bound(self, points: np.ndarray, cap: float) -> np.ndarray:
        """Distance to the nearest surface sample (≥ the true distance), ``inf`` above ``cap``."""
        if len(points) == 0:
            return np.zeros(0)
        d, _ = self._tree.query(points, distance_upper_bound=cap + self.cover, workers=-1)
        return d

    def _exact(self, p: np.ndarray, radius: np.ndarray) -> np.ndarray:
        """Exact distance of each point (k, 3) to the triangles of the samples within
        ``radius`` (k,) of it (``inf`` when there are none), (k,)."""
        out = np.full(len(p), np.inf)
        for lo in range(0, len(p), EXACT_CHUNK):  # the neighbour lists are Python lists
            hi = lo + EXACT_CHUNK
            out[lo:hi] = self._exact_chunk(p[lo:hi], radius[lo:hi])
        return out

    def _exact_chunk(self, p: np.ndarray, radius: np.ndarray) -> np.ndarray:
        """:meth:`_exact` of a few points (k, 3) at once, (k,)."""
        out = np.full(len(p), np.inf)
        near = self._tree.query_ball_point(p, radius, workers=-1, return_sorted=False)
        counts = np.fromiter((len(x) for x in near), dtype=np.int64, count=len(p))
        if counts.sum() == 0:
            return out
        pi = np.repeat(np.arange(len(p)), counts)
        ti = self._owner[np.concatenate([np.asarray(x, dtype=np.int64) for x in near])]
        pair = sorted_unique(pi * len(self.tris) + ti)
        pi, ti = pair // len(self.tris), pair % len(self.tris)
        t = self.tris[ti]
        d2 = triangle_d2(p[pi], t[:, 0], t[:, 1], t[:, 2])
        starts = np.flatnonzero(np.r_[True, pi[1:] != pi[:-1]])
        out[pi[starts]] = np.sqrt(np.minimum.reduceat(d2, starts))
        return out

    def within(self, points: np.ndarray, limit: float, bound: np.ndarray | None = None
               ) -> np.ndarray:
        """Whether each point (n, 3) lies within ``limit`` of the surface, (n,) bool (exact).

        ``bound`` is :meth:`nearest_bound` of the points with a cap ≥ ``limit``.
        """
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        d0 = self.nearest_bound(p, limit) if bound is None else bound
        out = d0 <= limit
        band = np.flatnonzero(~out & (d0 - self.cover <= limit))
        out[band] = self._exact(p[band], np.full(len(band), limit + self.cover)) <= limit
        return out

    def distance(self, points: np.ndarray, limit: float, bound: np.ndarray | None = None
                 ) -> np.ndarray:
        """Exact distance to the surface where it is ≤ ``limit``, else ``inf``, (n,).

        ``bound`` is :meth:`nearest_bound` of the points with a cap ≥ ``limit``.
        """
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        d0 = self.nearest_bound(p, limit) if bound is None else bound
        out = np.full(len(p), np.inf)
        idx = np.flatnonzero(d0 - self.cover <= limit)
        d = self._exact(p[idx], np.minimum(d0[idx], limit) + self.cover)
        out[idx] = np.where(d <= limit, d, np.inf)
        return out

    def inside(self, points: np.ndarray, near: np.ndarray | None = None) -> np.ndarray:
        """Which points (n, 3) lie inside the closed mesh, (n,) bool.

        ``near`` is :meth:`distance` of the points with a limit ≥ ``inside_pitch / √2``
        (computed when not given): only points that close need a ray of their own.
        """
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        if len(p) == 0:
            return np.zeros(0, dtype=bool)
        out = self._columns.parity_inside(p)
        solid = self._ray_solid()
        if solid is None:
            return out
        close = self.inside_pitch / math.sqrt(2.0)
        d = self.distance(p, close) if near is None else near
        for i in np.flatnonzero(d <= close):
            hits = solid.ray_cast(p[i], np.array([p[i, 0], p[i, 1], self._top]))
            out[i] = len(hits) % 2 == 1
        return out

    def _ray_solid(self) -> m3.Manifold | None:
        """The mesh as a manifold3d solid for ray casts, built on first use."""
        if not self._solid_cache:
            self._solid_cache.append(_solid(*self._mesh))
        return self._solid_cache[0]

    @property
    def nbytes(self) -> int:
        """Bytes held by the index's arrays (triangles, surface samples and their tree's
        indices, column crossings, coverage grids)."""
        grids = sum(g.nbytes + m.nbytes for g, m in self.grids.values())
        return int(self.tris.nbytes + self._tree.data.nbytes + self._tree.indices.nbytes
                   + self._owner.nbytes + self._columns.key.nbytes + grids)

    def parity_inside(self, points: np.ndarray) -> np.ndarray:
        """The column test alone: exact for points farther than ``inside_pitch / √2`` from the
        surface (cheaper than :meth:`inside` where closer points are judged otherwise)."""
        return self._columns.parity_inside(np.asarray(points, dtype=float).reshape(-1, 3))
