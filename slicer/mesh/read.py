"""Loading, repair, validation and placement of STL parts.

:func:`load_mesh` reads ASCII or binary STL with trimesh, repairs what can be repaired (merged
duplicate vertices, consistent outward winding, degenerate and duplicate faces dropped) and
refuses what cannot be printed with a :class:`MeshError` whose ``str`` is one line naming the
file. Closed shells that overlap (solids exported into one file without a union, as CAD and
Blender exports often are) become one solid by a manifold3d union (:func:`merge_shells`);
shells that stay apart are refused. A part too thin to print that ×25.4 would fit the machine
is refused with a hint that it was exported in inches (:func:`inch_hint`).
:func:`place_on_platform` finds the flat base and returns the part in the platform frame (z up,
base on z = 0, base centroid on the C axis) together with the 4×4 placement matrix that every
later output carries.
"""

from __future__ import annotations

import math
import re
import struct
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import manifold3d as m3
import numpy as np
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from slicer.mesh.samples import to_manifold, to_trimesh
from slicer.planes2d import TOL

#: A direction no structured mesh is aligned with: the first key of the canonical order.
GENERIC = np.array([0.5377, 0.7185, 0.4411]) / np.linalg.norm([0.5377, 0.7185, 0.4411])

#: Tolerances of this module (mm, or cosines of angles).
PLANE_TOL = 1e-3  # distance of a face from its base plane, mm
NORMAL_COS = np.cos(np.radians(1.0))  # a face "faces down" within 1°
MIN_BASE_AREA = 1.0  # a flat base smaller than this (mm²) is no base
INCH = 25.4  # mm

_PARSE_ERRORS = (ValueError, TypeError, IndexError, KeyError, ImportError, UnicodeDecodeError,
                 struct.error)


class MeshError(ValueError):
    """A part that cannot be printed; ``str()`` is a one-line reason naming the file."""


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
    """Which flat face a decomposed part stands on, and why (:mod:`slicer.bases`).

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


def load_mesh(path: str | Path, build_volume: np.ndarray | None = None,
              min_size: float = 0.4) -> tuple[trimesh.Trimesh, Placement]:
    """Read, repair, validate and place an STL file.

    Overlapping closed shells are merged into one solid (:func:`merge_shells`; how many is
    ``placement.merged_shells``); a part too thin to print that looks exported in inches is
    refused with that hint (:func:`inch_hint`).

    Parameters
    ----------
    path : str or Path
        ASCII or binary STL.
    build_volume : (3,) float, optional
        Largest extents (x, y, z) the machine can hold, mm.
    min_size : float
        Smallest acceptable largest extent (the nozzle diameter), mm.

    Returns
    -------
    mesh : trimesh.Trimesh
        Watertight, in the platform frame.
    placement : Placement

    Raises
    ------
    MeshError
        One line: ``"<file>: <reason>"``.
    """
    name = str(path)
    mesh, merged = merge_shells(repair(read_stl(path), name), name)
    check_size(mesh, name, None, min_size)
    hint = inch_hint(mesh, build_volume, min_size)
    if hint:
        raise MeshError(f"{name}: {hint}")
    placed, placement = place_on_platform(mesh, name)
    check_size(placed, name, build_volume, min_size)
    return placed, replace(placement, merged_shells=merged)


def read_stl(path: str | Path) -> trimesh.Trimesh:
    """Parse an STL file (:func:`parse_stl`), naming it by ``path``."""
    name = str(path)
    try:
        if not Path(path).is_file():  # a directory, /dev/zero, a pipe: no end to read to
            raise MeshError(f"{name}: not a regular file" if Path(path).exists()
                            else f"{name}: cannot read: No such file or directory")
        data = Path(path).read_bytes()
    except OSError as exc:
        raise MeshError(f"{name}: cannot read: {exc.strerror or exc}") from None
    return parse_stl(data, name)


def parse_stl(data: bytes, name: str) -> trimesh.Trimesh:
    """The triangles of ASCII or binary STL ``data``, parsed by trimesh (unprocessed).

    Empty, truncated, unreadable and non-finite data is refused; for an ASCII STL the message
    names the first line at fault. The daemon's upload check runs this too (in its worker
    process), so an upload is refused for what would stop its slice here, in the same words.

    Raises
    ------
    MeshError
        One line: ``"<name>: <reason>"``, e.g. ``"part.stl: not a readable STL file (line 5:
        'vertex 1 0 x0')"``.
    """
    if not data.strip():
        raise MeshError(f"{name}: empty file")
    text = _is_ascii_stl(data)
    data = _ascii_body(data, name) if text else _binary_body(data, name)
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")  # non-finite input is refused below, in one line
            mesh = trimesh.load_mesh(trimesh.util.wrap_as_stream(data), file_type="stl",
                                     process=False)
    except _PARSE_ERRORS as exc:
        where = _first_bad_line(data) if text else None
        raise MeshError(f"{name}: not a readable STL file ("
                        f"{where or type(exc).__name__})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise MeshError(f"{name}: no triangles (empty or truncated STL)")
    _check_finite(mesh, data if text else None, name)
    return mesh


def _check_finite(mesh: trimesh.Trimesh, text: bytes | None, name: str) -> None:
    """Refuse NaN or infinite corners, naming the first: its line in the ASCII ``text``, or
    its triangle (binary, ``text`` None)."""
    corners = ~np.isfinite(mesh.triangles).all(axis=2)
    if not corners.any():
        return
    first = _first_bad_line(text) if text is not None else None
    where = first or f"in triangle {int(np.flatnonzero(corners.any(axis=1))[0])}"
    raise MeshError(f"{name}: {int(corners.sum())} triangle corners have NaN or infinite "
                    f"coordinates (the first {'at ' if first else ''}{where})")


def _is_ascii_stl(data: bytes) -> bool:
    """ASCII STL: text from ``solid`` on (a binary header may also begin with "solid", but
    then NUL bytes or its 50-byte records follow, not ``facet`` or ``endsolid``; and no
    binary STL is printable text throughout: its triangle count, bytes 80-83, would be over
    0x20202020)."""
    head = data.lstrip()[:2048]
    return head[:5].lower() == b"solid" and b"\0" not in head and (
        b"facet" in head or b"endsolid" in data[-2048:].lower() or _looks_like_text(data))


def _ascii_body(data: bytes, name: str) -> bytes:
    """An ASCII STL as :func:`_ascii_text`; refused, naming its last line, when it was cut
    short (:func:`_cut_short`)."""
    data = _ascii_text(data)
    lower = data.lower()
    if _cut_short(lower):
        lines = data.rstrip().splitlines()
        last = f"line {len(lines)}: {lines[-1].strip().decode('ascii')[:60]!r}"
        if b"facet" not in lower:
            raise MeshError(f"{name}: ASCII STL with no facets and no endsolid (empty, or "
                            f"cut short after {last})")
        raise MeshError(f"{name}: truncated ASCII STL: no endsolid after {last}")
    return data


def _cut_short(lower: bytes) -> bool:
    """Whether the lower-cased ASCII STL ``lower`` has no ``endsolid``, or a facet after the
    line of its last one (trimesh reads no triangle of the one, and silently drops the facets
    of the other)."""
    end = lower.rfind(b"endsolid")
    if end < 0:
        return True
    line_end = lower.find(b"\n", end)
    return line_end >= 0 and lower.find(b"facet", line_end) >= 0


def _ascii_text(data: bytes) -> bytes:
    """The file with every byte outside ASCII as ``?``: STL keywords and numbers are ASCII,
    and names in another encoding (``solid café`` in Latin-1) must not stop the parse."""
    return data.decode("latin-1").encode("ascii", "replace")


_STL_LINE = re.compile(rb"\s*(solid\b.*|endsolid\b.*|facet\s+normal(\s+\S+){3}|outer\s+loop"
                       rb"|vertex(\s+\S+){3}|endloop|endfacet|)\s*", re.IGNORECASE)
_NUMBERS = re.compile(rb"\s*(facet\s+normal|vertex)\s+(.*)", re.IGNORECASE)


def _first_bad_line(data: bytes) -> str | None:
    """``"line N: <text>"`` for the first line of an ASCII STL that is not STL (or a vertex
    that is not finite), or None."""
    for number, line in enumerate(data.splitlines(), 1):
        numbers = _NUMBERS.fullmatch(line)
        if _STL_LINE.fullmatch(line) and (numbers is None
                                          or _numbers_ok(numbers[1], numbers[2])):
            continue
        text = line.strip().decode("ascii", "replace")
        return f"line {number}: {text[:60]!r}"
    return None


def _numbers_ok(keyword: bytes, text: bytes) -> bool:
    """Three numbers, finite for a ``vertex`` (a normal may be NaN: some exporters write that
    for a degenerate triangle, and the normals are recomputed from the corners)."""
    try:
        values = [float(x) for x in text.split()]
    except ValueError:
        return False
    return len(values) == 3 and (keyword.lower() != b"vertex" or all(map(math.isfinite, values)))


def _binary_body(data: bytes, name: str) -> bytes:
    """A binary STL's header and records: refused when shorter than its triangle count
    says, trailing bytes past it (some exporters pad the file) dropped."""
    if _looks_like_text(data):
        raise MeshError(f"{name}: not an STL file (text that does not begin with 'solid')")
    if len(data) < 84:
        raise MeshError(f"{name}: truncated STL ({len(data)} bytes, no binary header)")
    count = struct.unpack("<I", data[80:84])[0]
    expected = 84 + 50 * count
    if len(data) < expected:
        raise MeshError(f"{name}: truncated binary STL: header declares {count} triangles "
                        f"({expected} bytes) but the file has {len(data)} bytes")
    return data[:expected]


def _looks_like_text(data: bytes) -> bool:
    """Printable text throughout its first kilobytes (a binary STL's records hold floats)."""
    head = data[:4096]
    return not head.translate(None, bytes(range(32, 127)) + b"\t\r\n")


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
