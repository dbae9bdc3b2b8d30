"""Where a part stands: its flat bases, its placement on the platform, its canonical order.

:func:`place_on_platform` finds the flat base (:func:`find_base`: the part's own bottom, else
the largest flat region on its convex hull, :func:`flat_bases`) and returns the part in the
platform frame (z up, base on z = 0, base centroid on the C axis) together with the 4×4
placement matrix that every later output carries. A placed mesh is put in canonical order
on the snap grid (:func:`canonical_mesh`), so what follows depends on the shape only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from slicer.mesh.errors import MeshError
from slicer.planes2d import TOL

#: A direction no structured mesh is aligned with: the first key of the canonical order.
GENERIC = np.array([0.5377, 0.7185, 0.4411]) / np.linalg.norm([0.5377, 0.7185, 0.4411])

#: Tolerances of this module (mm, or cosines of angles).
PLANE_TOL = 1e-3  # distance of a face from its base plane, mm
NORMAL_COS = np.cos(np.radians(1.0))  # a face "faces down" within 1°
MIN_BASE_AREA = 1.0  # a flat base smaller than this (mm²) is no base


@dataclass(frozen=True)
class Placement:
    """Where the flat base was found and how the part was moved onto the platform.

    Attributes
    ----------
    matrix : (4, 4) float
        Input frame → platform frame.
    base_area : float
        Area of the flat base, mm².
    base_normal : (3,) float
        Outward normal of the base in the input frame.
    merged_shells : int
        How many overlapping closed shells of the file were merged into the one solid (0 when
        the file held one).
    """

    matrix: np.ndarray
    base_area: float
    base_normal: np.ndarray
    merged_shells: int = 0


@dataclass(frozen=True)
class BaseChoice:
    """Which flat face a decomposed part stands on, and why (:mod:`slicer.decompose.bases`).

    Attributes
    ----------
    area : float
        Area of the face it stands on, mm².
    normal : (3,) float
        That face's outward normal in the file's frame.
    turn : (4, 4) float or None
        Placed frame as loaded → the frame it stands in (:func:`moved` gives the mesh), or
        None when it stands as loaded.
    note : str or None
        One line for the user: why it was turned, or a much larger flat face it could stand
        on; None when there is nothing to say.
    tried : tuple of str
        One line per face tried, in order (face, outcome).
    """

    area: float
    normal: np.ndarray
    turn: np.ndarray | None = None
    note: str | None = None
    tried: tuple[str, ...] = ()

    def to_json(self) -> dict[str, object]:
        """The ``base`` entry of ``decomposition.json``."""
        return {"area_mm2": self.area, "normal_in_file": np.asarray(self.normal).tolist(),
                "turned": self.turn is not None, "note": self.note, "tried": list(self.tried)}


@dataclass(frozen=True)
class FlatBase:
    """A flat region of the surface on a supporting plane: a base the part can stand on.

    Attributes
    ----------
    normal : (3,) float
        Outward unit normal of the plane, in the frame of the mesh it was found on.
    area : float
        Area of the faces on the plane, mm².
    faces : (m,) int
        Those faces.
    """

    normal: np.ndarray
    area: float
    faces: np.ndarray


def find_base(mesh: trimesh.Trimesh) -> tuple[np.ndarray, float, np.ndarray]:
    """The flat base: the largest downward planar region at the lowest height.

    The part's own orientation is tried first (faces facing -Z at the lowest z); when it has
    no flat bottom, the planes of the convex hull are tried and the one holding the most
    coplanar face area wins (the first of :func:`flat_bases`).

    Returns
    -------
    normal : (3,) float
        Outward unit normal of the base.
    area : float
        Base area, mm² (0 when there is no base).
    faces : (m,) int
        Faces on the base.
    """
    down = np.array([0.0, 0.0, -1.0])
    faces, area = _faces_on_plane(mesh, down)
    if area >= MIN_BASE_AREA:
        return down, area, faces
    bases = flat_bases(mesh, min_area=0.0)
    if not bases or bases[0].area <= area:
        return down, area, faces
    return bases[0].normal, bases[0].area, bases[0].faces


def flat_bases(mesh: trimesh.Trimesh, min_area: float = MIN_BASE_AREA) -> list[FlatBase]:
    """Every flat region on a plane of the convex hull, largest first.

    A face lies on the hull plane with outward normal n when its own normal is within 1° of n
    (:data:`NORMAL_COS`) and its centroid within :data:`PLANE_TOL` of the plane. Face/plane
    pairs come from a KD-tree over the normals (no faces × planes matrix). Regions of equal
    area keep the order of the hull's planes (its facets, then its faces in no facet), so the
    order depends on the shape only.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Watertight, n faces.
    min_area : float
        Smallest area kept, mm² (regions of no area are never kept).

    Returns
    -------
    list of FlatBase
        Regions of at least ``min_area``, by decreasing area.
    """
    normals, heights = _hull_planes(mesh.convex_hull)
    chord = 2.0 * np.sin(np.arccos(NORMAL_COS) / 2.0)  # 1° between unit vectors
    pairs = cKDTree(mesh.face_normals).sparse_distance_matrix(
        cKDTree(normals), chord, output_type="ndarray")
    face, plane = pairs["i"].astype(np.int64), pairs["j"].astype(np.int64)
    cos = np.einsum("ij,ij->i", mesh.face_normals[face], normals[plane])
    gap = np.einsum("ij,ij->i", mesh.triangles_center[face], normals[plane]) - heights[plane]
    keep = (cos >= NORMAL_COS) & (np.abs(gap) <= PLANE_TOL)
    face, plane = face[keep], plane[keep]
    area = np.bincount(plane, weights=mesh.area_faces[face], minlength=len(normals))
    ranked = np.argsort(-np.round(area, 6), kind="stable")
    ranked = ranked[(area[ranked] >= min_area) & (area[ranked] > 0.0)]
    return [FlatBase(normals[j], float(area[j]), np.sort(face[plane == j])) for j in ranked]


def _hull_planes(hull: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    """Outward unit normals (h, 3) and heights (h,) of the planes of a convex hull: its
    facets (coplanar faces), then its faces in no facet."""
    alone = np.ones(len(hull.faces), dtype=bool)
    if len(hull.facets):
        alone[np.concatenate(hull.facets)] = False
        normals = np.vstack([hull.facets_normal, hull.face_normals[alone]])
        points = np.vstack([hull.facets_origin, hull.triangles[alone, 0]])
    else:
        normals, points = hull.face_normals, hull.triangles[:, 0]
    normals = np.asarray(normals, dtype=float)
    return normals, np.einsum("ij,ij->i", np.asarray(points, dtype=float), normals)


def _faces_on_plane(mesh: trimesh.Trimesh, normal: np.ndarray) -> tuple[np.ndarray, float]:
    """Faces facing ``normal`` on the extreme supporting plane in that direction."""
    height = float((mesh.vertices @ normal).max())
    facing = mesh.face_normals @ normal >= NORMAL_COS
    on = np.abs(mesh.triangles_center @ normal - height) <= PLANE_TOL
    idx = np.flatnonzero(facing & on)
    return idx, float(mesh.area_faces[idx].sum())


def standing_base(mesh: trimesh.Trimesh) -> FlatBase:
    """The faces a placed part stands on: facing -Z on its lowest plane (z = 0)."""
    down = np.array([0.0, 0.0, -1.0])
    faces, area = _faces_on_plane(mesh, down)
    return FlatBase(down, area, faces)


def place_on_platform(mesh: trimesh.Trimesh, name: str = "<mesh>",
                      base: FlatBase | None = None) -> tuple[trimesh.Trimesh, Placement]:
    """Turn the base down onto z = 0 with its area centroid on the platform centre.

    ``base`` is the flat region to stand on (one of :func:`flat_bases`); by default the one
    :func:`find_base` picks.
    """
    if base is None:
        base = FlatBase(*find_base(mesh))
    normal, area, faces = base.normal, base.area, base.faces
    if area < MIN_BASE_AREA:
        dims = " × ".join(f"{x:.3g}" for x in mesh.extents)
        raise MeshError(f"{name}: no flat base of {MIN_BASE_AREA:g} mm² to stand on (largest "
                        f"planar face region {area:.3g} mm²; the part is {dims} mm)")
    matrix = trimesh.geometry.align_vectors(normal, [0.0, 0.0, -1.0])
    verts = trimesh.transform_points(mesh.vertices, matrix)
    tri = verts[mesh.faces[faces]]
    w = mesh.area_faces[faces]
    centre = (tri.mean(axis=1) * w[:, None]).sum(axis=0) / w.sum()
    shift = np.eye(4)
    shift[:3, 3] = (-centre[0], -centre[1], -verts[:, 2].min())
    matrix = shift @ matrix
    return moved(mesh, matrix), Placement(matrix, area, np.asarray(normal, dtype=float))


def moved(mesh: trimesh.Trimesh, matrix: np.ndarray) -> trimesh.Trimesh:
    """``mesh`` moved by the 4×4 ``matrix``, in canonical order (:func:`canonical_mesh`):
    the same matrix always gives the same mesh, wherever it is applied."""
    placed = mesh.copy()
    placed.apply_transform(matrix)
    return canonical_mesh(placed)


def canonical_mesh(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """``mesh`` snapped to ``TOL.snap_grid`` with its vertices and faces in a canonical order.

    The decomposition draws random samples over the face list and k-means seeds over them, so
    the order of the faces and any floating-point residue of the placement would change the
    result (a part shifted by 1 µm, or its faces shuffled, gave another branch direction).
    Vertices are rounded to ``TOL.snap_grid`` (1 nm, far below print resolution; its
    half-steps are not on the float32 lattice of STL coordinates, so no residue decides a
    tie), then sorted by their projection on :data:`GENERIC` (then x, y, z); every face
    starts at its lowest vertex (winding kept) and faces are sorted by their centroid's
    projection, then their vertices. The result depends on the shape only (a copy rounded
    to float32 far from the origin is another shape, by up to 6e-5 mm).

    Parameters
    ----------
    mesh : trimesh.Trimesh
        n vertices, m faces, in the platform frame.

    Returns
    -------
    trimesh.Trimesh
        Same shape (vertices moved by at most half the grid), (n, 3) vertices and (m, 3)
        faces in canonical order. Vertices the grid merges are welded, and faces that
        become degenerate dropped.
    """
    q = TOL.snap_grid
    verts = np.round(np.asarray(mesh.vertices, dtype=float) / q) * q + 0.0  # no -0.0
    faces = np.asarray(mesh.faces, dtype=np.int64)
    if len(np.unique(verts, axis=0)) < len(verts):  # sub-grid edges: weld, drop slivers
        welded = trimesh.Trimesh(verts, faces, process=True)
        welded.update_faces(welded.nondegenerate_faces())
        welded.remove_unreferenced_vertices()
        verts, faces = np.asarray(welded.vertices), np.asarray(welded.faces, dtype=np.int64)
    order = np.lexsort((verts[:, 2], verts[:, 1], verts[:, 0], verts @ GENERIC))
    rank = np.empty(len(order), dtype=np.int64)
    rank[order] = np.arange(len(order))
    verts, faces = verts[order], rank[faces]
    first = np.argmin(faces, axis=1)
    faces = faces[np.arange(len(faces))[:, None], (first[:, None] + np.arange(3)) % 3]
    centre = verts[faces].mean(axis=1) @ GENERIC
    faces = faces[np.lexsort((faces[:, 2], faces[:, 1], faces[:, 0], centre))]
    return trimesh.Trimesh(verts, faces, process=False)
