"""The part as a mesh: reading STL files, their checks, sample parts and the placement.

* :mod:`~slicer.mesh.read`: :func:`load_mesh` reads an ASCII or binary STL, repairs it,
  refuses what cannot be printed (:class:`MeshError`, one line naming the file) and places it
  on the platform; the checks (watertight, one body, size, parts in inches), the flat bases
  a part can stand on and the canonical order of a placed mesh.
* :mod:`~slicer.mesh.samples`: parametric sample parts (cylinder, branched pipes) and the
  trimesh ↔ manifold3d conversions.

The other stages import what they need from here, not from the modules.
"""

from __future__ import annotations

from slicer.mesh.read import (
    BaseChoice,
    FlatBase,
    MeshError,
    Placement,
    canonical_mesh,
    check_size,
    flat_bases,
    load_mesh,
    merged_note,
    moved,
    parse_stl,
    place_on_platform,
    repair,
    separate_bodies,
    standing_base,
)
from slicer.mesh.samples import pipe2, pipe3, to_manifold, to_trimesh

__all__ = [
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
    "parse_stl",
    "pipe2",
    "pipe3",
    "place_on_platform",
    "repair",
    "separate_bodies",
    "standing_base",
    "to_manifold",
    "to_trimesh",
]
