"""What a client may cost the daemon: one mechanism for every server that faces clients.

The serial stream comes first. A client's request waits its turn, its bytes count against a
budget, its connection against a cap, its events against a bound, and a connection that holds
a place without using it is closed. The control socket (:mod:`hostd.control.server`) and the
metrics endpoint (:mod:`hostd.metrics.server`) are built on these pieces, and so is to be the
HTTP/WebSocket API of issue 13 (on the same loop and endpoint registry):

- :class:`Listener` accepts on a listening socket under a :class:`ConnectionGate`. At the cap,
  the connection that has sent no whole request for longest makes room (a slot is never held
  by a client that only connects); when none has, the newcomer gets one refusal and is closed.
  An accept that fails for want of descriptors pauses accepting for a second and is logged at
  most once a minute (asyncio's own accept loop logs a traceback for each connection waiting,
  and retries at once). Any protocol factory fits, aiohttp's ``web.Server`` too.
- :class:`ByteBudget`: the bytes of unfinished and unanswered requests, across connections;
  over it, the connection holding the most is dropped (the offender, not whoever comes next).
- :class:`IdleTimer`: a connection with no request in progress and no subscription is closed
  after ``idle_timeout`` seconds without a whole request; bytes of an unfinished one do not
  count, so a client sending a byte a second (slow loris) holds nothing for long.
- :class:`Outbox`: what one connection has queued to send. Replies always go (the connection
  is not read meanwhile); a pushed event that finds the queue full drops the subscriber, with
  a logged reason, and counts as dropped with those still queued.
- :class:`Turns`: requests start one per pass of the event loop, and take a share of its
  time while others wait. Between two requests the loop polls its descriptors, the serial
  port's among them, so clients, however many and however fast, delay a reply of the
  firmware by one request at most, and a client that paused before asking goes before those
  that ask again the moment they have their answer.
- :class:`ReadPace`: the bytes of long requests (past their first 64 KiB) come in at a
  bounded rate across connections, so frames over the limit sent again and again cost the
  loop little.

:class:`Limits` holds the pieces the API's listeners share (the gate, the budget, the turns,
the pace and the counters the metrics export); the metrics endpoint has a gate of its own and
shares the turns. The HTTP/WebSocket API takes the same: its listening socket served by a
:class:`Listener` on :attr:`Limits.gate` (aiohttp's ``web.Server`` is a protocol factory),
``max_request_bytes`` as its largest body and WebSocket message (reserved in the budget while
held), the idle timeout as its keep-alive timeout and an :class:`IdleTimer` for a WebSocket
without subscription, an :class:`Outbox` for each WebSocket's events, and a turn
(:meth:`Turns.take`) before each request it dispatches.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import heapq
import itertools
import logging
import math
import socket
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

log = logging.getLogger(__name__)

KiB = 1024
MiB = 1024 * KiB
ACCEPT_RETRY_S = 1.0
"""Pause of a listener whose accept failed for want of descriptors or memory."""
ACCEPT_BATCH = 8
"""Connections accepted in one wake-up of a listener."""
LOG_INTERVAL_S = 60.0
"""Least time between two log lines of one kind of refusal or failure."""
QUEUE_BYTES = 256 * KiB
"""Bytes a connection may have queued to send before a pushed event drops it."""
QUEUE_MESSAGES = 2000
"""Messages likewise (many small events)."""
DROP_REASONS = ("idle", "too_large", "budget", "slow_reader", "room")
"""Why a connection was closed by a limit: idle too long, a request over the per-connection
limit, the offender when the buffered bytes went over their total, a subscriber not reading
its events, a silent connection closed to make room for a new one at the cap."""
REQUEST_SHARE = 0.15
"""Share of the event loop's time requests may take while others wait (:class:`Turns`)."""
MAX_REST_S = 0.005
"""Longest rest after one turn (a large request would otherwise hold the next one long)."""
WAIT_DECAY_S = 1.0
"""Time constant of the decay of each connection's waiting time (:class:`Turns`' order)."""
RANK_STEP_S = 0.001
"""Rests shorter than this rank alike (:class:`Turns`' order)."""
MAX_RANK_S = 3600.0
"""Rests longer than this rank alike."""
POLITE_S = 0.01
"""A request after a rest this long starts without waiting out the rest after a turn."""
MIN_REST_S = 0.0001
"""A rest shorter than this is none (a timer costs more than it would give)."""
SHORT_REQUEST = 64 * KiB
"""Bytes of a request read without pacing (:class:`ReadPace`)."""
LONG_READ_RATE = 32 * MiB
"""Bytes per second of long requests read, across connections (:class:`ReadPace`)."""
LONG_READ_BURST = 1 * MiB
RESOURCE_ERRNOS = frozenset({errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM})


@dataclass(frozen=True)
class LimitSettings:
    """The limits of the API's connections (``daemon.*`` keys)."""

    max_connections: int = 64
    idle_timeout: float = 30.0
    max_request_bytes: int = 512 * KiB
    max_buffered_bytes: int = 16 * MiB
    queue_bytes: int = QUEUE_BYTES
    queue_messages: int = QUEUE_MESSAGES


def limit_settings_from_config(config: Mapping[str, Any]) -> LimitSettings:
    return LimitSettings(max_connections=int(config["daemon.max_connections"]),
                         idle_timeout=float(config["daemon.idle_timeout"]),
                         max_request_bytes=int(config["daemon.max_request_bytes"]),
                         max_buffered_bytes=int(config["daemon.max_buffered_bytes"]))


def listen_tcp(host: str, port: int, backlog: int) -> socket.socket:
    """A listening TCP socket on ``host:port`` (IPv4 or IPv6, as the address is)."""
    family = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM,
                                flags=socket.AI_PASSIVE)[0][0]
    return socket.create_server((host, port), family=family, backlog=backlog)


class Throttled:
    """A log line of one kind at most every ``interval`` seconds; the next one logged says
    how many were held back meanwhile (the counters keep the full count)."""

    def __init__(self, logger: logging.Logger, interval: float = LOG_INTERVAL_S) -> None:
        self.logger = logger
        self.interval = interval
        self._last: dict[str, float] = {}
        self._held: dict[str, int] = {}

    def warning(self, kind: str, now: float, message: str) -> None:
        if now - self._last.get(kind, -math.inf) < self.interval:
            self._held[kind] = self._held.get(kind, 0) + 1
            return
        held = self._held.pop(kind, 0)
        self._last[kind] = now
        more = f" ({held} more since the last one logged)" if held else ""
        self.logger.warning("%s%s", message, more)


# -- connections --------------------------------------------------------------------------------


class Ticket:
    """One connection's place under a :class:`ConnectionGate`.

    ``proven`` once a whole request arrived; ``evict`` (set by the connection) closes it to
    make room and must give the place back (:meth:`release`) before it returns."""

    __slots__ = ("evict", "gate", "opened", "proven", "released")

    def __init__(self, gate: ConnectionGate, opened: float) -> None:
        self.gate = gate
        self.opened = opened
        self.proven = False
        self.evict: Callable[[str], None] | None = None
        self.released = False

    def release(self) -> None:
        if not self.released:
            self.released = True
            self.gate.open.discard(self)


class ConnectionGate:
    """At most ``cap`` connections of one listener group (``setting`` names the key)."""

    def __init__(self, name: str, cap: int, setting: str) -> None:
        self.name = name
        self.cap = cap
        self.setting = setting
        self.open: set[Ticket] = set()
        self.accepted = 0
        self.refused = 0
        self.made_room = 0

    def admit(self, now: float) -> Ticket | None:
        """A place for a new connection, or ``None`` (counted as refused)."""
        if len(self.open) >= self.cap and not self._make_room():
            self.refused += 1
            return None
        ticket = Ticket(self, now)
        self.open.add(ticket)
        self.accepted += 1
        return ticket

    def _make_room(self) -> bool:
        """Close the oldest connection that has sent no whole request yet, if any."""
        silent = [t for t in self.open if not t.proven and t.evict is not None]
        if not silent:
            return False
        oldest = min(silent, key=lambda t: t.opened)
        assert oldest.evict is not None
        oldest.evict(f"no request yet, closed to make room ({self.setting} "
                     f"{self.cap} reached)")
        oldest.release()
        self.made_room += 1
        return True

    def refusal(self) -> str:
        return f"too many connections: {self.setting} ({self.cap}) are open; try again later"


class Listener:
    """Accepts connections on ``sock`` (listening, non-blocking) under ``gate``.

    ``factory(ticket)`` makes each admitted connection's protocol, which must release the
    ticket once the connection is gone; a connection refused at the cap gets ``refusal(gate)``
    (best effort, never blocking) and is closed."""

    def __init__(self, sock: socket.socket, gate: ConnectionGate,
                 factory: Callable[[Ticket], asyncio.BaseProtocol],
                 refusal: Callable[[ConnectionGate], bytes]) -> None:
        self.sock = sock
        self.gate = gate
        self.factory = factory
        self.refusal = refusal
        self._loop = asyncio.get_running_loop()
        self._log = Throttled(log)
        self._retry: asyncio.TimerHandle | None = None
        self._pending: set[asyncio.Task[Any]] = set()
        self.accept_failures = 0
        self.serving = False

    def start(self) -> None:
        self.sock.setblocking(False)
        self._loop.add_reader(self.sock.fileno(), self._ready)
        self.serving = True

    def close(self) -> None:
        """Stop accepting (the socket stays open: its owner closes it)."""
        if self.serving:
            self._loop.remove_reader(self.sock.fileno())
            self.serving = False
        if self._retry is not None:
            self._retry.cancel()
            self._retry = None

    def _ready(self) -> None:
        for _ in range(ACCEPT_BATCH):
            try:
                conn, _ = self.sock.accept()
            except (BlockingIOError, InterruptedError):
                return
            except ConnectionAbortedError:
                continue
            except OSError as exc:
                self._failed(exc)
                return
            self._take(conn)

    def _take(self, conn: socket.socket) -> None:
        ticket = self.gate.admit(self._loop.time())
        if ticket is None:
            self._refuse(conn)
            return
        conn.setblocking(False)
        task = self._loop.create_task(self._connect(conn, ticket))
        self._pending.add(task)
        task.add_done_callback(self._pending.discard)

    async def _connect(self, conn: socket.socket, ticket: Ticket) -> None:
        try:
            await self._loop.connect_accepted_socket(lambda: self.factory(ticket), conn)
        except OSError as exc:  # the client left before its transport was made
            log.debug("%s: connection lost while set up: %s", self.gate.name, exc)
            ticket.release()
            conn.close()

    def _refuse(self, conn: socket.socket) -> None:
        self._log.warning("refused", self._loop.time(),
                          f"{self.gate.name}: connection refused: {self.gate.refusal()}")
        with contextlib.suppress(OSError):
            conn.setblocking(False)
            with contextlib.suppress(BlockingIOError):
                conn.recv(64 * KiB)  # what already came: closing on unread bytes resets
            conn.send(self.refusal(self.gate))
            conn.shutdown(socket.SHUT_WR)
        conn.close()

    def _failed(self, exc: OSError) -> None:
        """Accept failed: out of descriptors (or memory) pauses accepting for a while."""
        self.accept_failures += 1
        self._log.warning("accept", self._loop.time(),
                          f"{self.gate.name}: accept failed: {exc.strerror or exc}"
                          + (" (open files at the limit: LimitNOFILE, "
                             f"{self.gate.setting})" if exc.errno in RESOURCE_ERRNOS else ""))
        if exc.errno not in RESOURCE_ERRNOS or not self.serving:
            return
        self._loop.remove_reader(self.sock.fileno())
        self.serving = False
        self._retry = self._loop.call_later(ACCEPT_RETRY_S, self._resume)

    def _resume(self) -> None:
        self._retry = None
        self.start()


# -- bytes in, bytes out --------------------------------------------------------------------------


class Holder(Protocol):
    """A connection holding bytes of the budget."""

    def over_budget(self, reason: str) -> None:
        """Drop the connection (its bytes are already given back)."""
        ...


class ByteBudget:
    """Bytes held by unfinished or unanswered requests, across every connection."""

    def __init__(self, cap: int, setting: str = "daemon.max_buffered_bytes") -> None:
        self.cap = cap
        self.setting = setting
        self.used = 0
        self.held: dict[Holder, int] = {}

    def take(self, holder: Holder, n: int) -> bool:
        """Count ``n`` more bytes held by ``holder``. Over the cap, the holder of the most
        (``holder`` with these bytes included) is the offender: another one is dropped to
        make room, and ``False`` says it is ``holder`` (the caller drops it)."""
        while self.used + n > self.cap:
            offender = max(self.held, key=self.held.__getitem__, default=None)
            if offender is None or offender is holder or (
                    self.held[offender] <= self.held.get(holder, 0) + n):
                return False
            self._drop(offender)
        self.held[holder] = self.held.get(holder, 0) + n
        self.used += n
        return True

    def give(self, holder: Holder, n: int | None = None) -> None:
        """Give back ``n`` of ``holder``'s bytes (all of them by default)."""
        have = self.held.get(holder, 0)
        n = have if n is None else min(n, have)
        self.used -= n
        if have - n:
            self.held[holder] = have - n
        else:
            self.held.pop(holder, None)

    def _drop(self, offender: Holder) -> None:
        held = self.held.get(offender, 0)
        self.give(offender)
        offender.over_budget(f"{held} bytes of unfinished requests, the most when the "
                             f"{self.setting} ({self.cap}) across connections ran out")


class Outbox:
    """Messages waiting for one connection's transport, written through while it takes them.

    ``write`` hands bytes to the transport; :meth:`pause` and :meth:`resume` follow its flow
    control (``pause_writing``/``resume_writing``). Replies are always queued; an event that
    would take the queue past ``max_bytes`` or ``max_messages`` is refused (``False``), and
    the caller drops the subscriber."""

    def __init__(self, write: Callable[[bytes], None], max_bytes: int = QUEUE_BYTES,
                 max_messages: int = QUEUE_MESSAGES) -> None:
        self._write = write
        self.max_bytes = max_bytes
        self.max_messages = max_messages
        self._queue: deque[tuple[bytes, bool]] = deque()
        self.queued_bytes = 0
        self.paused = False
        self._drained: asyncio.Event | None = None

    def reply(self, data: bytes) -> None:
        self._put(data, False)

    def event(self, data: bytes) -> bool:
        if self._queue and (self.queued_bytes + len(data) > self.max_bytes
                            or len(self._queue) >= self.max_messages):
            return False
        self._put(data, True)
        return True

    def _put(self, data: bytes, event: bool) -> None:
        if not self.paused and not self._queue:
            self._write(data)
            return
        self._queue.append((data, event))
        self.queued_bytes += len(data)

    def pause(self) -> None:
        self.paused = True

    def resume(self) -> None:
        self.paused = False
        while self._queue and not self.paused:
            data, _ = self._queue.popleft()
            self.queued_bytes -= len(data)
            self._write(data)  # may pause again
        if not self._queue and self._drained is not None:
            self._drained.set()

    async def drained(self) -> None:
        """Return once nothing waits (the transport took everything queued)."""
        if not self._queue and not self.paused:
            return
        if self._drained is None:
            self._drained = asyncio.Event()
        self._drained.clear()
        await self._drained.wait()

    def discard(self) -> int:
        """Drop what waits; the number of events among it."""
        events = sum(1 for _, event in self._queue if event)
        self._queue.clear()
        self.queued_bytes = 0
        if self._drained is not None:
            self._drained.set()
        return events

    def __len__(self) -> int:
        return len(self._queue)


class ReadPace:
    """Bytes of long requests read per second, across connections: a token bucket.

    Reading is the one work a client makes the loop do before any turn: a client that sends
    frames over the limit again and again, connecting anew each time, would have the loop
    read ``max_request_bytes`` for each. Beyond the first :data:`SHORT_REQUEST` bytes of a
    request, :meth:`spend` says how long its connection is left unread, so that such bytes
    come in at :data:`LONG_READ_RATE` at most (a burst of :data:`LONG_READ_BURST` at once).
    """

    def __init__(self, rate: float = LONG_READ_RATE, burst: float = LONG_READ_BURST) -> None:
        self.rate = rate
        self.burst = burst
        self._tokens = burst
        self._at = 0.0
        self.paused = 0

    def spend(self, n: int, now: float) -> float:
        """Take ``n`` bytes read at ``now``; the seconds to leave the connection unread."""
        self._tokens = min(self.burst, self._tokens + (now - self._at) * self.rate) - n
        self._at = now
        if self._tokens >= 0:
            return 0.0
        self.paused += 1
        return -self._tokens / self.rate


# -- time -----------------------------------------------------------------------------------------


class IdleTimer:
    """Calls ``expire()`` once a connection has been idle ``timeout`` seconds: ``busy()``
    false (no request in progress, no subscription) and no whole request meanwhile
    (:meth:`touch`). One timer a connection, looked at once per ``timeout``."""

    def __init__(self, timeout: float, busy: Callable[[], bool],
                 expire: Callable[[], None]) -> None:
        self._loop = asyncio.get_running_loop()
        self.timeout = timeout
        self._busy = busy
        self._expire = expire
        self.last = self._loop.time()
        self._handle: asyncio.TimerHandle | None = self._loop.call_at(self.last + timeout,
                                                                       self._check)

    def touch(self) -> None:
        self.last = self._loop.time()

    def cancel(self) -> None:
        if self._handle is not None:
            self._handle.cancel()
            self._handle = None

    def _check(self) -> None:
        now = self._loop.time()
        if self._busy():
            self.last = now
        elif now - self.last >= self.timeout:
            self._handle = None
            self._expire()
            return
        self._handle = self._loop.call_at(self.last + self.timeout, self._check)


@dataclass(order=True)
class _Waiter:
    rank: float
    seq: int
    future: asyncio.Future[None] = field(compare=False)


class Turns:
    """Requests start one per pass of the event loop, and take at most ``share`` of its time
    while others wait; a client that asks now and then goes before those that never stop.

    A turn granted schedules the next grant for the loop's next pass, after the loop has
    polled its descriptors: the callbacks of the serial port run between any two requests.
    While requests wait, the next one starts only after a rest as long as the turn before it
    took (the rest of its pass) times ``(1 - share) / share``, at most
    :data:`MAX_REST_S`: a flood of requests leaves the loop idle most of the time (and the
    daemon's process the CPU), so its wake-ups for the port come at once. The turn covers a
    request up to its first wait (parsing, the handler's work, encoding the reply): what
    follows a wait is the loop's ordinary business.

    Order: how long the client let its connection rest before this request (since its last
    answer; a connection's first request, as long as can be), longest first, in steps of
    :data:`RANK_STEP_S`, then first come, first served. A client that asks again the moment
    it has its answer ranks last; one that rested :data:`POLITE_S` or more need not even
    wait for the rest after a turn: it waits for the turn under way at most, however many
    flood.
    """

    def __init__(self, share: float = REQUEST_SHARE) -> None:
        self.share = share
        self._loop: asyncio.AbstractEventLoop | None = None
        self._waiting: list[_Waiter] = []
        self._seq = itertools.count()
        self._open = True
        self._rest: asyncio.TimerHandle | None = None
        self._started = 0.0
        self.waited = 0
        self.busy_s = 0.0

    async def take(self, rested: float) -> None:
        """Return when a request may start whose client rested ``rested`` seconds before it
        (``math.inf``: a connection's first request)."""
        if self._open and not self._waiting:
            self._grant()
            return
        if self._rest is not None and rested >= POLITE_S:  # no need to rest for it
            self._rest.cancel()
            self._grant()
            return
        loop = self._loop or asyncio.get_running_loop()
        rank = -min(rested, MAX_RANK_S) // RANK_STEP_S
        waiter = _Waiter(rank, next(self._seq), loop.create_future())
        heapq.heappush(self._waiting, waiter)
        self.waited += 1
        await waiter.future  # cancelled with the request: the next grant passes it over

    def _grant(self) -> None:
        self._open = False
        if self._loop is None:
            self._loop = asyncio.get_running_loop()
        self._started = time.perf_counter()
        self._loop.call_soon(self._passed)

    def _passed(self) -> None:
        """The pass of the last turn is over: rest in proportion, then the next turn."""
        took = time.perf_counter() - self._started
        self.busy_s += took
        rest = min(took * (1 - self.share) / self.share, MAX_REST_S)
        if self._waiting and rest > MIN_REST_S:
            assert self._loop is not None
            self._rest = self._loop.call_later(rest, self._next)
        else:
            self._next()

    def _next(self) -> None:
        self._open = True
        self._rest = None
        while self._waiting:
            waiter = heapq.heappop(self._waiting)
            if not waiter.future.done():
                waiter.future.set_result(None)  # its task runs first in the next pass,
                self._grant()  # and then the measure of its turn
                return


# -- the whole -----------------------------------------------------------------------------------


class Limits:
    """The limits the API's listeners share: the control socket's, and the HTTP/WebSocket
    API's of issue 13 (its connections count against the same cap and budget)."""

    def __init__(self, settings: LimitSettings) -> None:
        self.settings = settings
        self.gate = ConnectionGate("control", settings.max_connections,
                                   "daemon.max_connections")
        self.budget = ByteBudget(settings.max_buffered_bytes)
        self.turns = Turns()
        self.pace = ReadPace()
        self.dropped = dict.fromkeys(DROP_REASONS, 0)
        self.events_dropped = 0
        self.log = Throttled(log)

    def outbox(self, write: Callable[[bytes], None]) -> Outbox:
        return Outbox(write, self.settings.queue_bytes, self.settings.queue_messages)

    def drop(self, reason: str, who: str, why: str) -> None:
        """Count and log (at most once a minute per reason) a connection closed by a limit."""
        self.dropped[reason] = self.dropped.get(reason, 0) + 1
        loop = asyncio.get_running_loop()
        self.log.warning(reason, loop.time(), f"{who} dropped: {why}")

    def status(self) -> dict[str, Any]:
        s = self.settings
        return {"open": len(self.gate.open), "max_connections": s.max_connections,
                "accepted": self.gate.accepted, "refused": self.gate.refused,
                "dropped": dict(self.dropped), "events_dropped": self.events_dropped,
                "buffered_bytes": self.budget.used, "max_buffered_bytes": s.max_buffered_bytes,
                "max_request_bytes": s.max_request_bytes, "idle_timeout_s": s.idle_timeout,
                "reads_paced": self.pace.paused, "turns_waited": self.turns.waited,
                "turns_busy_s": round(self.turns.busy_s, 3)}
