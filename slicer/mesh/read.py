"""Reading STL parts: the file's triangles, and a part loaded whole, repaired and placed.

:func:`load_mesh` reads ASCII or binary STL with trimesh (:func:`read_stl`,
:func:`parse_stl`), repairs what can be repaired and refuses what cannot be printed
(:mod:`~slicer.mesh.checks`), then places it on the platform
(:mod:`~slicer.mesh.placement`). Every refusal is a :class:`~slicer.mesh.errors.MeshError`
whose ``str`` is one line naming the file; for an unreadable ASCII STL it names the first
line at fault.
"""

from __future__ import annotations

import math
import re
import struct
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import trimesh

from slicer.mesh.checks import check_size, inch_hint, merge_shells, repair
from slicer.mesh.errors import MeshError
from slicer.mesh.placement import Placement, place_on_platform

_PARSE_ERRORS = (ValueError, TypeError, IndexError, KeyError, ImportError, UnicodeDecodeError,
                 struct.error)


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
