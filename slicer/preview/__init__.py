"""PNG previews a person checks at a glance (matplotlib, no display needed).

* :mod:`~slicer.preview.decomposition`: :func:`render_preview`, the sub-parts in colours, cut
  planes, build order and the coarse region numbers (``hostctl decompose``);
  :func:`render_refused`, the part with the point a refused decomposition names.
* :mod:`~slicer.preview.toolpaths`: :func:`render_toolpaths`, a print plan's toolpaths by
  sub-part, a refusal's failing region in red (``hostctl slice --preview``).
"""

from __future__ import annotations

from slicer.preview.decomposition import render_preview, render_refused
from slicer.preview.toolpaths import render_toolpaths

__all__ = ["render_preview", "render_refused", "render_toolpaths"]
