"""Checks and repairs of a read mesh: closed, one body, a printable size, not in inches.

:func:`repair` merges duplicate vertices, drops degenerate and duplicate faces and fixes the
winding, and refuses what stays open. Closed shells that overlap (solids exported into one
file without a union, as CAD and Blender exports often are) become one solid by a manifold3d
union (:func:`merge_shells`); shells that stay apart, and internal cavities, are refused
(:func:`separate_bodies`). :func:`check_size` refuses a part larger than the build volume or
smaller than the nozzle; a part too thin to print that ×25.4 would fit the machine is refused
with a hint that it was exported in inches (:func:`inch_hint`). Every refusal is a
:class:`~slicer.mesh.errors.MeshError` naming the file.
"""

from __future__ import annotations

import manifold3d as m3
import numpy as np
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from slicer.mesh.errors import MeshError
from slicer.mesh.samples import to_manifold, to_trimesh

INCH = 25.4  # mm


def repair(mesh: trimesh.Trimesh, name: str = "<mesh>") -> trimesh.Trimesh:
    """Merge vertices, drop degenerate/duplicate faces, fix winding; refuse open meshes."""
    mesh = trimesh.Trimesh(mesh.vertices, mesh.faces, process=True, validate=True)
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.update_faces(mesh.unique_faces())
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) == 0:
        raise MeshError(f"{name}: all triangles are degenerate")
    _fix_orientation(mesh)
    if not mesh.is_watertight:
        raise MeshError(f"{name}: not watertight after repair: {_edge_faults(mesh)}")
    if not mesh.is_winding_consistent or mesh.volume <= 0:
        raise MeshError(f"{name}: not a closed solid (inconsistent winding or no volume)")
    return mesh


def _edge_faults(mesh: trimesh.Trimesh) -> str:
    """What keeps a repaired mesh from being closed: open edges, or edges shared by more
    than two triangles (bodies touching along an edge)."""
    counts = np.unique(trimesh.grouping.hashable_rows(mesh.edges_sorted), return_counts=True)[1]
    open_edges, shared = int((counts == 1).sum()), int((counts > 2).sum())
    faults = ([f"{_count(open_edges, 'open edge')}"] if open_edges else []) + (
        [f"{_count(shared, 'edge')} shared by more than two triangles (bodies touching "
         "along an edge)"] if shared else [])
    return ", ".join(faults) or "inconsistent edges"


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" + ("" if n == 1 else "s")


def _fix_orientation(mesh: trimesh.Trimesh) -> None:
    """Consistent outward winding (in place); the costly re-winding only when needed."""
    if not mesh.is_winding_consistent:
        trimesh.repair.fix_winding(mesh)
    if mesh.is_watertight and mesh.volume < 0:
        mesh.invert()


def check_size(mesh: trimesh.Trimesh, name: str, build_volume: np.ndarray | None,
               min_size: float) -> None:
    """Refuse a part larger than the build volume or smaller than the nozzle."""
    ext = mesh.extents
    if ext.max() < min_size:
        raise MeshError(f"{name}: too small: largest extent {ext.max():.3g} mm is below the "
                        f"nozzle diameter {min_size:g} mm")
    if build_volume is not None:
        limit = np.asarray(build_volume, dtype=float)
        if (ext > limit).any():
            dims = " × ".join(f"{x:.1f}" for x in ext)
            room = " × ".join(f"{x:.1f}" for x in limit)
            raise MeshError(f"{name}: too big: {dims} mm exceeds the build volume {room} mm")


def merged_note(count: int) -> str:
    """What a slice's summary says of ``count`` shells merged by :func:`merge_shells`."""
    return f"merged {count} overlapping shells of the file into one solid"


def _shell(mesh: trimesh.Trimesh, faces: np.ndarray) -> trimesh.Trimesh:
    """The faces selected by ``faces``, (n,) bool, as a mesh of their own."""
    shell = trimesh.Trimesh(mesh.vertices, mesh.faces[faces], process=False)
    shell.remove_unreferenced_vertices()
    return shell


def inch_hint(mesh: trimesh.Trimesh, build_volume: np.ndarray | None,
              min_size: float) -> str | None:
    """Why a part that looks exported in inches cannot be printed, or None.

    The slicer reads millimetres and has no scale option, so only a part that could not be
    printed properly anyway is refused: one nowhere even half as thick as the nozzle (no ball
    of that diameter fits in it, :func:`holds_ball`: no bead, no layer of its own height) that
    ×25.4 would fit the build volume. Any other small part is left as it is.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Watertight.
    build_volume : (3,) float, optional
        Largest extents (x, y, z) the machine can hold, mm.
    min_size : float
        The nozzle diameter, mm.

    Returns
    -------
    str or None
        E.g. ``"too thin to print: the part is 1.72 × 1.26 × 2.36 mm and nowhere 0.2 mm thick
        (half the 0.4 mm nozzle); was it exported in inches? ×25.4 it would be 43.6 × 32.0 ×
        60.0 mm (STL files are read in millimetres)"``.
    """
    scaled = mesh.extents * INCH
    if build_volume is not None and (scaled > np.asarray(build_volume, dtype=float)).any():
        return None
    if holds_ball(mesh, min_size / 2.0):
        return None
    dims = " × ".join(f"{x:.3g}" for x in mesh.extents)
    inches = " × ".join(f"{x:.1f}" for x in scaled)
    return (f"too thin to print: the part is {dims} mm and nowhere {min_size / 2.0:g} mm thick "
            f"(half the {min_size:g} mm nozzle); was it exported in inches? ×25.4 it would be "
            f"{inches} mm (STL files are read in millimetres)")


def holds_ball(mesh: trimesh.Trimesh, diameter: float) -> bool:
    """Whether a ball of ``diameter`` fits inside the part (give or take ``diameter`` / 16).

    Horizontal sections (manifold3d) ``diameter / 8`` apart: a ball centred at one section's
    height fits where every section it spans, shrunk by the ball's half-width at that height,
    still overlaps. The middle heights are tried first. A mesh that manifold3d does not take
    counts as holding one (nothing is concluded from it).

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Watertight.
    diameter : float
        mm.
    """
    solid = to_manifold(mesh)
    if solid.status() != m3.Error.NoError or solid.is_empty():
        return True
    step = diameter / 8.0
    radius = diameter / 2.0 - step / 2.0  # a ball between two sections holds this one on one
    reach = np.arange(int(np.ceil(radius / step)))  # sections a ball spans on either side
    shrink = np.sqrt(radius**2 - (reach * step) ** 2)
    lo, hi = mesh.bounds[:, 2]
    heights = np.arange(lo + step / 2.0, hi, step)
    shrunk: dict[tuple[int, int], m3.CrossSection] = {}

    def section(k: int, j: int) -> m3.CrossSection:
        if (k, j) not in shrunk:
            shrunk[k, j] = solid.slice(float(heights[k])).offset(-float(shrink[j]))
        return shrunk[k, j]

    middle_first = np.argsort(np.abs(heights - (lo + hi) / 2.0), kind="stable")
    for k in middle_first[(middle_first >= reach[-1]) & (middle_first < len(heights) - reach[-1])]:
        room = section(int(k), 0)
        for j in reach[1:]:
            if room.is_empty():
                break
            room = room ^ section(int(k - j), int(j)) ^ section(int(k + j), int(j))
        if not room.is_empty():
            return True
    return False


def _face_volumes(mesh: trimesh.Trimesh) -> np.ndarray:
    """Signed volume of the tetrahedron from the origin to every face, (n,) float."""
    tri = mesh.triangles
    return np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])) / 6.0


def body_labels(mesh: trimesh.Trimesh) -> np.ndarray:
    """Edge-connected body of every face, (n,) int, 0 = the body with the largest volume.

    Bodies touching only at a vertex count as separate (nothing prints across a point).
    """
    n = len(mesh.faces)
    pairs = mesh.face_adjacency
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    count, comp = connected_components(graph, directed=False)
    if count == 1:
        return comp
    volume = np.bincount(comp, weights=_face_volumes(mesh), minlength=count)
    rank = np.empty(count, dtype=np.int64)
    rank[np.argsort(-volume, kind="stable")] = np.arange(count)
    return rank[comp]


def separate_bodies(mesh: trimesh.Trimesh, labels: np.ndarray | None = None) -> str | None:
    """``None`` for one connected solid, else a phrase naming the smallest body and where.

    ``labels`` are the mesh's :func:`body_labels`, (n,) int, when already known.

    Example: ``"the part is 2 separate bodies (the smallest, 1.24 mm³ near [9.6, 0.0, 23.6]
    mm, is not joined to the rest); one connected solid is needed"``.
    """
    labels = body_labels(mesh) if labels is None else labels
    count = int(labels.max()) + 1
    if count == 1:
        return None
    signed = np.bincount(labels, weights=_face_volumes(mesh), minlength=count)
    if (signed < 0).any():  # an inner shell facing inward: a closed void inside the part
        void = int(np.argmin(signed))
        return (f"the part has an internal cavity ({-signed[void]:.3g} mm³ near "
                f"[{_centre(mesh, labels == void)}] mm); fill it or open it to the outside")
    small = labels == count - 1
    volume = abs(float(signed[count - 1]))
    return (f"the part is {count} separate bodies (the smallest, {volume:.3g} mm³ near "
            f"[{_centre(mesh, small)}] mm, is not joined to the rest); one connected solid "
            "is needed")


def merge_shells(mesh: trimesh.Trimesh, name: str = "<mesh>") -> tuple[trimesh.Trimesh, int]:
    """One solid of a repaired mesh whose closed shells overlap (a manifold3d union).

    Files often hold solids that intersect, simply concatenated; their union is the part. A
    shell inside another is absorbed by it. Shells that stay apart after the union, and an
    inward-facing shell (an internal cavity), are refused with :func:`separate_bodies`'s
    reason.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Watertight with outward winding (:func:`repair`), n faces.
    name : str
        How errors name the file.

    Returns
    -------
    mesh : trimesh.Trimesh
        ``mesh`` itself when it is one body, else the union of its shells (repaired).
    merged : int
        How many shells were merged (0 when ``mesh`` is one body).

    Raises
    ------
    MeshError
        One line: ``"<file>: the part is 2 separate bodies ..."``, or an internal cavity.
    """
    labels = body_labels(mesh)
    count = int(labels.max()) + 1
    if count == 1:
        return mesh, 0
    refusal = MeshError(f"{name}: {separate_bodies(mesh, labels)}")
    if (np.bincount(labels, weights=_face_volumes(mesh)) < 0).any():
        raise refusal  # an internal cavity: no union would fill it
    shells = [to_manifold(_shell(mesh, labels == i)) for i in range(count)]
    if any(shell.status() != m3.Error.NoError for shell in shells):
        raise refusal
    union = repair(to_trimesh(m3.Manifold.batch_boolean(shells, m3.OpType.Add)), name)
    left = body_labels(union)
    if int(left.max()) + 1 == count:  # nothing overlapped: refused as the file's own bodies
        raise refusal
    rest = separate_bodies(union, left)
    if rest:
        raise MeshError(f"{name}: {rest}")
    return union, count


def _centre(mesh: trimesh.Trimesh, faces: np.ndarray) -> str:
    """The mean of the centres of the faces selected by ``faces``, (n,) bool, as text."""
    centre = np.round(mesh.triangles_center[faces].mean(axis=0), 1) + 0.0  # no "-0.0"
    return ", ".join(f"{x:.1f}" for x in centre)
