"""Pure geometry core: decomposition, multi-axis slicing, toolpaths and G-code."""

from __future__ import annotations
