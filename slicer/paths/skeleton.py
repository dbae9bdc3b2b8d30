"""Skeleton curve of a sub-part: mean-curvature-flow skeleton, main chain, arc-length spline.

Pipeline (paper §2.2.4 (1), improved):

1. **Solid proxy.** MCF (CGAL, via ``compas_cgal``) contracts a *surface*; on a thin-walled
   hollow tube it converges onto the wall (a genus-1 tube gives a loop, not its axis). The
   skeleton is therefore taken of the part's envelope: the part is rasterised by manifold3d
   slices, morphologically closed (EDT dilate/erode by half its smallest extent, which fills
   bores) and re-meshed with ``Manifold.level_set``. This coarse proxy (~1–5k triangles) also
   keeps MCF fast.
2. **MCF skeleton** of the proxy (``compas_cgal.skeletonization.mesh_skeleton``).
3. **Main chain**: the skeleton graph's longest shortest path from the node nearest the base
   centre, prefixed by the base centre itself.
4. **Fit**: the paper fits y(x), z(x) polynomials, which fail when a branch is vertical (x is
   constant). Here a parametric smoothing spline p(u) (``scipy.interpolate.splprep``) is fitted
   and re-parameterised by arc length s through a dense table. Straight chains (deviation from
   their least-squares line below :data:`TOL.straight_rel` of the length or
   :data:`TOL.straight_thick` of the part's smallest extent) degenerate to that axis, snapped to
   the base normal within :data:`TOL.snap_deg` (so a straight root prints straight up); when MCF
   fails or gives too short a chain, the fallback is the PCA axis of the part from its base.

Beyond its ends the curve continues straight along its end tangents, so slicing can run past
the (always slightly short) MCF skeleton to the end of the part.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import manifold3d as m3
import numpy as np
import shapely
import trimesh
from compas_cgal.skeletonization import mesh_skeleton
from numpy.typing import ArrayLike
from scipy import ndimage
from scipy.interpolate import splev, splprep
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from slicer.planes2d import TOL, cross_section_polygons, to_manifold, unit

PROXY_CELLS = 16  # grid cells along the largest extent of the solid proxy
TABLE_SIZE = 2048  # samples of the arc-length table
CHAIN_STEP = 1.0  # resampling step of the skeleton chain before fitting, mm


@dataclass(frozen=True)
class SkeletonCurve:
    """A curve p(s) parameterised by arc length s ∈ [0, length], extended straight beyond.

    Attributes
    ----------
    tck : tuple
        ``splprep`` representation over u ∈ [0, 1].
    u_table, s_table : (k,) float
        Dense monotone table u ↔ s.
    source : str
        "mcf", "axis" (straight chain) or "pca" (fallback).
    line : ((3,) float, (3,) float) or None
        Start and unit direction when the curve is a straight segment: p(s) and τ(s) are then
        evaluated directly (the root's ~300 layers each ask for both several times).
    """

    tck: tuple
    u_table: np.ndarray
    s_table: np.ndarray
    source: str
    line: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def length(self) -> float:
        """Arc length of the fitted part, mm."""
        return float(self.s_table[-1])

    def u_of_s(self, s: ArrayLike) -> np.ndarray:
        """Spline parameter at arc lengths ``s`` (clamped to [0, 1]), (n,) float."""
        return np.interp(np.asarray(s, dtype=float), self.s_table, self.u_table)

    def s_of_u(self, u: ArrayLike) -> np.ndarray:
        """Arc length at spline parameters ``u``, (n,) float."""
        return np.interp(np.asarray(u, dtype=float), self.u_table, self.s_table)

    def point(self, s: ArrayLike) -> np.ndarray:
        """p(s), (n, 3) float; linear continuation along the end tangents outside [0, L]."""
        s = np.atleast_1d(np.asarray(s, dtype=float))
        if self.line is not None:
            return self.line[0] + s[:, None] * self.line[1]
        sc = np.clip(s, 0.0, self.length)
        p = np.column_stack(splev(self.u_of_s(sc), self.tck))
        return p + (s - sc)[:, None] * self.tangent(sc)

    def tangent(self, s: ArrayLike) -> np.ndarray:
        """Unit tangent τ(s), (n, 3) float (end tangents outside [0, L])."""
        s = np.atleast_1d(np.asarray(s, dtype=float)).clip(0.0, self.length)
        if self.line is not None:
            return np.repeat(self.line[1][None, :], len(s), axis=0)
        d = np.column_stack(splev(self.u_of_s(s), self.tck, der=1))
        return unit(d)[0]

    def project(self, points: ArrayLike) -> np.ndarray:
        """Arc length of the table sample nearest each point, (n,) float."""
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        table = np.column_stack(splev(self.u_table, self.tck))
        d = np.linalg.norm(p[:, None, :] - table[None, :, :], axis=2)
        return self.s_table[np.argmin(d, axis=1)]


def fit_curve(points: ArrayLike, smoothing: float = 0.0, source: str = "mcf") -> SkeletonCurve:
    """Fit a parametric spline through ordered points and tabulate its arc length.

    Parameters
    ----------
    points : (n, 3) float, n >= 2
        Ordered chain; duplicates are dropped.
    smoothing : float
        ``splprep`` smoothing ``s`` (sum of squared residuals allowed), mm².
    """
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    keep = np.r_[True, np.linalg.norm(np.diff(p, axis=0), axis=1) > 1e-9]
    p = p[keep]
    if len(p) < 2:
        raise ValueError("a curve needs two distinct points")
    chord = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))]
    k = min(3, len(p) - 1)
    tck, _ = splprep(p.T, u=chord / chord[-1], k=k, s=smoothing)
    u = np.linspace(0.0, 1.0, TABLE_SIZE)
    q = np.column_stack(splev(u, tck))
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(q, axis=0), axis=1))]
    return SkeletonCurve(tck=tck, u_table=u, s_table=s, source=source)


def line_curve(start: ArrayLike, direction: ArrayLike, length: float,
               source: str = "axis") -> SkeletonCurve:
    """A straight curve from ``start`` along ``direction`` for ``length`` mm."""
    d = unit(direction)[0][0]
    a = np.asarray(start, dtype=float)
    curve = fit_curve(np.vstack([a, a + max(length, 1e-3) * d]), source=source)
    return replace(curve, line=(a.copy(), d))


def solid_proxy(mesh: trimesh.Trimesh, cells: int = PROXY_CELLS
                ) -> tuple[np.ndarray, np.ndarray] | None:
    """A coarse watertight envelope of ``mesh`` with bores closed, as (V (n, 3), F (m, 3)).

    Returns ``None`` when the mesh is not a valid solid or the proxy is empty.
    """
    solid = to_manifold(mesh)
    if solid.is_empty():
        return None
    lo, hi = (np.asarray(b, dtype=float) for b in mesh.bounds)
    ext = hi - lo
    pitch = float(ext.max()) / cells
    radius = 0.5 * float(ext.min())
    pad = radius + 2.0 * pitch
    lo = lo - pad
    nz, ny, nx = (int(n) for n in (np.ceil((hi + pad - lo) / pitch).astype(int) + 1)[::-1])
    occ = _occupancy(solid, lo, pitch, (nz, ny, nx))
    if not occ.any():
        return None
    grown = ndimage.distance_transform_edt(~occ) * pitch <= radius
    closed = ndimage.distance_transform_edt(grown) * pitch > radius
    closed |= occ
    sdf = ndimage.distance_transform_edt(closed) - ndimage.distance_transform_edt(~closed)
    sdf = ndimage.gaussian_filter(sdf.astype(float), 0.7)
    box = _level_box(closed, lo, pitch)
    out = m3.Manifold.level_set(_trilinear(sdf, lo, pitch), box, pitch, 0.0)
    if out.is_empty() or out.status() != m3.Error.NoError:
        return None
    m = out.to_mesh()
    return (np.asarray(m.vert_properties, dtype=float)[:, :3],
            np.asarray(m.tri_verts, dtype=np.int64))


def _level_box(closed: np.ndarray, lo: np.ndarray, pitch: float) -> list[float]:
    """Bounds [x0, y0, z0, x1, y1, z1] of the occupied nodes grown by two pitches (the level
    set is only evaluated there: the dilation padding of the grid is empty)."""
    idx = np.argwhere(closed)  # (k, 3) in z, y, x order
    a = lo + pitch * (idx.min(axis=0)[::-1] - 2)
    b = lo + pitch * (idx.max(axis=0)[::-1] + 2)
    return [*a, *b]


def _occupancy(solid: m3.Manifold, lo: np.ndarray, pitch: float,
               shape: tuple[int, int, int]) -> np.ndarray:
    """(nz, ny, nx) bool: grid nodes inside the solid (one manifold slice per z row)."""
    nz, ny, nx = shape
    x, y = np.meshgrid(lo[0] + pitch * np.arange(nx), lo[1] + pitch * np.arange(ny))
    occ = np.zeros(shape, dtype=bool)
    for k in range(nz):
        poly = cross_section_polygons(solid.slice(lo[2] + pitch * k))
        if not poly.is_empty:
            occ[k] = shapely.contains_xy(poly, x, y)
    return occ


def _trilinear(grid: np.ndarray, lo: np.ndarray, pitch: float
               ) -> Callable[[float, float, float], float]:
    """A scalar callable f(x, y, z) interpolating ``grid`` (z, y, x order) trilinearly.

    Manifold's ``level_set`` calls it once per lattice point from C++, so it works on nested
    Python lists (numpy scalar indexing costs more than the arithmetic).
    """
    g = grid.tolist()
    hz, hy, hx = (n - 2 for n in grid.shape)
    x0, y0, z0 = (float(v) for v in lo)
    inv = 1.0 / pitch

    def f(x: float, y: float, z: float) -> float:
        fi, fj, fk = (z - z0) * inv, (y - y0) * inv, (x - x0) * inv
        i = min(max(int(fi), 0), hz)
        j = min(max(int(fj), 0), hy)
        k = min(max(int(fk), 0), hx)
        a, b, c = fi - i, fj - j, fk - k
        p0, p1 = g[i], g[i + 1]
        r00, r01, r10, r11 = p0[j], p0[j + 1], p1[j], p1[j + 1]
        c00 = r00[k] + (r00[k + 1] - r00[k]) * c
        c01 = r01[k] + (r01[k + 1] - r01[k]) * c
        c10 = r10[k] + (r10[k + 1] - r10[k]) * c
        c11 = r11[k] + (r11[k + 1] - r11[k]) * c
        return (c00 + (c01 - c00) * b) * (1 - a) + (c10 + (c11 - c10) * b) * a

    return f


def mcf_edges(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """MCF skeleton edges of a closed manifold mesh, (k, 2, 3) float (empty on failure)."""
    try:
        edges = mesh_skeleton((vertices, faces))
    except (RuntimeError, ValueError, TypeError):
        return np.zeros((0, 2, 3))
    return np.asarray(edges, dtype=float).reshape(-1, 2, 3)


def main_chain(edges: np.ndarray, start: ArrayLike) -> np.ndarray:
    """The skeleton's longest shortest path from the node nearest ``start``.

    Parameters
    ----------
    edges : (k, 2, 3) float
    start : (3,) float

    Returns
    -------
    (m, 3) float
        Ordered nodes (m may be 0 or 1 for an empty/degenerate skeleton).
    """
    if len(edges) == 0:
        return np.zeros((0, 3))
    nodes, inv = np.unique(np.round(edges.reshape(-1, 3), 9), axis=0, return_inverse=True)
    inv = inv.reshape(-1, 2)
    w = np.linalg.norm(nodes[inv[:, 0]] - nodes[inv[:, 1]], axis=1) + 1e-12
    n = len(nodes)
    graph = coo_matrix((np.r_[w, w], (np.r_[inv[:, 0], inv[:, 1]], np.r_[inv[:, 1], inv[:, 0]])),
                       shape=(n, n)).tocsr()
    root = int(np.argmin(np.linalg.norm(nodes - np.asarray(start, dtype=float), axis=1)))
    dist, pred = dijkstra(graph, indices=root, return_predecessors=True)
    dist[~np.isfinite(dist)] = -1.0
    node = int(np.argmax(dist))
    path = [node]
    while pred[node] >= 0:
        node = int(pred[node])
        path.append(node)
    return nodes[path[::-1]]


def _resample(chain: np.ndarray, step: float) -> np.ndarray:
    """Chain resampled every ``step`` mm of polyline length (ends kept), (m, 3) float."""
    seg = np.linalg.norm(np.diff(chain, axis=0), axis=1)
    s = np.r_[0.0, np.cumsum(seg)]
    if s[-1] <= step:
        return chain[[0, -1]]
    t = np.linspace(0.0, s[-1], int(np.ceil(s[-1] / step)) + 1)
    return np.column_stack([np.interp(t, s, chain[:, i]) for i in range(3)])


def _axis_fit(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares line direction of ``points`` and the largest deviation from it."""
    c = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - c)
    d = vt[0]
    rel = points - c
    dev = np.linalg.norm(rel - np.outer(rel @ d, d), axis=1)
    return d, float(dev.max())


def pca_axis(mesh: trimesh.Trimesh, normal: ArrayLike) -> np.ndarray:
    """Principal axis of the mesh surface (area-weighted), oriented along ``normal``, (3,)."""
    w = mesh.area_faces
    c = mesh.triangles_center
    mean = (w[:, None] * c).sum(axis=0) / w.sum()
    cov = ((c - mean).T * w) @ (c - mean)
    d = np.linalg.eigh(cov)[1][:, -1]
    n = unit(normal)[0][0]
    d = d if d @ n >= 0 else -d
    return d if d @ n > 0.3 else n


def skeleton_curve(mesh: trimesh.Trimesh, start: ArrayLike, normal: ArrayLike,
                   cells: int = PROXY_CELLS) -> SkeletonCurve:
    """The skeleton curve of a sub-part from the centre of its base.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Watertight sub-part, platform frame.
    start : (3,) float
        Centre of the base section (the curve starts here).
    normal : (3,) float
        Base normal pointing into the part.
    cells : int
        Resolution of the solid proxy.

    Returns
    -------
    SkeletonCurve
        ``source`` tells which branch produced it ("mcf", "axis", "pca").
    """
    a = np.asarray(start, dtype=float)
    n = unit(normal)[0][0]
    extent = float(np.linalg.norm(mesh.extents))
    proxy = solid_proxy(mesh, cells)
    chain = np.zeros((0, 3)) if proxy is None else main_chain(mcf_edges(*proxy), a)
    if len(chain):
        chain = chain[(chain - a) @ n > 0.02 * extent]  # drop skeleton bits at the base face
    if len(chain) < 2 or np.linalg.norm(chain[-1] - a) < 0.1 * extent:
        return line_curve(a, pca_axis(mesh, n), _reach(mesh, a, pca_axis(mesh, n)), "pca")
    chain = _resample(np.vstack([a, chain]), CHAIN_STEP)
    d, dev = _axis_fit(chain)
    length = float(np.linalg.norm(chain[-1] - chain[0]))
    if dev < max(TOL.straight_abs, TOL.straight_rel * length,
                 TOL.straight_thick * float(mesh.extents.min())):
        d = d if d @ (chain[-1] - a) > 0 else -d
        d = n if np.degrees(np.arccos(np.clip(d @ n, -1.0, 1.0))) < TOL.snap_deg else d
        return line_curve(a, d, _reach(mesh, a, d), "axis")
    sigma = 0.25 * float(mesh.extents.max()) / cells
    return fit_curve(chain, smoothing=len(chain) * sigma**2, source="mcf")


def _reach(mesh: trimesh.Trimesh, start: np.ndarray, d: np.ndarray) -> float:
    """How far the mesh extends from ``start`` along ``d``, mm."""
    return float(np.max((mesh.vertices - start) @ d))
