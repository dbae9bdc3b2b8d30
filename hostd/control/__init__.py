"""The control socket: JSON-RPC 2.0 framing and registry, the Unix socket server, events."""

from __future__ import annotations
