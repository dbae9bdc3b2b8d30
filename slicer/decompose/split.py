"""Splitting a piece along a separating plane into watertight solids (manifold3d).

The child is the union of the positive-side components that hold the child's faces; every
other positive-side component (for example the top of the main tube that a branch's plane also
crosses) stays with the parent, which is the negative side plus those components.

The solid that is cut need not be the mesh the child's faces were found on: the plane search
runs on a simplified proxy (:func:`search_proxy`) and :func:`split_solid` cuts the
full-resolution solid, telling the child's components apart by the proxy's labels.
"""

from __future__ import annotations

import manifold3d as m3
import numpy as np
import trimesh
from scipy.spatial import cKDTree

from slicer.decompose.planes import EPS, PROXY_FACES, PROXY_TOLERANCES, Plane
from slicer.mesh import to_manifold, to_trimesh

HULL_MARGIN = 0.5  # mm: the bounded cutter clears the child's hull by at least this / √3
VOLUME_RTOL = 1e-6  # the bounded cut must take the child's volume and no more


def search_proxy(mesh: trimesh.Trimesh, solid: m3.Manifold) -> trimesh.Trimesh:
    """A coarser copy of ``mesh`` for the plane search (``mesh`` itself when small).

    The solid is simplified with growing tolerances (:data:`PROXY_TOLERANCES`, all well
    below the obstacle sample margin) until it has at most :data:`PROXY_FACES` faces; the
    last one is used when none gets there.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Watertight part, (n,) faces.
    solid : manifold3d.Manifold
        The same part as a manifold.
    """
    if len(mesh.faces) <= PROXY_FACES:
        return mesh
    proxy = solid
    for tol in PROXY_TOLERANCES:
        proxy = solid.simplify(tol)
        if proxy.num_tri() <= PROXY_FACES:
            break
    return to_trimesh(proxy)


def split_solid(solid: m3.Manifold, plane: Plane, labels: trimesh.Trimesh,
                child_faces: np.ndarray) -> tuple[m3.Manifold, m3.Manifold]:
    """Cut ``solid`` by ``plane`` into (child, rest) as manifolds.

    Parameters
    ----------
    solid : manifold3d.Manifold
        The piece to cut.
    plane : Plane
        Normal into the child.
    labels : trimesh.Trimesh
        The same piece (possibly a simplified proxy), (m,) faces.
    child_faces : (m,) bool
        Faces of ``labels`` whose positive part belongs to the child.

    Raises
    ------
    ValueError
        Nothing of the child is on the positive side.
    """
    offset = float(plane.point @ plane.normal)
    # trim_by_plane twice, not split_by_plane: the latter's halves share their cut vertices,
    # and a union of its negative half with a positive component leaves them unwelded.
    pos = solid.trim_by_plane(plane.normal, offset)
    neg = solid.trim_by_plane(-plane.normal, -offset)
    h = plane.signed(labels.vertices)
    flags = np.zeros(len(labels.vertices), dtype=bool)
    flags[labels.faces[child_faces].ravel()] = True
    up = h > EPS
    tree = cKDTree(labels.vertices[up]) if up.any() else None
    child: list[m3.Manifold] = []
    rest = [neg]
    for comp in pos.decompose():
        verts = np.asarray(comp.to_mesh64().vert_properties)[:, :3]
        verts = verts[plane.signed(verts) > EPS]
        votes = flags[up][tree.query(verts)[1]] if len(verts) and tree is not None else [False]
        (child if np.mean(votes) > 0.5 else rest).append(comp)
    if not child:
        raise ValueError("the plane leaves nothing of the child on its positive side")
    kid = m3.Manifold.compose(child) if len(child) > 1 else child[0]
    if len(rest) == 1:
        return kid, neg
    return _bounded_cut(solid, kid, plane, offset) or (
        kid, m3.Manifold.batch_boolean(rest, m3.OpType.Add))


def _bounded_cut(solid: m3.Manifold, kid: m3.Manifold, plane: Plane, offset: float
                 ) -> tuple[m3.Manifold, m3.Manifold] | None:
    """(child, rest) when the plane also crosses other material: cut by the positive side
    of the plane within the child's convex hull widened by :data:`HULL_MARGIN`, so child and
    rest come from two booleans with one cutter. Joining the crossed pieces back onto the
    negative half instead keeps their touching cut faces inside the rest as a seam (edges of
    four faces once welded). None when that cutter would take other material too.
    """
    pts = np.asarray(kid.to_mesh64().vert_properties)[:, :3]
    spread = np.vstack([pts + d for d in HULL_MARGIN * np.vstack([np.eye(3), -np.eye(3)])])
    cutter = m3.Manifold.hull_points(spread).trim_by_plane(plane.normal, offset)
    child = solid ^ cutter
    if abs(child.volume() - kid.volume()) > VOLUME_RTOL * kid.volume():
        return None
    return child, solid - cutter


def split_piece(piece: trimesh.Trimesh, plane: Plane, child_faces: np.ndarray
                ) -> tuple[trimesh.Trimesh, trimesh.Trimesh]:
    """Cut ``piece`` by ``plane`` into (child, rest).

    Parameters
    ----------
    piece : trimesh.Trimesh
        Watertight solid, (m,) faces.
    plane : Plane
        Normal into the child.
    child_faces : (m,) bool
        Faces of ``piece`` whose positive part belongs to the child.

    Returns
    -------
    child, rest : trimesh.Trimesh
        Watertight; their volumes sum to the piece's.
    """
    child, rest = split_solid(to_manifold(piece), plane, piece, child_faces)
    return to_trimesh(child), to_trimesh(rest)
