"""Vectorised mesh queries of the replay check: inside test, distance to surface, volume grid.

Triangles are binned into a regular grid (xy columns for ray casting, 3D cells for distance
queries), so each point meets only the triangles near it; every test is exact on those.
"""

from __future__ import annotations

import numpy as np

CELL = 0.5  # mm: bin size of the triangle grids
_JITTER = np.array([1.234567e-7, 2.345678e-7])  # moves query columns off shared edges


def _cell_entries(lo: np.ndarray, hi: np.ndarray, origin: np.ndarray, cell: float,
                  dims: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Grid keys of every cell each box [lo, hi] (k, d) overlaps: (keys, box index), sorted."""
    i0 = np.floor((lo - origin) / cell).astype(np.int64)
    i1 = np.floor((hi - origin) / cell).astype(np.int64)
    i0 = np.clip(i0, 0, dims - 1)
    i1 = np.clip(i1, 0, dims - 1)
    span = i1 - i0 + 1
    counts = np.prod(span, axis=1)
    owner = np.repeat(np.arange(len(lo)), counts)
    local = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    key = np.zeros(len(owner), dtype=np.int64)
    stride = 1
    for ax in range(lo.shape[1] - 1, -1, -1):
        sub = span[owner, ax]
        idx = local % sub
        local = local // sub
        key += (i0[owner, ax] + idx) * stride
        stride *= int(dims[ax])
    order = np.argsort(key, kind="stable")
    return key[order], owner[order]


def _point_keys(points: np.ndarray, origin: np.ndarray, cell: float, dims: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """Grid key of each point and whether it lies inside the grid."""
    idx = np.floor((points - origin) / cell).astype(np.int64)
    ok = np.all((idx >= 0) & (idx < dims), axis=1)
    idx = np.clip(idx, 0, dims - 1)
    key = np.zeros(len(points), dtype=np.int64)
    stride = 1
    for ax in range(points.shape[1] - 1, -1, -1):
        key += idx[:, ax] * stride
        stride *= int(dims[ax])
    return key, ok


def _pairs(keys: np.ndarray, owner: np.ndarray, pkey: np.ndarray, ok: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray]:
    """(point index, triangle index) of every point/triangle sharing a cell."""
    lo = np.searchsorted(keys, pkey, side="left")
    hi = np.searchsorted(keys, pkey, side="right")
    n = np.where(ok, hi - lo, 0)
    pi = np.repeat(np.arange(len(pkey)), n)
    off = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    return pi, owner[np.repeat(lo, n) + off]


def _column_crossings(tris: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Heights where vertical lines through ``xy`` (m, 2) cross the mesh.

    Returns
    -------
    column : (k,) int
        Which line.
    z : (k,) float
        Height of the crossing.
    """
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
    keep = np.abs(area) > 1e-12
    t = tris[keep]
    area = area[keep]
    lo, hi = t[:, :, :2].min(axis=1), t[:, :, :2].max(axis=1)
    origin = np.minimum(lo.min(axis=0), xy.min(axis=0)) - CELL
    dims = np.ceil((np.maximum(hi.max(axis=0), xy.max(axis=0)) - origin) / CELL).astype(
        np.int64) + 2
    keys, owner = _cell_entries(lo, hi, origin, CELL, dims)
    pkey, ok = _point_keys(xy, origin, CELL, dims)
    pi, ti = _pairs(keys, owner, pkey, ok)
    q = xy[pi]
    a, b, c = t[ti, 0], t[ti, 1], t[ti, 2]
    w0 = ((b[:, 0] - q[:, 0]) * (c[:, 1] - q[:, 1]) - (c[:, 0] - q[:, 0]) * (b[:, 1] - q[:, 1]))
    w1 = ((c[:, 0] - q[:, 0]) * (a[:, 1] - q[:, 1]) - (a[:, 0] - q[:, 0]) * (c[:, 1] - q[:, 1]))
    w0, w1 = w0 / area[ti], w1 / area[ti]
    w2 = 1.0 - w0 - w1
    hit = (w0 >= 0) & (w1 >= 0) & (w2 >= 0)
    z = w0 * a[:, 2] + w1 * b[:, 2] + w2 * c[:, 2]
    return pi[hit], z[hit]


def inside(tris: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Which points lie inside a closed triangle mesh (ray parity along +z).

    Parameters
    ----------
    tris : (t, 3, 3) float
    points : (n, 3) float

    Returns
    -------
    (n,) bool
    """
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    if len(p) == 0:
        return np.zeros(0, dtype=bool)
    col, z = _column_crossings(tris, p[:, :2] + _JITTER)
    above = z > p[col, 2]
    return np.bincount(col[above], minlength=len(p)) % 2 == 1


def volume_grid(tris: np.ndarray, pitch: float) -> np.ndarray:
    """Cell centres of a regular grid of ``pitch`` that lie inside the mesh, (m, 3)."""
    lo, hi = tris.reshape(-1, 3).min(axis=0), tris.reshape(-1, 3).max(axis=0)
    axes = [np.arange(lo[k] + pitch / 2, hi[k], pitch) for k in range(3)]
    gx, gy = np.meshgrid(axes[0], axes[1], indexing="ij")
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    col, z = _column_crossings(tris, xy + _JITTER)
    zs = axes[2]
    # crossings above each grid height, per column: sort by (column, z) and search
    order = np.lexsort((z, col))
    col, z = col[order], z[order]
    span = float(hi[2] - lo[2]) + 4 * pitch
    key = col * span + (z - lo[2] + pitch)
    qcol = np.repeat(np.arange(len(xy)), len(zs))
    qz = np.tile(zs, len(xy))
    qkey = qcol * span + (qz - lo[2] + pitch)
    below = np.searchsorted(key, qkey, side="right")
    end = np.searchsorted(col, np.arange(len(xy)), side="right")[qcol]
    mask = (end - below) % 2 == 1
    return np.column_stack([xy[qcol[mask]], qz[mask]])


def _segment_d2(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    den = np.einsum("ij,ij->i", ab, ab)
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.where(den > 0, den, 1.0), 0.0, 1.0)
    d = p - a - t[:, None] * ab
    return np.einsum("ij,ij->i", d, d)


def _triangle_d2(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Squared distance from each point to its triangle, (k,)."""
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
    interior = good & (v >= 0) & (w >= 0) & (v + w <= 1)
    n = np.cross(ab, ac)
    nn = np.einsum("ij,ij->i", n, n)
    plane = np.einsum("ij,ij->i", ap, n) ** 2 / np.where(nn > 0, nn, 1.0)
    edges = np.minimum(np.minimum(_segment_d2(p, a, b), _segment_d2(p, b, c)),
                       _segment_d2(p, c, a))
    return np.where(interior, plane, edges)


def surface_distance(tris: np.ndarray, points: np.ndarray, max_distance: float) -> np.ndarray:
    """Distance from each point to the mesh surface, ``inf`` where above ``max_distance``.

    Parameters
    ----------
    tris : (t, 3, 3) float
    points : (n, 3) float
    max_distance : float

    Returns
    -------
    (n,) float
    """
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    out = np.full(len(p), np.inf)
    if len(p) == 0:
        return out
    cell = max(CELL, 2.0 * max_distance)
    lo, hi = tris.min(axis=1) - max_distance, tris.max(axis=1) + max_distance
    origin = np.minimum(lo.min(axis=0), p.min(axis=0)) - cell
    dims = np.ceil((np.maximum(hi.max(axis=0), p.max(axis=0)) - origin) / cell).astype(
        np.int64) + 2
    keys, owner = _cell_entries(lo, hi, origin, cell, dims)
    pkey, ok = _point_keys(p, origin, cell, dims)
    normal = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    norm = np.linalg.norm(normal, axis=1, keepdims=True)
    unit = np.where(norm > 0, normal / np.where(norm > 0, norm, 1.0), 0.0)
    for chunk in np.array_split(np.arange(len(p)), max(1, len(p) // 200_000)):
        pi, ti = _pairs(keys, owner, pkey[chunk], ok[chunk])
        if len(pi) == 0:
            continue
        q = p[chunk][pi]
        near = np.abs(np.einsum("ij,ij->i", q - tris[ti, 0], unit[ti])) <= max_distance
        pi, ti, q = pi[near], ti[near], q[near]
        if len(pi) == 0:
            continue
        d2 = _triangle_d2(q, tris[ti, 0], tris[ti, 1], tris[ti, 2])
        starts = np.flatnonzero(np.r_[True, pi[1:] != pi[:-1]])
        out[chunk[pi[starts]]] = np.sqrt(np.minimum.reduceat(d2, starts))
    out[out > max_distance] = np.inf
    return out
