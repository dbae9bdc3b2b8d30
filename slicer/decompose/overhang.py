"""Overhang of a decomposition: the surface each sub-part would print in the air.

A face of a sub-part overhangs when its outward normal points further below the plane square
to the sub-part's build direction than :attr:`~slicer.planes2d.Tolerances.overhang_deg`
(n·d < -sin(limit)); a face straight down (n·d = -1) overhangs by 90°. Faces on cuts are not
counted: the sub-part's own base (it rests on its parent's cut face) and its faces on the
base planes of its children (the child is printed onto them), and for the root the faces
resting on the platform z = 0.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import trimesh

from slicer.decompose.planes import Plane
from slicer.planes2d import TOL


@dataclass(frozen=True)
class Overhang:
    """Overhanging surface of one sub-part.

    Attributes
    ----------
    index : int
        The sub-part.
    area : float
        Overhanging area, mm².
    point : (3,) float or None
        A point on the sub-part's surface in the overhang (the centroid of the overhanging
        face nearest to the overhang's area centroid); ``None`` when there is none.
    """

    index: int
    area: float
    point: np.ndarray | None


def overhanging_faces(mesh: trimesh.Trimesh, direction: np.ndarray, cuts: Sequence[Plane],
                      on_platform: bool, limit_deg: float = TOL.overhang_deg) -> np.ndarray:
    """Which faces of ``mesh`` overhang when it is printed along ``direction``.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        A sub-part, (f,) faces.
    direction : (3,) float
        Unit build direction.
    cuts : sequence of Plane
        Cut planes of the sub-part (its base and its children's bases); faces lying on one of
        them, parallel to it, are not counted.
    on_platform : bool
        The sub-part rests on z = 0 (the root): faces on z = 0 facing -Z are not counted.
    limit_deg : float
        Overhang limit from the horizontal of the build frame, degrees.

    Returns
    -------
    (f,) bool
    """
    n = np.asarray(mesh.face_normals, dtype=float)
    c = np.asarray(mesh.triangles_center, dtype=float)
    over = n @ np.asarray(direction, dtype=float) < -np.sin(np.radians(limit_deg))
    over &= ~on_cuts(mesh, cuts)
    if on_platform:
        over &= ~((np.abs(c[:, 2]) < TOL.cut_tol) & (n[:, 2] < -TOL.cut_cos))
    return over


def on_cuts(mesh: trimesh.Trimesh, cuts: Sequence[Plane]) -> np.ndarray:
    """Which faces of ``mesh`` lie on one of the ``cuts``, parallel to it, (f,) bool."""
    if not cuts:
        return np.zeros(len(mesh.faces), dtype=bool)
    n = np.asarray(mesh.face_normals, dtype=float)
    c = np.asarray(mesh.triangles_center, dtype=float)
    points = np.stack([np.asarray(p.point, dtype=float) for p in cuts])  # (m, 3)
    normals = np.stack([np.asarray(p.normal, dtype=float) for p in cuts])  # (m, 3)
    dist = np.abs(np.einsum("fk,mk->fm", c, normals) - (points * normals).sum(axis=1))
    par = np.abs(n @ normals.T) > TOL.cut_cos  # (f, m)
    return ((dist < TOL.cut_tol) & par).any(axis=1)


def subpart_overhang(index: int, mesh: trimesh.Trimesh, direction: np.ndarray,
                     cuts: Sequence[Plane], on_platform: bool) -> Overhang:
    """Overhanging area of one sub-part and a point of it on the surface.

    Parameters are those of :func:`overhanging_faces`; ``index`` names the sub-part.
    """
    over = overhanging_faces(mesh, direction, cuts, on_platform)
    areas = np.asarray(mesh.area_faces)[over]
    total = float(areas.sum())
    if not over.any() or total <= 0.0:
        return Overhang(index, 0.0, None)
    centres = np.asarray(mesh.triangles_center)[over]
    mean = (centres * areas[:, None]).sum(axis=0) / total
    near = int(np.argmin(np.linalg.norm(centres - mean, axis=1)))
    return Overhang(index, total, centres[near].copy())


def decomposition_overhang(meshes: Sequence[trimesh.Trimesh], parents: Sequence[int | None],
                           bases: Sequence[Plane | None], directions: Sequence[np.ndarray]
                           ) -> list[Overhang]:
    """Overhang of every sub-part of a decomposition.

    Parameters
    ----------
    meshes : sequence of trimesh.Trimesh
        Sub-parts, indexed as the other sequences (length s).
    parents : sequence of int or None
        Parent of each sub-part (``None`` for the root, which rests on the platform).
    bases : sequence of Plane or None
        Base plane of each sub-part (``None`` for the root).
    directions : sequence of (3,) float
        Build direction of each sub-part.

    Returns
    -------
    list of Overhang
        One per sub-part, in index order.
    """
    cuts: list[list[Plane]] = [[] if b is None else [b] for b in bases]
    for k, (parent, base) in enumerate(zip(parents, bases, strict=True)):
        if parent is not None and base is not None and k != parent:
            cuts[parent].append(base)
    return [subpart_overhang(k, m, d, cuts[k], parents[k] is None)
            for k, (m, d) in enumerate(zip(meshes, directions, strict=True))]


__all__ = ["Overhang", "decomposition_overhang", "overhanging_faces", "subpart_overhang"]
