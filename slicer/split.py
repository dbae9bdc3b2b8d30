"""Splitting a piece along a separating plane into watertight solids (manifold3d).

The child is the union of the positive-side components that hold the child's faces; every
other positive-side component (for example the top of the main tube that a branch's plane also
crosses) stays with the parent, which is the negative side plus those components.
"""

from __future__ import annotations

import manifold3d as m3
import numpy as np
import trimesh
from scipy.spatial import cKDTree

from slicer.planes import EPS, Plane
from slicer.samples import to_manifold, to_trimesh


def split_piece(piece: trimesh.Trimesh, plane: Plane, child_faces: np.ndarray
                ) -> tuple[trimesh.Trimesh, trimesh.Trimesh]:
    """Cut ``piece`` by ``plane`` into (child, rest).

    Parameters
    ----------
    piece : trimesh.Trimesh
        Watertight solid.
    plane : Plane
        Normal into the child.
    child_faces : (m,) bool
        Faces of ``piece`` whose positive part belongs to the child.

    Returns
    -------
    child, rest : trimesh.Trimesh
        Watertight; their volumes sum to the piece's.
    """
    solid = to_manifold(piece)
    offset = float(plane.point @ plane.normal)
    pos = solid.trim_by_plane(plane.normal, offset)
    neg = solid.trim_by_plane(-plane.normal, -offset)
    h = plane.signed(piece.vertices)
    flags = np.zeros(len(piece.vertices), dtype=bool)
    flags[piece.faces[child_faces].ravel()] = True
    up = h > EPS
    tree = cKDTree(piece.vertices[up])
    child, rest = [], [neg]
    for comp in pos.decompose():
        verts = np.asarray(comp.to_mesh64().vert_properties)[:, :3]
        verts = verts[plane.signed(verts) > EPS]
        votes = flags[up][tree.query(verts)[1]] if len(verts) and up.any() else [False]
        (child if np.mean(votes) > 0.5 else rest).append(comp)
    if not child:
        raise ValueError("the plane leaves nothing of the child on its positive side")
    return (to_trimesh(m3.Manifold.batch_boolean(child, m3.OpType.Add)),
            to_trimesh(m3.Manifold.batch_boolean(rest, m3.OpType.Add)))
