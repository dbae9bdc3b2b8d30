"""Reading parts: the file's triangles, and a part loaded whole, repaired and placed.

:func:`load_mesh` reads ASCII or binary STL, 3MF (every build item with its transform, in
the model's unit) and OBJ with trimesh (:func:`read_mesh`, :func:`parse_mesh`; the format
told by the content, :func:`sniff_format`, the file name only when the content does not
say), repairs what can be repaired and refuses what cannot be printed
(:mod:`~slicer.mesh.checks`), then places it on the platform
(:mod:`~slicer.mesh.placement`). Every refusal is a :class:`~slicer.mesh.errors.MeshError`
whose ``str`` is one line naming the file; for an unreadable ASCII STL it names the first
line at fault. A file of another format (PLY, STEP, AMF, ...) is refused as an unsupported
format, naming it, never with an STL reader's words.
"""

from __future__ import annotations

import io
import math
import re
import struct
import warnings
import zipfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import trimesh

from slicer.mesh.checks import check_size, inch_hint, merge_shells, repair
from slicer.mesh.errors import MeshError
from slicer.mesh.placement import Placement, place_on_platform

_PARSE_ERRORS = (ValueError, TypeError, IndexError, KeyError, ImportError, UnicodeDecodeError,
                 struct.error)
_ARCHIVE_ERRORS = (zipfile.BadZipFile, StopIteration, SyntaxError, AttributeError, EOFError)
"""What trimesh's 3MF reader raises on a broken archive or model (lxml's XML errors are
SyntaxErrors; a model without meshes or build fails on a missing element)."""

MESH_FORMATS = ("stl", "3mf", "obj")
"""The formats :func:`parse_mesh` reads."""
SUFFIXES = {".stl": "stl", ".3mf": "3mf", ".obj": "obj"}
UNITS_MM = {"micron": 0.001, "millimeter": 1.0, "centimeter": 10.0, "inch": 25.4,
            "foot": 304.8, "meter": 1000.0}
"""3MF's model units (the ``unit`` attribute; millimeter when absent) in millimetres."""
_MAGIC = ((b"ply", "PLY"), (b"ISO-10303-21", "STEP"), (b"glTF", "glTF (GLB)"),
          (b"OFF", "OFF"), (b"#VRML", "VRML"), (b"#Inventor", "Open Inventor"))
"""Leading bytes of formats we do not read, and their names."""
_XML_ROOTS = ((b"<amf", "AMF"), (b"<COLLADA", "COLLADA"), (b"<X3D", "X3D"))
_OBJ_LINE = re.compile(rb"(v|vt|vn|vp|f|l|p|o|g|s|mtllib|usemtl)\s", re.IGNORECASE)


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
    mesh, merged = merge_shells(repair(read_mesh(path), name), name)
    check_size(mesh, name, None, min_size)
    hint = inch_hint(mesh, build_volume, min_size)
    if hint:
        raise MeshError(f"{name}: {hint}")
    placed, placement = place_on_platform(mesh, name)
    check_size(placed, name, build_volume, min_size)
    return placed, replace(placement, merged_shells=merged)


def read_stl(path: str | Path) -> trimesh.Trimesh:
    """Parse an STL file (:func:`parse_stl`), naming it by ``path``."""
    return parse_stl(_file_bytes(path), str(path))


def read_mesh(path: str | Path) -> trimesh.Trimesh:
    """Parse an STL, 3MF or OBJ file (:func:`parse_mesh`), naming it by ``path``; its
    extension says the format only when the content does not."""
    return parse_mesh(_file_bytes(path), str(path), SUFFIXES.get(Path(path).suffix.lower()))[0]


def _file_bytes(path: str | Path) -> bytes:
    """The bytes of the regular file ``path``; :class:`MeshError` naming it when there are
    none to read."""
    name = str(path)
    try:
        if not Path(path).is_file():  # a directory, /dev/zero, a pipe: no end to read to
            raise MeshError(f"{name}: not a regular file" if Path(path).exists()
                            else f"{name}: cannot read: No such file or directory")
        data = Path(path).read_bytes()
    except OSError as exc:
        raise MeshError(f"{name}: cannot read: {exc.strerror or exc}") from None
    return data


def sniff_format(data: bytes) -> str | None:
    """The format of ``data`` by its content: ``stl``, ``3mf``, ``obj``, the name of a
    format :func:`parse_mesh` does not read (``PLY``, ``STEP``, ``ZIP archive``, ...), or
    ``None`` for text it cannot tell (a file name's extension may then say)."""
    head = data[:4096]
    if head.startswith(b"PK\x03\x04"):
        return "3mf" if _is_3mf(data) else "ZIP archive (no 3D/3dmodel.model: not 3MF)"
    lead = head.lstrip()
    for magic, fmt in _MAGIC:
        if lead.startswith(magic):
            return fmt
    if lead.startswith(b"<"):
        return next((fmt for root, fmt in _XML_ROOTS if root in head), "XML")
    if _is_ascii_stl(data):
        return "stl"
    if _looks_like_text(data):
        return "obj" if _looks_like_obj(head) else None
    return "stl"


def _is_3mf(data: bytes) -> bool:
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            return any(n.lower().endswith("3d/3dmodel.model") for n in archive.namelist())
    except (zipfile.BadZipFile, OSError, ValueError):
        return False


def _looks_like_obj(head: bytes) -> bool:
    """Text whose first statements are OBJ's (vertices, faces, groups, comments)."""
    lines = [ln.strip() for ln in head.splitlines()[:-1] or head.splitlines()]
    statements = [ln for ln in lines if ln and not ln.startswith(b"#")]
    return bool(statements) and all(_OBJ_LINE.match(ln + b" ") for ln in statements[:20])


def parse_mesh(data: bytes, name: str, kind: str | None = None
               ) -> tuple[trimesh.Trimesh, str]:
    """The triangles of STL, 3MF or OBJ ``data`` (unprocessed) and the format read.

    The content says the format (:func:`sniff_format`); ``kind`` (``stl``, ``3mf``,
    ``obj``: what the file was sent as) only when it cannot tell. A 3MF gives every build
    item with its transform, scaled from the model's unit to millimetres; an OBJ is in
    millimetres. The daemon's upload check runs this too, so an upload is refused for what
    would stop its slice, in the same words.

    Raises
    ------
    MeshError
        One line naming ``name``: ``"part.ply: unsupported format: PLY (hostd reads STL,
        3MF and OBJ)"``, or what :func:`parse_stl` says of a bad STL.
    """
    if not data.strip():
        raise MeshError(f"{name}: empty file")
    found = sniff_format(data)
    if found is not None and found not in MESH_FORMATS:
        raise MeshError(f"{name}: unsupported format: {found} (hostd reads STL, 3MF and OBJ)")
    fmt = found or kind or "stl"
    if fmt == "3mf":
        return _parse_3mf(data, name), fmt
    if fmt == "obj":
        return _parse_obj(data, name), fmt
    return parse_stl(data, name), fmt


def _parse_3mf(data: bytes, name: str) -> trimesh.Trimesh:
    """Every build item of a 3MF, placed by its transform, in millimetres."""
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            loaded = trimesh.load(io.BytesIO(data), file_type="3mf", process=False)
    except _PARSE_ERRORS + _ARCHIVE_ERRORS as exc:
        raise MeshError(f"{name}: not a readable 3MF file ({type(exc).__name__}: "
                        f"{str(exc)[:80]})") from None
    unit = str((getattr(loaded, "metadata", None) or {}).get("units") or "millimeter")
    scale = UNITS_MM.get(unit.lower().rstrip("s"))
    if scale is None:
        raise MeshError(f"{name}: 3MF unit {unit!r} is not one of {', '.join(UNITS_MM)}")
    mesh = _one_mesh(loaded, name, "3MF")
    if scale != 1.0:
        mesh.apply_scale(scale)
    return mesh


def _parse_obj(data: bytes, name: str) -> trimesh.Trimesh:
    """Every object of an OBJ as one mesh."""
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            loaded = trimesh.load(io.BytesIO(data), file_type="obj", process=False,
                                  skip_materials=True)
    except _PARSE_ERRORS as exc:
        raise MeshError(f"{name}: not a readable OBJ file ({type(exc).__name__})") from None
    return _one_mesh(loaded, name, "OBJ")


def _one_mesh(loaded: object, name: str, fmt: str) -> trimesh.Trimesh:
    """A loaded scene's geometry, each instance placed, as one mesh; refused when it holds
    no triangles or non-finite ones."""
    if isinstance(loaded, trimesh.Scene):
        loaded = loaded.to_mesh() if loaded.geometry else None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise MeshError(f"{name}: no triangles in the {fmt} file")
    _check_finite(loaded, None, name)
    return loaded


def stl_bytes(mesh: trimesh.Trimesh) -> bytes:
    """``mesh`` as a binary STL (the spool keeps every part to slice as one)."""
    data = trimesh.exchange.stl.export_stl(mesh)
    assert isinstance(data, bytes)
    return data


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
