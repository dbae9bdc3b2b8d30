"""One control connection: its requests in, its replies and events out, within the limits.

The bytes are framed into lines as they arrive (no stream reader: the connection itself
counts what it holds against :class:`~hostd.control.limits.ByteBudget`). One task per
connection answers its requests in order, each started in its turn
(:class:`~hostd.control.limits.Turns`); replies and pushed events go through one
:class:`~hostd.control.limits.Outbox`, whole messages in order, so they never interleave
mid-line. While a reply waits for the client to read, the connection is not read either.
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING, Protocol

from hostd.control.codes import CONNECTION_LIMIT, MESSAGE_TOO_LARGE
from hostd.control.limits import SHORT_REQUEST, IdleTimer, Ticket
from hostd.control.rpc import encode, response

if TYPE_CHECKING:
    from hostd.control.server import ControlServer

log = logging.getLogger(__name__)

PIPELINE = 16
"""Whole requests a connection may have waiting before it is read no further."""


class Subscribers(Protocol):
    """The server of a :class:`Client`: it counts the subscribed ones."""

    subscribers: int


class Client:
    """What a handler sees of its connection (``ctx``): its id, its event subscription,
    and hooks to run once it has ended (a control connection's, or a WebSocket's)."""

    def __init__(self, cid: int, server: Subscribers) -> None:
        self.id = cid
        self.server = server
        self._subscribed: frozenset[str] | None = None  # None: not subscribed
        self.all_events = False
        self.dropped = False
        self.on_close: dict[str, Callable[[], None]] = {}  # run once the connection has ended

    @property
    def subscribed(self) -> frozenset[str] | None:
        return self._subscribed

    @subscribed.setter
    def subscribed(self, names: frozenset[str] | None) -> None:
        self.server.subscribers += (names is not None) - (self._subscribed is not None)
        self._subscribed = names

    def subscribe(self, names: list[str] | None) -> None:
        self.all_events = not names
        self.subscribed = frozenset(names or ())

    def wants(self, name: str) -> bool:
        subs = self._subscribed
        return subs is not None and not self.dropped and (self.all_events or name in subs)


class _TooLarge:
    """Stands in the request queue for a request over the limit (answered in its place)."""


TOO_LARGE = _TooLarge()


class Connection(asyncio.Protocol):
    """A control connection under ``server``'s limits, admitted with ``ticket``."""

    def __init__(self, server: ControlServer, ticket: Ticket, cid: int) -> None:
        self.server = server
        self.limits = server.limits
        self.ticket = ticket
        self.client = Client(cid, server)
        self.transport: asyncio.Transport | None = None
        self._partial: list[bytes] = []
        self._partial_len = 0
        self._lines: deque[bytes | _TooLarge] = deque()
        self._wake: asyncio.Future[None] | None = None
        self._ended = False  # no more requests will come (EOF, lost, dropped)
        self._closing = False
        self._reading = True
        self._paced: asyncio.TimerHandle | None = None
        self.busy = False
        self.answered = -math.inf  # loop time of the last answer (none yet)
        self.outbox = self.limits.outbox(self._write)
        self.idle: IdleTimer | None = None
        self.task: asyncio.Task[None] | None = None

    @property
    def who(self) -> str:
        return f"control client {self.client.id}"

    # -- the transport's callbacks -------------------------------------------------------------

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport
        self.ticket.evict = self._evict
        self.idle = IdleTimer(self.limits.settings.idle_timeout, self._busy, self._idle)
        self.server.attach(self)
        self.task = asyncio.get_running_loop().create_task(self._serve())

    def data_received(self, data: bytes) -> None:
        if self._ended:
            return
        if not self.limits.budget.take(self, len(data)):
            self._drop("budget", f"{self.limits.budget.held.get(self, 0) + len(data)} bytes "
                       "of unfinished requests, the most when "
                       f"daemon.max_buffered_bytes ({self.limits.budget.cap}) ran out")
            return
        self._partial.append(data)
        self._partial_len += len(data)
        if b"\n" in data:
            self._split()
        if self._partial_len > self.limits.settings.max_request_bytes:
            self._too_large()
        elif self._partial_len > SHORT_REQUEST:
            self._pace_long(len(data))
        self._pace_reading()
        self._wake_up()

    def eof_received(self) -> bool:
        self._end()
        return True  # keep writing: the requests already read are still answered

    def connection_lost(self, exc: Exception | None) -> None:
        self.client.dropped = True
        self.outbox.discard()
        self._end()
        self._release()

    def pause_writing(self) -> None:
        self.outbox.pause()

    def resume_writing(self) -> None:
        self.outbox.resume()

    # -- requests in -----------------------------------------------------------------------------

    def _split(self) -> None:
        *lines, rest = b"".join(self._partial).split(b"\n")
        self._partial = [rest] if rest else []
        self._partial_len = len(rest)
        limit = self.limits.settings.max_request_bytes
        for i, line in enumerate(lines):
            if len(line) > limit:
                self.limits.budget.give(self, sum(len(x) + 1 for x in lines[i:]))
                self._too_large()
                return
            if line.strip():
                self._lines.append(line)
            else:
                self.limits.budget.give(self, len(line) + 1)

    def _too_large(self) -> None:
        """A request over ``max_request_bytes``: answered after those before it, then the
        connection is closed (what follows cannot be resynchronised)."""
        self.server.oversized += 1
        self._lines.append(TOO_LARGE)
        self._end()
        self._stop_reading()

    def _pace_long(self, n: int) -> None:
        """A long request: left unread a while when long requests come in too fast."""
        loop = asyncio.get_running_loop()
        pause = self.limits.pace.spend(n, loop.time())
        if pause and self._reading:
            self._stop_reading()
            self._paced = loop.call_later(pause, self._paced_out)

    def _paced_out(self) -> None:
        self._paced = None
        if len(self._lines) < PIPELINE:
            self._resume_reading()

    def _pace_reading(self) -> None:
        if self._reading and len(self._lines) >= PIPELINE:
            self._stop_reading()

    def _stop_reading(self) -> None:
        if self._reading and self.transport is not None and not self.transport.is_closing():
            self.transport.pause_reading()
        self._reading = False

    def _resume_reading(self) -> None:
        if (not self._reading and not self._ended and self._paced is None
                and self.transport is not None and not self.transport.is_closing()):
            self._reading = True
            self.transport.resume_reading()

    def _wake_up(self) -> None:
        if self._wake is not None and not self._wake.done():
            self._wake.set_result(None)

    async def _next(self) -> bytes | _TooLarge | None:
        """The next request, or ``None`` once none will come."""
        while not self._lines:
            if self._ended:
                return None
            self._resume_reading()
            self._wake = asyncio.get_running_loop().create_future()
            await self._wake
        return self._lines.popleft()

    # -- serving -----------------------------------------------------------------------------

    async def _serve(self) -> None:
        try:
            while (line := await self._next()) is not None:
                if isinstance(line, _TooLarge):
                    self._answer_too_large()
                    return
                await self._request(line)
                await self.outbox.drained()  # the client reads its replies before it is read
        except asyncio.CancelledError:
            if not self.server.closing:
                raise
            # the server stops: the connection ends as a normal close would
        finally:
            self._finish()

    async def _request(self, line: bytes) -> None:
        assert self.idle is not None
        self.ticket.proven = True
        self.idle.touch()
        self.busy = True
        loop = asyncio.get_running_loop()
        try:
            await self.limits.turns.take(loop.time() - self.answered)
            self.server.requests += 1
            reply = await self.server.registry.dispatch(line, self.client)
        finally:
            self.busy = False
            self.idle.touch()
            self.limits.budget.give(self, len(line) + 1)
            self.answered = loop.time()
        if reply is not None and not self._closing:
            self.outbox.reply(reply.encode())

    def _answer_too_large(self) -> None:
        limit = self.limits.settings.max_request_bytes
        self.limits.drop("too_large", self.who, f"a request over {limit} bytes "
                         "(daemon.max_request_bytes)")
        self._close_with(MESSAGE_TOO_LARGE, f"message exceeds {limit} bytes "
                         "(daemon.max_request_bytes)")

    def _finish(self) -> None:
        """The connection's end, once its last request is answered: hooks, then gone."""
        self._end()
        self.limits.budget.give(self)
        if self.transport is not None and not self.transport.is_closing():
            self.transport.close()
        for name, hook in self.client.on_close.items():
            try:
                hook()
            except Exception:  # one failing hook must not keep the others from running
                log.exception("client %d: closing %s", self.client.id, name)
        self._release()
        self.client.subscribed = None
        self.server.detach(self)

    # -- events out ------------------------------------------------------------------------------

    def push(self, line: bytes) -> None:
        """A pushed event; a subscriber whose queue is full is dropped."""
        if self._closing:
            return
        if not self.outbox.event(line):
            queued = len(self.outbox)
            self.limits.events_dropped += 1
            self._drop("slow_reader", f"not reading its events ({queued} messages, "
                       f"{self.outbox.queued_bytes} bytes queued)")

    def _write(self, data: bytes) -> None:
        if self.transport is not None and not self.transport.is_closing():
            self.transport.write(data)

    # -- limits ----------------------------------------------------------------------------------

    def _busy(self) -> bool:
        return self.busy or self.client.subscribed is not None

    def _idle(self) -> None:
        timeout = self.limits.settings.idle_timeout
        self.limits.drop("idle", self.who, f"no whole request for {timeout:g} s "
                         "(daemon.idle_timeout)")
        self._close_with(CONNECTION_LIMIT, f"closed: no whole request for {timeout:g} s "
                         "(daemon.idle_timeout)")

    def _evict(self, why: str) -> None:
        self.limits.drop("room", self.who, why)
        self._release()
        self._close_with(CONNECTION_LIMIT, f"closed: {why}")

    def over_budget(self, reason: str) -> None:
        """The budget dropped this connection, holding the most (its bytes given back)."""
        self._drop("budget", reason)

    def _drop(self, reason: str, why: str) -> None:
        """Close at once (nothing more is sent or read), counted and logged."""
        if self._closing:
            return
        self.limits.drop(reason, self.who, why)
        self._closing = True
        self.limits.events_dropped += self.outbox.discard()
        self._lines.clear()
        self._end()
        self.limits.budget.give(self)
        if self.transport is not None:
            self.transport.abort()

    def _close_with(self, code: int, message: str) -> None:
        """One error line, then close: at once when the client does not take it."""
        if self._closing:
            return
        self._closing = True
        self._end()
        self.outbox.reply(encode(response(None, error={"code": code,
                                                       "message": message})).encode())
        if self.transport is None:
            return
        if len(self.outbox) or self.transport.get_write_buffer_size():
            self.limits.events_dropped += self.outbox.discard()
            self.transport.abort()
        else:
            self.transport.close()

    def _end(self) -> None:
        """No more requests come in: the unfinished one is let go."""
        self._ended = True
        self.limits.budget.give(self, self._partial_len)
        self._partial.clear()
        self._partial_len = 0
        self._wake_up()

    def _release(self) -> None:
        """Give back the connection's place (once the transport is gone, or at the end)."""
        self.ticket.release()
        if self._paced is not None:
            self._paced.cancel()
            self._paced = None
        if self.idle is not None:
            self.idle.cancel()
