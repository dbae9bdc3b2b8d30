"""The hostd daemon: wiring of the components, signals, graceful shutdown, stderr logging.

Components (serial link, job manager, slicing worker, control server, event bus, metrics) each
expose a read-only ``status()``; :meth:`Daemon.snapshot` gathers them for ``printer.status``
and the metrics exporter. SIGTERM/SIGINT stop the job at a safe point (after the acknowledged
lines; the job is recorded ``interrupted`` with its modal state) and close everything.

Under systemd (``Type=notify``) the daemon sends ``READY=1`` once the control socket serves,
``STATUS=`` with a one-line state when it changes, ``WATCHDOG=1`` from a task on the event loop
while every supervised task (link supervisor, job loops, temperature monitor) is alive, and
``STOPPING=1`` at shutdown. A control socket passed by ``hostd.socket`` is served as is.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import gc
import logging
import os
import resource
import signal
import socket
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hostd import __version__
from hostd.config import Config
from hostd.control.endpoints import build_registry
from hostd.control.limits import Limits, limit_settings_from_config
from hostd.control.rpc import Encoded, encoded
from hostd.control.server import ControlError, ControlServer
from hostd.errors import PrinterBusy
from hostd.events import EventBus
from hostd.jobs.manager import JobManager
from hostd.jobs.notify import Notifier
from hostd.jobs.spool import Spool
from hostd.jobs.store import JobStore, StoreError
from hostd.link.errors import LinkError
from hostd.link.link import SerialLink
from hostd.link.replies import Reply
from hostd.link.settings import link_settings_from_config
from hostd.printer.envelope import envelope_from_config
from hostd.printer.raw_gcode import RawReplies, run_script
from hostd.printer.settings import stream_settings_from_config
from hostd.sdnotify import listen_fds, notify, watchdog_interval
from hostd.sim.settings import sim_settings_from_config
from hostd.slicing_worker import SlicingWorker
from hostd.state_lock import StateLock, StateLockError

log = logging.getLogger("hostd")

EXIT_OK = 0
EXIT_FAILED = 1
TEMPERATURE_INTERVAL = 2.0  # s between temperature queries (and reports)
FD_RESERVE = 128
"""Open files beside the connection caps: the port, the database, uploads, worker pipes."""
STATUS_TTL_S = 0.02
"""Longest time ``printer.status`` answers with the same encoded snapshot (none outlives an
event): a flood of status requests costs one snapshot per period, not one each."""


class DaemonError(Exception):
    """The daemon cannot start (state directory, socket, database)."""


class LinkPort:
    """The streamer's view of :class:`SerialLink`."""

    def __init__(self, link: SerialLink) -> None:
        self.link = link

    def submit(self, command: str) -> asyncio.Future[int]:
        return self.link.submit(command)

    def submit_many(self, commands: Sequence[str]) -> tuple[int, asyncio.Future[int]]:
        return self.link.submit_many(commands)

    def withdraw(self, first: int, last: int) -> int:
        return self.link.withdraw(first, last)

    async def query(self, command: str) -> tuple[Reply, ...]:
        return (await self.link.query(command),)

    def acknowledged(self) -> int:
        return self.link.protocol.last_acked


def _state_dir_problem(state_dir: Path, exc: OSError) -> str:
    """One line for a state directory hostd cannot make or use: the file in the way of it
    or of a directory in it (``/var/lib/hostd/spool is a file, not a directory``), else
    the path and the system's words."""
    path = Path(exc.filename or state_dir)
    blocked = _not_a_directory(path) if exc.errno in (errno.EEXIST, errno.ENOTDIR) else None
    if blocked is None:
        return f"daemon.state_dir: cannot use {path}: {exc.strerror or exc}"
    where = "" if blocked == state_dir else f"cannot use {state_dir}: "
    what = "a file, not a directory" if blocked.is_file() else "not a directory"
    return f"daemon.state_dir: {where}{blocked} is {what}"


def _not_a_directory(path: Path) -> Path | None:
    """``path`` or the nearest directory above it that exists but is no directory."""
    for p in (path, *path.parents):
        if p.is_dir():
            return None
        if p.exists():
            return p
    return None


class Daemon:
    """All components of one running daemon; the control endpoints see it as a
    :class:`~hostd.control.host.Host`."""

    def __init__(self, config: Config) -> None:
        self.config = config
        self.state_dir = Path(config["daemon.state_dir"])
        self.is_sim = str(config["serial.port"]).startswith("sim://")
        self.bus = EventBus()
        self.started = time.time()
        self.stopping = asyncio.Event()
        self.link = SerialLink(link_settings_from_config(config),
                               sim_settings_from_config(config) if self.is_sim else None)
        self.worker: SlicingWorker | None = None
        self.store: JobStore | None = None
        self.server: ControlServer | None = None
        self.limits = Limits(limit_settings_from_config(config))
        self.metrics: Any = None
        self._tasks: list[asyncio.Task[None]] = []
        self._jobs: JobManager | None = None
        self.notifier: Notifier | None = None
        self.http: Any = None
        self._status_line = ""
        self._status_json: tuple[Encoded, float, int] | None = None  # (text, when, events)
        self._lock = StateLock(self.state_dir)

    @property
    def jobs(self) -> JobManager:
        assert self._jobs is not None
        return self._jobs

    @property
    def machine_name(self) -> str:
        return str(self.config["machine.name"])

    @property
    def max_upload_bytes(self) -> int:
        return int(self.config["daemon.max_upload_bytes"])

    async def start(self) -> None:
        check_descriptors(self.config)
        try:
            self.state_dir.mkdir(parents=True, exist_ok=True)
            self._lock.acquire()
            self.store = JobStore(self.state_dir / "jobs.db")
            spool = Spool(self.state_dir / "spool", self.config["daemon.max_upload_bytes"])
            self.worker = SlicingWorker(self.state_dir / "cache", self.config.data)
        except (StoreError, StateLockError) as exc:
            raise DaemonError(str(exc)) from None
        except OSError as exc:
            raise DaemonError(_state_dir_problem(self.state_dir, exc)) from None
        self._jobs = JobManager(self.store, spool, self.worker, lambda: LinkPort(self.link),
                                self.bus, stream_settings_from_config(self.config),
                                envelope_from_config(self.config.data), printer=self.link,
                                hold_after_print=self.config["daemon.next_job"] == "after_clear",
                                resends=lambda: self.link.protocol.counters.lines_resent)
        self.jobs.recover()  # before the socket opens: no client sees a dead job printing
        self.server = ControlServer(self.config["daemon.socket"], build_registry(self),
                                    self.bus, self.limits)
        try:
            await self.server.start(_activated_socket())
        except ControlError as exc:
            raise DaemonError(str(exc)) from None
        await self._start_http()
        connected = await self._connect_link()
        self.jobs.start()
        self._start_metrics()
        self._tasks.append(asyncio.create_task(self._temperature_monitor(), name="temps"))
        if not connected:
            self._tasks.append(asyncio.create_task(self._link_supervisor(), name="link"))
        self.notifier = Notifier(self.bus, self.config["notify.command"], self.jobs.job_detail,
                                 self.config["notify.timeout"])
        self.bus.subscribe(lambda name, data: self._notify_status(),
                           ("job.state", "printer.state"))
        gc.freeze()  # what starting made lives on: later collections need not walk it
        notify("READY=1\nSTATUS=" + self.status_line())
        interval = watchdog_interval()
        if interval is not None:
            self._tasks.append(asyncio.create_task(self._watchdog(interval), name="watchdog"))
        log.info("hostd %s ready (socket %s, state %s)", __version__, self.server.path,
                 self.state_dir)

    async def _connect_link(self) -> bool:
        try:
            await self.link.connect()
        except LinkError as exc:
            log.error("serial link: %s", exc)
            return False
        return True

    async def _link_supervisor(self) -> None:
        """Retry the first connection with backoff (after it, the link reconnects itself)."""
        s = self.link.settings
        delay = s.reconnect_min
        while True:
            await asyncio.sleep(delay)  # backoff period, not synchronisation
            if self.link.connected:  # a firmware-restart got there first: no second reset
                return
            try:
                await self.link.connect()
            except LinkError as exc:
                log.debug("serial link: %s", exc)
                delay = min(delay * 2, s.reconnect_max)
                continue
            log.info("serial link connected")
            self._notify_status()
            return

    def healthy(self) -> bool:
        """Every supervised task is alive (the link supervisor may have finished its job)."""
        for task in self._tasks:
            if task.done() and (task.get_name() != "link" or task.cancelled()
                                or task.exception() is not None):
                return False
        return self._jobs is not None and self._jobs.alive() and not self.stopping.is_set()

    def dead_tasks(self) -> list[str]:
        """What killed each supervised task that died (for the log), one line each."""
        tasks = [*self._tasks, *(self._jobs.tasks() if self._jobs is not None else [])]
        return [f"{t.get_name()}: {t.exception()!r}" if not t.cancelled()
                else f"{t.get_name()}: cancelled" for t in tasks if t.done()
                and (t.cancelled() or t.exception() is not None)]

    async def _watchdog(self, interval: float) -> None:
        """``WATCHDOG=1`` every ``interval`` s while healthy; runs on the loop, so a blocked or
        dead loop stops the pings too and systemd restarts the daemon."""
        while True:
            if self.healthy():
                notify("WATCHDOG=1")
                self._notify_status()  # progress moves without events of its own
            else:
                log.error("unhealthy: a supervised task died (%s); withholding the watchdog"
                          " ping", "; ".join(self.dead_tasks()) or "see above")
            await asyncio.sleep(interval)  # the ping period, not synchronisation

    def status_line(self) -> str:
        """A short human state for ``systemctl status`` (``STATUS=``)."""
        link = "link ready" if self.link.connected else "link down"
        act = self._jobs.active if self._jobs is not None else None
        if act is None:
            waiting = self._jobs.status()["queue_length"] if self._jobs is not None else 0
            return f"idle, {link}, {waiting} queued"
        st = act.streamer
        pct = 100 * st.acked / st.program.total if st.program.total else 100.0
        return f"{act.job.state.value} job {act.job.id} ({act.job.name}) {pct:.0f}%, {link}"

    def _notify_status(self) -> None:
        line = self.status_line()
        if line != self._status_line:
            self._status_line = line
            notify("STATUS=" + line)

    async def _start_http(self) -> None:
        """The HTTP and WebSocket API (``http.enabled``), on the control socket's registry
        and limits; a port in use is fatal, as for the metrics."""
        if not self.config["http.enabled"]:
            return
        from hostd.api_keys import KeyRing
        from hostd.control import slicer_uploads, web_page
        from hostd.control.http_api import HttpApi, HttpError

        assert self.server is not None
        self.http = HttpApi(self, self.server.registry, self.bus, self.limits,
                            KeyRing(self.config["http.api_key_file"]),
                            self.config["http.host"], self.config["http.port"],
                            int(self.config["http.max_upload_mb"]) << 20,
                            (slicer_uploads.add_routes, web_page.add_routes))
        try:
            await self.http.start()
        except HttpError as exc:
            self.http = None
            raise DaemonError(f"{exc} (http.port)") from None

    def _start_metrics(self) -> None:
        if not self.config["metrics.enabled"]:
            return
        from hostd.metrics.server import MetricsError, MetricsServer

        self.metrics = MetricsServer(self.config["metrics.host"], self.config["metrics.port"],
                                     self.snapshot, self.config["metrics.max_connections"],
                                     self.config["daemon.idle_timeout"], self.limits.turns)
        try:
            self.metrics.start()
        except MetricsError as exc:  # a port in use: fatal, as a config error is
            self.metrics = None
            raise DaemonError(f"metrics.port: {exc}") from None

    async def _temperature_monitor(self) -> None:
        """Publish the temperatures every :data:`TEMPERATURE_INTERVAL`, keeping an ``M105``
        query out while the link is up.

        While a job prints, the query goes in line after the lines already queued (as
        OctoPrint polls): without it, a board that does not autoreport would show the
        temperatures of the job's start until its end. Its ``ok T:`` also acknowledges every
        line before it, so a plain ``ok`` lost on the wire narrows the window for about two
        seconds. The query is not awaited here: behind an ``M109`` it waits minutes, and the
        heat-up's own reports (which the link notes, as every reply) are published meanwhile.
        """
        query: asyncio.Task[None] | None = None
        try:
            while True:
                if self.link.connected and (query is None or query.done()):
                    query = asyncio.create_task(self._query_temperatures())
                temps = self.link.status().get("temperatures") or {}
                if temps:
                    self.bus.publish("printer.temperatures", {"heaters": temps})
                await asyncio.sleep(TEMPERATURE_INTERVAL)  # a report period, not synchronisation
        finally:
            if query is not None:
                query.cancel()

    async def _query_temperatures(self) -> None:
        with contextlib.suppress(LinkError):  # the link's own state and log tell of it
            await self.link.query("M105")

    async def raw_gcode(self, script: str) -> RawReplies:
        """Run an operator's raw G-code: checked against the machine's travel, limited to a
        safe set while a job prints (:mod:`hostd.printer.raw_gcode`)."""
        return await run_script(script, self.jobs.envelope, self.jobs.streamer(),
                                self.link.query)

    async def firmware_restart(self) -> dict[str, Any]:
        """Reset the firmware and reconnect (after a halt); refused while a job is on the
        printer (printing or paused: its position would be lost)."""
        act = self.jobs.active
        if act is not None:
            raise PrinterBusy(f"refused: job {act.job.id} is on the printer "
                              f"({act.streamer.state}); cancel it first")
        await self.link.restart()
        self.bus.publish("printer.state", {"state": "ready", "reason": "firmware restart"})
        self._notify_status()
        return {"link": self.link.status()["state"]}

    async def emergency_stop(self) -> None:
        log.warning("emergency stop requested")
        self.link.emergency_stop()
        self.bus.publish("printer.state", {"state": "halted", "reason": "emergency stop"})

    def emulator_log(self) -> list[tuple[int | None, str]]:
        conn = self.link.connection
        emulator = getattr(conn, "emulator", None) if conn is not None else None
        if emulator is None:
            return []
        return list(emulator.firmware.log)

    async def run(self) -> int:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, self.stopping.set)
        try:
            await self.start()
        except DaemonError as exc:
            log.error("%s", exc)
            await self.close()
            return EXIT_FAILED
        await self.stopping.wait()
        log.info("stopping")
        notify("STOPPING=1\nSTATUS=stopping")
        await self.close()
        return EXIT_OK

    async def close(self) -> None:
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        if self._jobs is not None:  # first, so that clients get the job's last state
            await self._jobs.stop("daemon stopped (SIGTERM)")
        if self.notifier is not None:
            await self.notifier.close()
        if self.http is not None:
            await self.http.close()
        if self.server is not None:
            await self.server.close()
        with contextlib.suppress(LinkError):
            await self.link.close()
        if self.worker is not None:
            self.worker.close()
        if self.metrics is not None:
            self.metrics.stop()
        if self.store is not None:
            self.store.close()
        self._lock.release()

    def snapshot_json(self) -> Encoded:
        """:meth:`snapshot` encoded, the same for :data:`STATUS_TTL_S` while no event is
        published (an event may follow a change that the counters do not show)."""
        now, published = time.monotonic(), self.bus.published
        cached = self._status_json
        if cached is not None and now - cached[1] < STATUS_TTL_S and cached[2] == published:
            return cached[0]
        text = encoded(self.snapshot())
        self._status_json = (text, now, published)
        return text

    def snapshot(self) -> dict[str, Any]:
        """Every component's ``status()`` (plain JSON)."""
        link = self.link.status()
        return {
            "daemon": {"info": {"version": __version__, "machine": self.config["machine.name"],
                                "firmware_name": link.get("firmware_name")},
                       "pid": os.getpid(), "uptime_s": time.time() - self.started,
                       "state_dir": str(self.state_dir), "emulator": self.is_sim},
            "link": link,
            "jobs": self.jobs.status() if self._jobs is not None else {},
            "slicer": self.worker.status() if self.worker is not None else {},
            "control": self.server.status() if self.server is not None else {},
            "events": self.bus.status(),
            "metrics": self.metrics.status() if self.metrics is not None else None,
            "notify": self.notifier.status() if self.notifier is not None else None,
            "http": self.http.status() if self.http is not None else None,
            "connections": self.connections(),
        }

    def connections(self) -> dict[str, Any]:
        """Connections open and refused by listener, and those dropped by a limit."""
        gates = [self.limits.gate] + ([self.metrics.gate] if self.metrics is not None else [])
        return {"open": {g.name: len(g.open) for g in gates},
                "refused": {g.name: g.refused for g in gates},
                "dropped": dict(self.limits.dropped),
                "events_dropped": self.limits.events_dropped}


def descriptors_needed(config: Config) -> int:
    """Open files the connection caps may take, with :data:`FD_RESERVE` for the rest."""
    metrics = config["metrics.max_connections"] if config["metrics.enabled"] else 0
    return int(config["daemon.max_connections"]) + int(metrics) + FD_RESERVE


def check_descriptors(config: Config) -> None:
    """Raise the soft limit of open files to what the caps need, or refuse to start (with
    too few, connections at the cap would leave none for the port, the database, uploads)."""
    need = descriptors_needed(config)
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft >= need:
        return
    if hard == resource.RLIM_INFINITY or hard >= need:
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (need, hard))
            return
        except (OSError, ValueError) as exc:  # a system call filter may refuse it
            log.debug("setrlimit: %s", exc)
    raise DaemonError(f"daemon.max_connections: the connection caps need {need} open files "
                      f"({FD_RESERVE} beside the caps), the limit is {soft} (LimitNOFILE= in "
                      "the unit, ulimit -n)")


def _activated_socket() -> socket.socket | None:
    """The control socket passed by ``hostd.socket`` (the first fd), if any."""
    fds = listen_fds()
    if not fds:
        return None
    if len(fds) > 1:
        log.warning("socket activation passed %d sockets; serving the first", len(fds))
    return socket.socket(fileno=fds[0])


def setup_logging(level: str) -> None:
    logging.basicConfig(stream=sys.stderr, level=getattr(logging, level.upper()),
                        format="%(levelname)s %(name)s: %(message)s", force=True)


def run_daemon(config: Config) -> int:
    """Run until SIGTERM/SIGINT; the exit status of ``hostd``."""
    setup_logging(config["daemon.log_level"])
    return asyncio.run(Daemon(config).run())
