"""The asyncio shell of the emulator: wall clock, wire throttling and scheduling.

:class:`Emulator` drives a :class:`~hostd.sim.firmware.Firmware` from bytes fed to it and
writes the replies through a ``write`` callable, so it can sit behind a socket pair (the
in-process ``sim://`` port) or a pseudo-terminal (``hostd-sim --pty``). Nothing polls: wire
delays and simulated-time events are single ``call_at`` timers.
"""

from __future__ import annotations

import asyncio
import socket
from collections import deque
from collections.abc import Callable

from hostd.sim.firmware import Firmware
from hostd.sim.settings import SimSettings


class Emulator:
    """One emulated board attached to a byte sink.

    Wire timing is computed, not slept: each line reaches the firmware when its last byte has
    crossed the throttled wire, and each reply leaves when the wire back is free after the
    moment it was produced. A timer that fires late (the event loop's timers are only
    millisecond-exact) delays the delivery, never the wire schedule, so the replies of a late
    delivery go out at the times the wire would have carried them (at once, if that is past).

    Parameters
    ----------
    settings
        Emulator settings.
    write
        Called with reply bytes, in order.
    """

    def __init__(self, settings: SimSettings, write: Callable[[bytes], None]) -> None:
        self.settings = settings
        self.firmware = Firmware(settings)
        self._write = write
        self._loop = asyncio.get_running_loop()
        self._t0 = self._loop.time()
        self._rate = settings.wire_bytes_per_second
        self._inbox: deque[tuple[float, bytes]] = deque()
        self._outbox: deque[tuple[float, bytes]] = deque()
        self._in_free = 0.0
        self._out_free = 0.0
        self._in_timer: asyncio.TimerHandle | None = None
        self._out_timer: asyncio.TimerHandle | None = None
        self._wake_timer: asyncio.TimerHandle | None = None
        self.closed = False
        self._flush(self._t0)

    # -- input --------------------------------------------------------------------------

    def feed(self, data: bytes) -> None:
        """Bytes the host wrote; they reach the firmware at the wire rate."""
        if self.closed or not data:
            return
        now = self._loop.time()
        if self._rate == float("inf"):
            self._deliver(data, now)
            return
        start = 0
        while start < len(data):
            end = data.find(b"\n", start)
            end = len(data) if end < 0 else end + 1
            self._in_free = max(self._in_free, now) + (end - start) / self._rate
            self._inbox.append((self._in_free, data[start:end]))
            start = end
        if self._in_timer is None:
            self._in_timer = self._loop.call_at(self._inbox[0][0], self._drain_inbox)

    def _drain_inbox(self) -> None:
        self._in_timer = None
        now = self._loop.time()
        while self._inbox and self._inbox[0][0] <= now and not self.closed:
            arrived, chunk = self._inbox.popleft()
            self._deliver(chunk, arrived)
        if self._inbox and not self.closed:
            self._in_timer = self._loop.call_at(self._inbox[0][0], self._drain_inbox)

    def _deliver(self, data: bytes, arrived: float) -> None:
        fw = self.firmware
        if self.settings.realtime:
            fw.advance(self._sim_time(arrived))
        fw.receive(data)
        self._run(arrived)

    # -- time ---------------------------------------------------------------------------

    def _sim_time(self, when: float) -> float:
        return (when - self._t0) * self.settings.time_scale

    def _run(self, when: float) -> None:
        fw = self.firmware
        if not self.settings.realtime:
            fw.settle()
        self._flush(when)
        self._schedule()

    def _schedule(self) -> None:
        if self._wake_timer is not None:
            self._wake_timer.cancel()
            self._wake_timer = None
        event = self.firmware.next_event()
        if event is None or self.closed or not self.settings.realtime:
            return
        when = self._t0 + event / self.settings.time_scale
        self._wake_timer = self._loop.call_at(when, self._wake)

    def _wake(self) -> None:
        self._wake_timer = None
        now = self._loop.time()
        self.firmware.advance(self._sim_time(now))
        self._run(now)

    # -- output -------------------------------------------------------------------------

    def _flush(self, produced: float) -> None:
        """Send the firmware's replies, produced at ``produced``, at the wire rate: each
        line leaves when its last byte has crossed the wire, as on a real one (a burst of
        replies, such as a heat-up's reports in fast mode, arrives over the time it takes,
        not at once at the end)."""
        data = self.firmware.take_output()
        if not data or self.closed:
            return
        if self._rate == float("inf"):
            self._write(data)
            return
        free = max(self._out_free, produced)
        for line in data.splitlines(keepends=True):
            free += len(line) / self._rate
            self._outbox.append((free, line))
        self._out_free = free
        if self._out_timer is None:  # else the armed timer reaches these replies in turn
            self._drain_outbox()

    def _drain_outbox(self) -> None:
        self._out_timer = None
        now = self._loop.time()
        due: list[bytes] = []
        while self._outbox and self._outbox[0][0] <= now:
            due.append(self._outbox.popleft()[1])
        if due and not self.closed:
            self._write(b"".join(due))
        if self._outbox and not self.closed:
            self._out_timer = self._loop.call_at(self._outbox[0][0], self._drain_outbox)

    def close(self) -> None:
        """Stop all timers; later input is ignored."""
        self.closed = True
        for timer in (self._in_timer, self._out_timer, self._wake_timer):
            if timer is not None:
                timer.cancel()


class _SocketSide(asyncio.Protocol):
    """Adapter: the emulator on one end of a stream socket."""

    def __init__(self, settings: SimSettings) -> None:
        self.settings = settings
        self.emulator: Emulator | None = None
        self.transport: asyncio.Transport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport
        self.emulator = Emulator(self.settings, transport.write)

    def data_received(self, data: bytes) -> None:
        if self.emulator is not None:
            self.emulator.feed(data)

    def connection_lost(self, exc: Exception | None) -> None:
        if self.emulator is not None:
            self.emulator.close()


class SocketEmulator:
    """An emulator serving one connected socket (the board end of ``sim://``)."""

    def __init__(self, side: _SocketSide) -> None:
        self._side = side

    @classmethod
    async def serve(cls, settings: SimSettings, sock: socket.socket) -> SocketEmulator:
        """Attach a fresh emulator to ``sock`` (a connected stream socket)."""
        loop = asyncio.get_running_loop()
        side = _SocketSide(settings)
        await loop.create_connection(lambda: side, sock=sock)
        return cls(side)

    @property
    def emulator(self) -> Emulator:
        """The running emulator."""
        assert self._side.emulator is not None
        return self._side.emulator

    @property
    def firmware(self) -> Firmware:
        """The emulated board, for inspection in tests."""
        return self.emulator.firmware

    def unplug(self) -> None:
        """Drop the connection, as a pulled USB cable does."""
        self.emulator.close()
        if self._side.transport is not None:
            self._side.transport.close()
