"""The control socket: JSON-RPC 2.0 framing and registry, the error table, the endpoints and
the Unix socket server. It depends on the domain (jobs, printer, link, the event bus); the
domain never imports it."""

from __future__ import annotations
