"""The part as a mesh: reading STL files, their checks, sample parts and the placement.

* :mod:`~slicer.mesh.read`: :func:`load_mesh` (a file read, repaired, checked and placed),
  :func:`parse_mesh` (the triangles of an STL, 3MF or OBJ, the format told by
  :func:`sniff_format`), :func:`read_stl` and :func:`parse_stl` (ASCII or binary STL),
  :func:`stl_bytes` (a mesh as binary STL).
* :mod:`~slicer.mesh.checks`: :func:`repair`, overlapping shells merged
  (:func:`merge_shells`), separate bodies and cavities refused, sizes checked, parts
  exported in inches told apart.
* :mod:`~slicer.mesh.placement`: the flat bases a part can stand on, its placement on the
  platform (:class:`Placement`, :class:`BaseChoice`) and the canonical order of a placed mesh.
* :mod:`~slicer.mesh.samples`: parametric sample parts (cylinder, branched pipes) and the
  trimesh ↔ manifold3d conversions.
* :mod:`~slicer.mesh.errors`: :class:`MeshError`, a part that cannot be printed (one line
  naming the file).

The other stages import what they need from here, not from the modules.
"""

from __future__ import annotations

from slicer.mesh.checks import check_size, merged_note, repair, separate_bodies
from slicer.mesh.errors import MeshError
from slicer.mesh.placement import (
    BaseChoice,
    FlatBase,
    Placement,
    canonical_mesh,
    flat_bases,
    moved,
    place_on_platform,
    standing_base,
)
from slicer.mesh.read import MESH_FORMATS, load_mesh, parse_mesh, parse_stl, sniff_format, stl_bytes
from slicer.mesh.samples import pipe2, pipe3, to_manifold, to_trimesh

__all__ = [
    "MESH_FORMATS",
    "BaseChoice",
    "FlatBase",
    "MeshError",
    "Placement",
    "canonical_mesh",
    "check_size",
    "flat_bases",
    "load_mesh",
    "merged_note",
    "moved",
    "parse_mesh",
    "parse_stl",
    "pipe2",
    "pipe3",
    "place_on_platform",
    "repair",
    "separate_bodies",
    "sniff_format",
    "standing_base",
    "stl_bytes",
    "to_manifold",
    "to_trimesh",
]
