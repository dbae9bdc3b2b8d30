"""Serve the metrics over HTTP with prometheus-client's own server.

prometheus-client answers scrapes on its own thread; each scrape asks the event loop for a
fresh snapshot (``run_coroutine_threadsafe``), so components' ``status()`` are only ever read
on the loop thread and never need locks.

The server adds the figures of this process's run under ``metrics`` (its own ``status()``):
the daemon's start time, and the jobs finished since the start, by outcome. The job manager's
``jobs.finished`` starts from the database's row counts (it goes down once a job is deleted
and hostd restarts), so the counter exports only what it gained while this process ran.
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

from prometheus_client import start_http_server

from hostd.metrics.collector import Snapshot, lookup, make_registry

SCRAPE_TIMEOUT = 5.0


class MetricsError(Exception):
    """The metrics endpoint cannot be served (address in use, loop gone)."""


class RunTally:
    """Per-key totals that only grow: what a figure gained since the first one seen.

    ``observe()`` takes the source's current figures (a dict of counts); an increase is
    added, a decrease (rows deleted, a restart's rebuild) only moves the mark it is measured
    from. So the totals start at 0 and count what happened while this process ran.
    """

    def __init__(self, keys: tuple[str, ...]) -> None:
        self.totals = dict.fromkeys(keys, 0)
        self._mark: dict[str, int] | None = None

    def observe(self, figures: Any) -> dict[str, int]:
        now = _counts(figures)
        if self._mark is not None:
            for key, n in now.items():
                gained = n - self._mark.get(key, n)
                if gained > 0:
                    self.totals[key] = self.totals.get(key, 0) + gained
        self._mark = {**(self._mark or {}), **now}
        return dict(self.totals)


def _counts(figures: Any) -> dict[str, int]:
    if not isinstance(figures, Mapping):
        return {}
    return {str(k): int(v) for k, v in figures.items()
            if isinstance(v, int) and not isinstance(v, bool)}


OUTCOMES = ("completed", "failed", "cancelled", "interrupted")


class MetricsServer:
    """HTTP ``/metrics`` on ``host:port`` rendering ``snapshot()`` from the event loop."""

    def __init__(self, host: str, port: int, snapshot: Callable[[], Snapshot]) -> None:
        self._host, self._port = host, port
        self._snapshot = snapshot
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: Any = None
        self._thread: threading.Thread | None = None
        self.scrapes = 0
        self.finished = RunTally(OUTCOMES)
        self.start_time: float | None = None

    def start(self) -> None:
        """Start serving; call from the event loop's thread, once the components run: the
        jobs finished from now on are counted (a job the last run left printing is recorded
        ``interrupted`` at the start, before this, and is not)."""
        self._loop = asyncio.get_running_loop()
        first = self._snapshot()
        self.finished.observe(lookup(first, "jobs.finished"))
        uptime = lookup(first, "daemon.uptime_s")
        now = time.time()
        self.start_time = round(now - uptime if isinstance(uptime, int | float) else now, 3)
        registry = make_registry(self._threadsafe_snapshot)
        try:
            self._server, self._thread = start_http_server(self._port, addr=self._host,
                                                           registry=registry)
        except OSError as exc:
            raise MetricsError(f"metrics: cannot listen on {self._host}:{self._port}: "
                               f"{exc.strerror or exc}") from None

    @property
    def port(self) -> int:
        """The bound port (the configured one; tests pass 0 for any free port)."""
        return int(self._server.server_address[1]) if self._server else self._port

    def _threadsafe_snapshot(self) -> Snapshot:
        assert self._loop is not None
        if self._loop.is_closed():
            raise MetricsError("metrics: event loop is closed")
        self.scrapes += 1
        fut = asyncio.run_coroutine_threadsafe(self._on_loop(), self._loop)
        return fut.result(timeout=SCRAPE_TIMEOUT)

    async def _on_loop(self) -> Snapshot:
        snap = dict(self._snapshot())
        self.finished.observe(lookup(snap, "jobs.finished"))
        snap["metrics"] = self.status()
        return snap

    def stop(self) -> None:
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._server = None

    def status(self) -> dict[str, Any]:
        """Also this run's figures: ``start_time_s`` (Unix time the daemon started) and
        ``jobs_finished`` (by outcome since then, as of the last scrape)."""
        return {"host": self._host, "port": self.port, "serving": self._server is not None,
                "scrapes": self.scrapes, "start_time_s": self.start_time,
                "jobs_finished": dict(self.finished.totals)}
