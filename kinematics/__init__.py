"""Pure A/C machine math for a table tilting-rotary (xyzac-trt) five-axis printer."""

from __future__ import annotations
