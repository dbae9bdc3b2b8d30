"""hostd: host daemon for a five-axis (XYZ + A/C platform) FDM printer."""

from __future__ import annotations

__version__ = "0.1.0"
