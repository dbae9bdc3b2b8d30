"""Decomposition: a placed part → support-free sub-parts, their build order and cut planes.

* :mod:`~slicer.decompose.decomposition`: :func:`decompose`, the whole stage (settings,
  result, errors, ``decomposition.json``), and the independent check of its constraints.
* :mod:`~slicer.decompose.partition`: the k-means coarse partition into regions.
* :mod:`~slicer.decompose.buildorder`: region axes, BFS build order and grouping.
* :mod:`~slicer.decompose.planes`: separating planes, their constraints and the directed
  search; :mod:`~slicer.decompose.plane_refine`: the second phase, the feasible plane that
  leaves the parent least overhang.
* :mod:`~slicer.decompose.split`: a piece split along a plane into watertight solids.
* :mod:`~slicer.decompose.overhang`: the surface each sub-part would print in the air.
* :mod:`~slicer.decompose.bases`: :func:`decompose_on_bases`, the part stood on a much
  larger flat face when it is refused (or overhangs) as placed.
* :mod:`~slicer.decompose.ahead`: the attempts of one decomposition shared with a spawned
  worker process, read in order.

The other stages import what they need from here, not from the modules.
"""

from __future__ import annotations

from slicer.decompose.bases import decompose_on_bases
from slicer.decompose.decomposition import (
    DecomposeSettings,
    Decomposition,
    DecompositionError,
    RootRegionError,
    Subpart,
    decompose,
    write_decomposition,
)
from slicer.decompose.overhang import on_cuts, overhanging_faces
from slicer.decompose.planes import Plane, SearchSettings, plane_basis

__all__ = [
    "DecomposeSettings",
    "Decomposition",
    "DecompositionError",
    "Plane",
    "RootRegionError",
    "SearchSettings",
    "Subpart",
    "decompose",
    "decompose_on_bases",
    "on_cuts",
    "overhanging_faces",
    "plane_basis",
    "write_decomposition",
]
