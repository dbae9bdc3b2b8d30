"""The asyncio shell around :class:`~hostd.link.protocol.Protocol`: one port, one writer.

All protocol decisions are made by the pure state machine; this module only moves bytes,
passes the loop's clock in, keeps one timer at (or before) the protocol's deadline, and turns
acknowledgements and failures into futures. Everything runs on the event loop thread, and
only :meth:`SerialLink._apply` writes to the port, so lines cannot be reordered.

Latency: the lines of each chunk read from the port are handled in the transport's callback
(no task switch), and every line the freed credit allows goes out in one ``write``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections import deque
from collections.abc import AsyncIterator, Awaitable, Callable, Iterable, Sequence
from typing import Any

from hostd.link import errors
from hostd.link.actions import Acked, Action, Answer, Connected, Failed, Notice, Write
from hostd.link.framing import strip_gcode
from hostd.link.notices import NoticeLog
from hostd.link.protocol import Protocol
from hostd.link.replies import FirmwareInfo, Ok, Position, Reply, Temperatures
from hostd.link.settings import LinkSettings
from hostd.link.transport import Connection, open_port
from hostd.sim.settings import SimSettings

log = logging.getLogger(__name__)
Opener = Callable[[LinkSettings, SimSettings | None], Awaitable[Connection]]
_EXPECTED: dict[str, type] = {"M114": Position, "M105": Temperatures, "M115": FirmwareInfo}


class SerialLink:
    """The link to the printer's board. See :mod:`hostd.link` for the API overview.

    Parameters
    ----------
    settings
        Link settings (:func:`~hostd.link.settings.link_settings_from_config`).
    emulator_settings
        Settings of the emulator when ``settings.port`` is ``sim://``.
    opener
        Opens the port; tests replace it to simulate a port that comes and goes.
    """

    def __init__(self, settings: LinkSettings, emulator_settings: SimSettings | None = None,
                 *, opener: Opener = open_port) -> None:
        self.settings = settings
        self.emulator_settings = emulator_settings
        self.protocol = Protocol(settings)
        self.connection: Connection | None = None
        self._opener = opener
        self._loop: asyncio.AbstractEventLoop | None = None  # the loop it was connected on
        self._reconnect_task: asyncio.Task[None] | None = None
        self._timer: asyncio.TimerHandle | None = None
        self._timer_at = 0.0
        self._lines: deque[tuple[int, asyncio.Future[int]]] = deque()
        self._queries: dict[int, tuple[str, asyncio.Future[Reply]]] = {}
        self._handshake: asyncio.Future[None] | None = None
        self._notices = NoticeLog(settings.port)
        self._connected = asyncio.Event()
        self._closed = False
        self._auto_reconnect = False
        self.reconnects = 0
        self.last_error: errors.LinkError | None = None

    # -- connecting ---------------------------------------------------------------------

    async def connect(self) -> None:
        """Open the port and handshake (``M110 N0``, then ``M115``).

        Raises
        ------
        LinkLost
            The port cannot be opened or the firmware does not answer.
        """
        self._closed = False
        self._auto_reconnect = False
        try:
            await self._open_and_handshake()
        except OSError as exc:
            raise errors.LinkLost(f"cannot open {self.settings.port}: {exc}") from exc
        self._auto_reconnect = True
        with contextlib.suppress(errors.LinkError, TimeoutError):
            async with asyncio.timeout(self.settings.handshake_timeout):
                await self.query("M115")

    async def _open_and_handshake(self) -> None:
        self._drop_connection()
        self._loop = asyncio.get_running_loop()
        conn = self.connection = await self._opener(self.settings, self.emulator_settings)
        conn.receiver.attach(self._on_lines, lambda reason: self._on_lost(conn, reason))
        self._handshake = self._loop.create_future()
        self._apply(self.protocol.start(self._now()))
        await self._handshake

    async def close(self) -> None:
        """Close the port and stop reconnecting; outstanding lines fail with LinkLost."""
        self._closed = True
        if self._reconnect_task is not None:
            self._reconnect_task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._reconnect_task
        self._apply(self.protocol.disconnected("closed", self._now()))
        self._drop_connection()

    async def wait_connected(self) -> None:
        """Wait until the link is connected (after a reset, a reconnect or a restart)."""
        while not self.connected:
            self._connected.clear()  # not ready: only the next Connected may set it
            await self._connected.wait()

    async def restart(self) -> None:
        """Reset the firmware and handshake again: how a halted printer (M112, a firmware
        kill, a link too noisy to go on) comes back without restarting hostd.

        The port is closed and opened again; opening a serial port drops DTR, which resets an
        Arduino-class board (the emulator starts afresh). Raises :class:`LinkLost` as
        :meth:`connect` does.
        """
        if self._reconnect_task is not None:
            self._reconnect_task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._reconnect_task
        self._connected.clear()
        log.warning("%s: firmware restart (port reopened)", self.settings.port)
        await self.connect()

    @property
    def connected(self) -> bool:
        """Whether lines may be submitted now."""
        return self.protocol.state == "ready"

    # -- sending ------------------------------------------------------------------------

    def submit(self, command: str) -> asyncio.Future[int]:
        """Queue one stripped command; the future gives its submission number once acked.

        Never blocks. The future fails with a :class:`LinkError` if the line is lost to a
        reset, halt, resend loop or lost link.
        """
        seq, actions = self.protocol.submit(command, self._now())  # raises unless connected
        assert self._loop is not None  # (asyncio.get_running_loop costs a getpid() per call)
        fut: asyncio.Future[int] = self._loop.create_future()
        self._lines.append((seq, fut))
        if actions:  # mostly none: the line waits for credit
            self._apply(actions)
        return fut

    def submit_many(self, commands: Sequence[str]) -> tuple[int, asyncio.Future[int]]:
        """Queue stripped commands (at least one) in order with one future for them all.

        Returns the submission number of the first (the others follow it) and a future that
        gives the last's once it is acked. The future fails as :meth:`submit`'s do; the
        error's ``last_acked`` tells how many of the commands were acknowledged before.
        """
        if not commands:
            raise ValueError("submit_many needs at least one command")
        first, actions = self.protocol.submit_many(commands, self._now())
        assert self._loop is not None
        fut: asyncio.Future[int] = self._loop.create_future()
        self._lines.append((first + len(commands) - 1, fut))
        if actions:
            self._apply(actions)
        return first, fut

    def withdraw(self, first: int, last: int) -> int:
        """Take back the lines submitted as ``first`` .. ``last`` (one :meth:`submit_many`
        batch: lines only, numbered in a row) that have not gone out; returns how many, the
        last ones of the batch. A future of a line taken back now stands for the last line kept (it
        resolves with that line's number once acknowledged), or is cancelled when every
        line of the range was taken back."""
        taken = self.protocol.withdraw(first, last)
        if taken:
            self._rekey(first, last, last - taken)
            self._arm_timer()
        return taken

    def _rekey(self, first: int, last: int, kept: int) -> None:
        """Futures of lines ``kept + 1`` .. ``last`` now wait for line ``kept`` (or are
        cancelled if ``kept < first``); ``_lines`` stays ordered."""
        acked = self.protocol.last_acked
        lines: deque[tuple[int, asyncio.Future[int]]] = deque()
        for seq, fut in self._lines:
            if kept < seq <= last:
                if kept < first:
                    fut.cancel()
                    continue
                if kept <= acked:
                    if not fut.done():
                        fut.set_result(kept)
                    continue
                seq = kept
            lines.append((seq, fut))
        self._lines = lines

    async def send(self, command: str) -> int:
        """Send one command and wait for its ``ok``; returns its submission number."""
        return await self.submit(command)

    def enqueue(self, commands: Iterable[str]) -> list[asyncio.Future[int]]:
        """:meth:`submit` each command, in order."""
        return [self.submit(c) for c in commands]

    async def stream(self, lines: Iterable[str], strip: bool = True) -> AsyncIterator[int]:
        """Send ``lines`` in order and yield the input index of each line as it is acked.

        Comments and blank lines are skipped when ``strip`` (their indices are never
        yielded). At most ``settings.max_queued`` lines are submitted ahead of the acks; when
        that many are out, the stream sleeps until a quarter of them are acknowledged (one
        wake-up per batch, not per ``ok``) and yields their indices.

        Raises
        ------
        LinkError
            A subclass telling why the job stopped; its ``job_line`` is the input index of
            the last acknowledged line (``None`` if none).
        """
        ahead: deque[tuple[int, asyncio.Future[int]]] = deque()
        last: int | None = None
        limit = self.settings.max_queued
        try:
            for index, raw in enumerate(lines):
                command = strip_gcode(raw) if strip else raw.strip()
                if not command:
                    continue
                ahead.append((index, self.submit(command)))
                if len(ahead) >= limit:
                    await _settled(ahead, len(ahead) - limit + max(1, limit // 4))
                    while ahead and ahead[0][1].done():
                        last = _pop_acked(ahead)
                        yield last
            while ahead:
                await _settled(ahead, 1)
                last = _pop_acked(ahead)
                yield last
        except errors.LinkError as err:
            cause = _first_failure(ahead) or err
            for _, fut in ahead:
                fut.cancel()
            raise type(cause)(cause.reason, cause.last_acked, last) from cause

    async def query(self, command: str) -> Reply:
        """Send ``command`` in line and return the reply it produced.

        ``M114`` gives a :class:`Position`, ``M105`` a :class:`Temperatures`, ``M115`` a
        :class:`FirmwareInfo`; other commands the last informational reply or the ``Ok``.
        """
        fut: asyncio.Future[Reply] = asyncio.get_running_loop().create_future()
        seq, actions = self.protocol.submit(command, self._now(), kind="query")
        self._queries[seq] = (command.split()[0].upper(), fut)
        self._apply(actions)
        return await fut

    def emergency_stop(self) -> None:
        """Write ``M112`` at once, ahead of the window and the queue; fail the job."""
        self._apply(self.protocol.emergency_stop(self._now()))

    def status(self) -> dict[str, Any]:
        """A read-only, JSON-able snapshot of the link (see :mod:`hostd.link`)."""
        snap = self.protocol.snapshot()
        snap.update(port=self.settings.port, reconnects=self.reconnects,
                    last_error=str(self.last_error) if self.last_error else None)
        return snap

    # -- the machinery ------------------------------------------------------------------

    def _now(self) -> float:
        # asyncio's loop clock (BaseEventLoop.time) without looking the loop up each line
        return time.monotonic()

    def _on_lines(self, lines: list[bytes]) -> None:
        self._apply(self.protocol.receive_lines(lines, self._now()))

    def _on_lost(self, conn: Connection, reason: str) -> None:
        if conn is self.connection and not self._closed:
            self._apply(self.protocol.disconnected(reason, self._now()))

    def _apply(self, actions: list[Action]) -> None:
        """Write every :class:`Write` at once, then handle the events in order."""
        data = b""
        events = False
        for action in actions:
            if type(action) is Write:
                data += action.data
            else:
                events = True
        if data:
            self._write(data)
        if events:
            for action in actions:
                if type(action) is not Write:
                    self._event(action)
        self._arm_timer()

    def _write(self, data: bytes) -> None:
        if self.connection is not None:
            self.connection.write(data)

    def _event(self, action: Action) -> None:
        if type(action) is Acked:
            lines = self._lines
            while lines and lines[0][0] <= action.line:
                seq, fut = lines.popleft()
                if not fut.done():
                    fut.set_result(seq)
        elif isinstance(action, Answer):
            self._answer(action)
        elif isinstance(action, Connected):
            self._connected.set()
            if self._handshake is not None and not self._handshake.done():
                self._handshake.set_result(None)
        elif isinstance(action, Failed):
            self._failed(action.error)
        elif isinstance(action, Notice):
            self._notices.notice(action, self._now())

    def _answer(self, answer: Answer) -> None:
        code, fut = self._queries.pop(answer.line, ("", None))
        if fut is None or fut.done():
            return
        wanted = _EXPECTED.get(code)
        found = [r for r in answer.replies if wanted is not None and isinstance(r, wanted)]
        if wanted is Temperatures:
            found += [r.temperatures for r in answer.replies
                      if isinstance(r, Ok) and r.temperatures is not None]
        if wanted is Position:
            found += [r.position for r in answer.replies
                      if isinstance(r, Ok) and r.position is not None]
        informative: list[Reply] = [r for r in answer.replies if not isinstance(r, Ok)]
        fut.set_result(found[-1] if found else (informative or list(answer.replies))[-1])

    def _failed(self, error: errors.LinkError) -> None:
        self.last_error = error
        self._connected.clear()
        pending = [f for _, f in self._lines] + [f for _, f in self._queries.values()]
        self._lines.clear()
        self._queries.clear()
        for fut in pending:
            if not fut.done():
                fut.set_exception(error)
        if self._handshake is not None and not self._handshake.done():
            self._handshake.set_exception(error)
        if isinstance(error, errors.LinkLost) and self._auto_reconnect and not self._closed:
            self._start_reconnect()

    def _arm_timer(self) -> None:
        """Keep one timer no later than the protocol's deadline.

        Deadlines mostly move later (every ``ok`` extends them): the timer is then left as it
        is and, when it fires early, re-armed; it is replaced only when the deadline comes
        sooner.
        """
        due = self.protocol.deadline()
        if due is None or (self._timer is not None and self._timer_at <= due):
            return
        if self._timer is not None:
            self._timer.cancel()
        self._timer_at = due
        self._timer = asyncio.get_running_loop().call_at(due, self._on_timer)

    def _on_timer(self) -> None:
        self._timer = None
        self._apply(self.protocol.tick(self._now()))

    def _drop_connection(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if self.connection is not None:
            self.connection.close()
            self.connection = None

    def _start_reconnect(self) -> None:
        if self._reconnect_task is None or self._reconnect_task.done():
            log.warning("%s: link lost (%s); reconnecting", self.settings.port, self.last_error)
            self._drop_connection()
            self._reconnect_task = asyncio.get_running_loop().create_task(self._reconnect())

    async def _reconnect(self) -> None:
        """Reopen the port with exponential backoff until it works or :meth:`close`."""
        delay = self.settings.reconnect_min
        attempts = 0
        while not self._closed:
            await asyncio.sleep(delay)  # backoff period, not synchronisation
            attempts += 1
            try:
                await self._open_and_handshake()
            except (OSError, errors.LinkError) as exc:
                log.debug("%s: reconnect attempt %d: %s", self.settings.port, attempts, exc)
                delay = min(delay * 2, self.settings.reconnect_max)
                continue
            self.reconnects += 1
            log.warning("%s: link back after %d attempt(s)", self.settings.port, attempts)
            return


async def _settled(ahead: deque[tuple[int, asyncio.Future[int]]], count: int) -> None:
    """Wait until the first ``count`` lines of ``ahead`` are acknowledged or failed."""
    fut = ahead[min(count, len(ahead)) - 1][1]
    if not fut.done():
        await asyncio.wait((fut,))


def _pop_acked(ahead: deque[tuple[int, asyncio.Future[int]]]) -> int:
    """The input index of the (done) head line; raises its error if it failed."""
    index, fut = ahead[0]
    fut.result()
    ahead.popleft()
    return index


def _first_failure(ahead: deque[tuple[int, asyncio.Future[int]]]) -> errors.LinkError | None:
    """The error of the oldest failed line (the cause, when a later submit was refused)."""
    for _, fut in ahead:
        if fut.done() and not fut.cancelled():
            exc = fut.exception()
            if isinstance(exc, errors.LinkError):
                return exc
    return None
