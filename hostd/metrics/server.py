"""Serve the metrics over HTTP: prometheus-client's exposition, on the daemon's event loop.

The answer is prometheus-client's own WSGI app (``make_wsgi_app``: content negotiation,
OpenMetrics, gzip, ``name[]`` filters), called from a small bounded HTTP server on the loop
(:mod:`hostd.metrics.http`) instead of prometheus-client's threaded one, which took a thread
for every connection held open and accepted without limit. Connections count against
``metrics.max_connections``, one without a whole request within ``daemon.idle_timeout`` is
closed, and each scrape is rendered in its turn (:class:`~hostd.control.limits.Turns`), the
serial port's callbacks between any two. The snapshot is read on the loop thread, so
components' ``status()`` never need locks.

The server adds the figures of this process's run under ``metrics`` (its own ``status()``):
the daemon's start time, and the jobs finished since the start, by outcome. The job manager's
``jobs.finished`` starts from the database's rows (it goes down once a job is deleted
and hostd restarts), so the counter exports only what it gained while this process ran.
"""

from __future__ import annotations

import socket
import time
from collections.abc import Callable, Mapping
from typing import Any

from prometheus_client import make_wsgi_app

from hostd.control.limits import ConnectionGate, Listener, Ticket, Turns, listen_tcp
from hostd.metrics.collector import Snapshot, lookup, make_registry
from hostd.metrics.http import HttpConnection, simple_response

BACKLOG = 64


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


def _refusal(gate: ConnectionGate) -> bytes:
    return simple_response("503 Service Unavailable", gate.refusal() + "\n")


class MetricsServer:
    """HTTP ``/metrics`` on ``host:port`` rendering ``snapshot()`` on the event loop.

    At most ``max_connections`` connections; one idle ``idle_timeout`` seconds is closed;
    ``turns`` are the API's (scrapes take turns with its requests), else its own."""

    def __init__(self, host: str, port: int, snapshot: Callable[[], Snapshot],
                 max_connections: int = 8, idle_timeout: float = 30.0,
                 turns: Turns | None = None) -> None:
        self._host, self._port = host, port
        self._snapshot = snapshot
        self.gate = ConnectionGate("metrics", max_connections, "metrics.max_connections")
        self.idle_timeout = idle_timeout
        self.turns = turns or Turns()
        self._app = make_wsgi_app(make_registry(self._scrape_snapshot))
        self._sock: socket.socket | None = None
        self._listener: Listener | None = None
        self._conns: set[HttpConnection] = set()
        self.scrapes = 0
        self.finished = RunTally(OUTCOMES)
        self.start_time: float | None = None

    def start(self) -> None:
        """Start serving; call from the event loop's thread, once the components run: the
        jobs finished from now on are counted (a job the last run left printing is recorded
        ``interrupted`` at the start, before this, and is not)."""
        first = self._snapshot()
        self.finished.observe(lookup(first, "jobs.finished"))
        uptime = lookup(first, "daemon.uptime_s")
        now = time.time()
        self.start_time = round(now - uptime if isinstance(uptime, int | float) else now, 3)
        try:
            self._sock = listen_tcp(self._host, self._port, BACKLOG)
        except OSError as exc:
            raise MetricsError(f"metrics: cannot listen on {self._host}:{self._port}: "
                               f"{exc.strerror or exc}") from None
        self._listener = Listener(self._sock, self.gate, self._connection, _refusal)
        self._listener.start()

    def _connection(self, ticket: Ticket) -> HttpConnection:
        return HttpConnection(ticket, self._app, self.turns, self.idle_timeout, self._counted,
                              self._conns)

    def _counted(self) -> None:
        self.scrapes += 1

    @property
    def port(self) -> int:
        """The bound port (the configured one; tests pass 0 for any free port)."""
        return int(self._sock.getsockname()[1]) if self._sock is not None else self._port

    def _scrape_snapshot(self) -> Snapshot:
        snap = dict(self._snapshot())
        self.finished.observe(lookup(snap, "jobs.finished"))
        snap["metrics"] = self.status()
        return snap

    def stop(self) -> None:
        if self._listener is not None:
            self._listener.close()
        for conn in list(self._conns):
            conn.close()
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def status(self) -> dict[str, Any]:
        """Also this run's figures: ``start_time_s`` (Unix time the daemon started) and
        ``jobs_finished`` (by outcome since then, as of the last scrape)."""
        return {"host": self._host, "port": self.port, "serving": self._sock is not None,
                "scrapes": self.scrapes, "start_time_s": self.start_time,
                "jobs_finished": dict(self.finished.totals),
                "connections": len(self.gate.open), "max_connections": self.gate.cap,
                "refused": self.gate.refused}
