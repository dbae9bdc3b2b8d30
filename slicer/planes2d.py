"""Plane frames and planar cross-sections of solids.

A layer lives in a plane through ``origin`` with unit ``normal``; its 2D coordinates are taken
in an orthonormal frame ``(u, v, n)`` stored as the rows of a (3, 3) matrix. Frames of
consecutive layers are parallel-transported (:func:`transport_frame`) so that 2D directions
(infill angles) stay continuous when the normal turns.

Cross-sections are cut with manifold3d: the solid is moved so the plane becomes z = 0 with
``u, v`` on x, y, then ``Manifold.slice`` gives the polygons directly in the plane's frame.

The tolerances of the whole slicing stage live here (:data:`TOL`).
"""

from __future__ import annotations

from dataclasses import dataclass

import manifold3d as m3
import numpy as np
import shapely
import shapely.affinity
import trimesh
from numpy.typing import ArrayLike
from shapely.geometry.base import BaseGeometry


@dataclass(frozen=True)
class Tolerances:
    """Every tolerance of the slicing stage, in one place (mm unless noted)."""

    unit: float = 1e-12  # a vector shorter than this has no direction
    min_area: float = 1e-4  # polygons smaller than this (mm²) are dropped
    min_path: float = 1e-3  # paths shorter than this are dropped
    contain: float = 1e-6  # containment slack of generated paths
    simplify: float = 0.01  # section outline simplification, mm (≪ line width)
    mesh_simplify: float = 0.005  # solid simplification before slicing, mm (< simplify)
    same: float = 1e-6  # vertex tolerance of "the same polygon" in consecutive layers, mm
    straight_rel: float = 0.03  # skeleton deviation / length below which a part is straight
    straight_abs: float = 0.5  # ... or below this absolute deviation
    straight_thick: float = 0.15  # ... or below this fraction of the part's smallest extent
    snap_deg: float = 5.0  # a straight axis this close to the base normal is the base normal
    turn_margin: float = 0.9  # fraction of the thickness slack a turn may use
    end_share: float = 0.5  # a sub-part's flat far end at least this share of a layer above
    #                         the last layer's plane gets a layer of its own, no thinner
    #                         (slicer.paths.layers.fit_end)
    # decomposition (slicer.decompose.overhang, slicer.decompose.decomposition)
    overhang_deg: float = 45.0  # a face overhangs when its normal points further below
    #                             the plane square to the build direction (FDM's 45° rule)
    cut_tol: float = 1e-3  # mm: a face this close to a cut plane (or z = 0) lies on it
    cut_cos: float = 0.999  # |n · plane normal| above this: a face is parallel to a cut
    overhang_retry_abs: float = 5.0  # mm²: a decomposition overhanging more than this ...
    overhang_retry_rel: float = 0.01  # ... and this share of the surface: try other seeds
    overhang_refuse_abs: float = 100.0  # mm²: a sub-part of the best result overhanging more
    overhang_refuse_rel: float = 0.05  # ... and than this share of the surface: refused
    retry_seeds: int = 4  # further (seed, K) attempts after the configured one
    min_volume_share: float = 1e-3  # a sub-part below this share of the volume is degenerate
    min_base_share: float = 1e-3  # ... or with a base below this share of (volume)^(2/3)
    base_ratio: float = 4.0  # a flat face this many times the base stood on is much larger:
    #                          tried when the part as placed is refused or overhangs (over the
    #                          retry threshold), named in a warning otherwise
    #                          (slicer.decompose.bases)
    base_tries: int = 2  # at most this many such faces are tried, largest first
    # placement (slicer.mesh.placement.canonical_mesh)
    snap_grid: float = 1e-6  # mm: placed vertices are rounded to this grid, so the residue
    #                          of a translation the placement undoes is gone (not a power of
    #                          two: float32 STL coordinates would sit exactly on its half-steps)


TOL = Tolerances()


def unit(v: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Row-normalise vectors.

    Parameters
    ----------
    v : (n, 3) float

    Returns
    -------
    unit : (n, 3) float
        Unit vectors (zero rows stay zero).
    valid : (n,) bool
        Rows that had a direction.
    """
    a = np.asarray(v, dtype=float).reshape(-1, 3)
    n = np.linalg.norm(a, axis=1)
    ok = np.isfinite(n) & (n > TOL.unit)
    out = np.zeros_like(a)
    out[ok] = a[ok] / n[ok, None]
    return out, ok


def plane_frame(normal: ArrayLike, hint: ArrayLike | None = None) -> np.ndarray:
    """An orthonormal frame whose third row is the unit ``normal``.

    Parameters
    ----------
    normal : (3,) float
    hint : (3,) float, optional
        Preferred direction of the first axis (projected into the plane); +X, then +Y if
        parallel to the normal.

    Returns
    -------
    (3, 3) float
        Rows ``u, v, n`` (right-handed).
    """
    n = unit(normal)[0][0]
    for h in ([] if hint is None else [hint]) + [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]:
        h = np.asarray(h, dtype=float)
        u, ok = unit(h - (h @ n) * n)
        if ok[0] and np.linalg.norm(h - (h @ n) * n) > 1e-6:
            u = u[0]
            return np.vstack([u, np.cross(n, u), n])
    raise ValueError(f"normal {n.tolist()} has no frame")


def transport_frame(frame: np.ndarray, normal: ArrayLike) -> np.ndarray:
    """The frame of a new ``normal`` whose first axis stays as close to ``frame[0]`` as it can."""
    return plane_frame(normal, hint=frame[0])


def to_plane(points: ArrayLike, origin: ArrayLike, frame: np.ndarray) -> np.ndarray:
    """Platform-frame points in plane coordinates.

    Parameters
    ----------
    points : (n, 3) float
    origin : (3,) float
    frame : (3, 3) float

    Returns
    -------
    (n, 3) float
        ``(x, y, height above the plane)``.
    """
    return (np.asarray(points, dtype=float).reshape(-1, 3) - np.asarray(origin)) @ frame.T


def from_plane(xy: ArrayLike, origin: ArrayLike, frame: np.ndarray) -> np.ndarray:
    """Plane coordinates (n, 2) or (n, 3) back to platform-frame points (n, 3)."""
    a = np.asarray(xy, dtype=float)
    a = np.hstack([a, np.zeros((len(a), 1))]) if a.shape[1] == 2 else a
    return a @ frame + np.asarray(origin, dtype=float)


def to_manifold(mesh: trimesh.Trimesh) -> m3.Manifold:
    """A watertight trimesh as a manifold3d solid (empty if it is not a valid manifold)."""
    return m3.Manifold(m3.Mesh64(np.array(mesh.vertices, dtype=np.float64, order="C"),
                                 np.array(mesh.faces, dtype=np.uint64, order="C")))


def slicing_solid(mesh: trimesh.Trimesh) -> m3.Manifold:
    """The solid to cut sections from: ``mesh`` simplified by :data:`TOL.mesh_simplify`.

    Manifold's ``simplify`` collapses edges that move the surface by less than the tolerance
    (a subdivided or finely tessellated STL of 33k faces drops to ~3k), which makes every
    section 3–6× cheaper; sections are simplified by the larger :data:`TOL.simplify` anyway.
    """
    solid = to_manifold(mesh)
    return solid.simplify(TOL.mesh_simplify) if TOL.mesh_simplify > 0 else solid


def cross_section_polygons(cs: m3.CrossSection) -> BaseGeometry:
    """A manifold3d CrossSection as a valid shapely (Multi)Polygon (possibly empty)."""
    polys = []
    for part in cs.decompose():
        rings = [np.asarray(r, dtype=float) for r in part.to_polygons() if len(r) >= 3]
        if not rings:
            continue
        areas = np.array([_signed_area(r) for r in rings])
        k = int(np.argmax(areas))
        polys.append(shapely.Polygon(rings[k], [r for i, r in enumerate(rings) if i != k]))
    return polygonal(shapely.MultiPolygon(polys)) if polys else shapely.Polygon()


_POLYGON, _MULTI, _COLLECTION = 3, 6, 7  # shapely type ids


def polygonal(geom: BaseGeometry, valid: bool = False) -> BaseGeometry:
    """Only the polygonal parts of ``geom`` above :data:`TOL.min_area`, made valid.

    Parameters
    ----------
    geom : shapely geometry
    valid : bool
        The caller knows ``geom`` is valid (GEOS overlay and buffer results are): the validity
        check, which costs as much as a small boolean, is skipped.

    Returns
    -------
    shapely Polygon or MultiPolygon
        Possibly empty.
    """
    if not valid and not shapely.is_valid(geom):
        geom = shapely.make_valid(geom)
    if shapely.get_type_id(geom) == _POLYGON:  # the common case, without array round trips
        return geom if shapely.area(geom) > TOL.min_area else shapely.Polygon()
    parts = shapely.get_parts(geom)
    kind = shapely.get_type_id(parts)
    while ((kind == _MULTI) | (kind == _COLLECTION)).any():
        nested = (kind == _MULTI) | (kind == _COLLECTION)
        parts = np.concatenate([parts[~nested], shapely.get_parts(parts[nested])])
        kind = shapely.get_type_id(parts)
    keep = parts[(kind == _POLYGON) & (shapely.area(parts) > TOL.min_area)]
    if len(keep) == 0:
        return shapely.Polygon()
    return keep[0] if len(keep) == 1 else shapely.MultiPolygon(list(keep))


def _signed_area(ring: np.ndarray) -> float:
    """Shoelace area of a ring (n, 2) without its closing vertex, > 0 counter-clockwise."""
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * float(x[:-1] @ y[1:] - x[1:] @ y[:-1] + x[-1] * y[0] - x[0] * y[-1])


def section(solid: m3.Manifold, origin: ArrayLike, frame: np.ndarray) -> BaseGeometry:
    """The cross-section of ``solid`` by the plane (origin, frame[2]) in the plane's 2D frame.

    Simplified by :data:`TOL.simplify` with Clipper2 (``CrossSection.simplify``) before the
    shapely polygons are built: a finely tessellated STL gives thousands of vertices per
    section, which every later boolean pays for, and Clipper's output stays a valid polygon set
    (simplifying in GEOS without topology preservation often needs a 10 ms ``make_valid``).

    Returns
    -------
    shapely Polygon or MultiPolygon
        Possibly empty.
    """
    o = np.asarray(origin, dtype=float)
    if np.array_equal(frame, np.eye(3)):  # horizontal, unrotated: slice in place (no copy)
        cs, shift = solid.slice(o[2]), (-o[0], -o[1])
    else:
        mat = np.hstack([frame, -(frame @ o).reshape(3, 1)])
        cs, shift = solid.transform(mat).slice(0.0), None
    if TOL.simplify > 0:
        cs = cs.simplify(TOL.simplify)
    region = cross_section_polygons(cs)
    return region if shift is None else shapely.affinity.translate(region, *shift)


def map_between(geom: BaseGeometry, src: tuple[np.ndarray, np.ndarray],
                dst: tuple[np.ndarray, np.ndarray]) -> BaseGeometry:
    """Project a 2D geometry of plane ``src = (origin, frame)`` into plane ``dst``'s 2D frame.

    The projection is orthogonal onto ``dst`` (an affine map of the plane coordinates).
    """
    (o1, f1), (o2, f2) = src, dst
    lin = f2[:2] @ f1[:2].T  # (2, 2): dst axes · src axes
    off = f2[:2] @ (o1 - o2)
    return shapely.affinity.affine_transform(
        geom, [lin[0, 0], lin[0, 1], lin[1, 0], lin[1, 1], off[0], off[1]])
