"""Serve the metrics over HTTP with prometheus-client's own server.

prometheus-client answers scrapes on its own thread; each scrape asks the event loop for a
fresh snapshot (``run_coroutine_threadsafe``), so components' ``status()`` are only ever read
on the loop thread and never need locks.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable
from typing import Any

from prometheus_client import start_http_server

from hostd.metrics.collector import Snapshot, make_registry

SCRAPE_TIMEOUT = 5.0


class MetricsError(Exception):
    """The metrics endpoint cannot be served (address in use, loop gone)."""


class MetricsServer:
    """HTTP ``/metrics`` on ``host:port`` rendering ``snapshot()`` from the event loop."""

    def __init__(self, host: str, port: int, snapshot: Callable[[], Snapshot]) -> None:
        self._host, self._port = host, port
        self._snapshot = snapshot
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: Any = None
        self._thread: threading.Thread | None = None
        self.scrapes = 0

    def start(self) -> None:
        """Start serving; call from the event loop's thread."""
        self._loop = asyncio.get_running_loop()
        registry = make_registry(self._threadsafe_snapshot)
        try:
            self._server, self._thread = start_http_server(self._port, addr=self._host,
                                                           registry=registry)
        except OSError as exc:
            raise MetricsError(f"metrics: cannot listen on {self._host}:{self._port}: "
                               f"{exc.strerror or exc}") from None

    @property
    def port(self) -> int:
        """The bound port (useful when configured as 0)."""
        return int(self._server.server_address[1]) if self._server else self._port

    def _threadsafe_snapshot(self) -> Snapshot:
        assert self._loop is not None
        if self._loop.is_closed():
            raise MetricsError("metrics: event loop is closed")
        self.scrapes += 1
        fut = asyncio.run_coroutine_threadsafe(self._on_loop(), self._loop)
        return fut.result(timeout=SCRAPE_TIMEOUT)

    async def _on_loop(self) -> Snapshot:
        return self._snapshot()

    def stop(self) -> None:
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._server = None

    def status(self) -> dict[str, Any]:
        return {"host": self._host, "port": self.port, "serving": self._server is not None,
                "scrapes": self.scrapes}
