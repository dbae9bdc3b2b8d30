"""Pure geometry core: decomposition, multi-axis slicing, toolpaths and G-code.

One sub-package per stage, in the order a part goes through them:

* :mod:`slicer.mesh`: STL files read, repaired, checked and placed on the platform; sample
  parts.
* :mod:`slicer.decompose`: the part cut into support-free sub-parts (coarse partition, build
  order, separating planes, split, overhang, the face it stands on).
* :mod:`slicer.paths`: every sub-part sliced along its skeleton curve into layers and
  toolpaths: the print plan.
* :mod:`slicer.gcode`: the plan written as joint-space G-code and read back; its
  ``markers`` module (no numpy) is the ``;HOSTD_`` markers and a command's words, which the
  daemon reads with too.
* :mod:`slicer.replay`: the replay check of a file against the part.
* :mod:`slicer.preview`: PNG previews.

Each sub-package's ``__init__`` is its face: the other stages (and ``hostd``) import from it,
never from its modules. On top, :mod:`slicer.pipeline` runs STL → checked G-code; beside it
stands what every stage shares: :mod:`slicer.plan` (the print plan), :mod:`slicer.settings`,
:mod:`slicer.printhead`, :mod:`slicer.planes2d` (plane frames, sections, the tolerances),
:mod:`slicer.envelope` (platform and travel checks) and :mod:`slicer.hugepages`. Nothing here
imports ``hostd``.
"""

from __future__ import annotations
