"""Toolpaths: every sub-part sliced along its skeleton curve into layers and their paths.

* :mod:`~slicer.paths.planner`: :func:`plan_print` (a decomposition → a
  :class:`~slicer.plan.PrintPlan`, A/C per layer) and :func:`plan_planar` (the 3-axis
  control).
* :mod:`~slicer.paths.skeleton`: a sub-part's skeleton curve (mean-curvature-flow skeleton,
  main chain, arc-length spline).
* :mod:`~slicer.paths.layers`: curved-layer planes marched along the curve within the wedge
  thickness bound; :class:`SlicingError`.
* :mod:`~slicer.paths.toolpaths`: one layer's perimeters, gap fill, infill and solid fill in
  its plane; :mod:`~slicer.paths.zones`: the solid skins of curved layers;
  :mod:`~slicer.paths.interfaces`: the parent solid under every child's base.
* :mod:`~slicer.paths.upright`: the root's layers leaned against its overhangs
  (:mod:`~slicer.paths.lean`, priced by :mod:`~slicer.paths.lean_costs`) and cut into
  stacked pieces where the lean jumps (:mod:`~slicer.paths.columns`); beyond the paper.
* :mod:`~slicer.paths.thin_layers`: thinner layers where the surface overhangs a little
  past what the layer height holds (:class:`Thinning`); beyond the paper.
* :mod:`~slicer.paths.subpart_paths`: a sub-part's layers on a thread pool, in three stages;
  :mod:`~slicer.paths.layer_workers`: stages 1 and 2 of long sub-parts in forked processes.

The other stages import what they need from here, not from the modules.
"""

from __future__ import annotations

from slicer.paths.layers import SlicingError
from slicer.paths.lean_costs import LEAN, LeanSettings
from slicer.paths.planner import plan_planar, plan_print
from slicer.paths.thin_layers import Spots, Thinning, any_height
from slicer.paths.upright import NO_HINTS, LeanHints

__all__ = ["LEAN", "NO_HINTS", "LeanHints", "LeanSettings", "SlicingError", "Spots",
           "Thinning", "any_height", "plan_planar", "plan_print"]
