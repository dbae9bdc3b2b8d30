"""Job streaming: G-code program model, modal state tracking, the streamer."""

from __future__ import annotations
