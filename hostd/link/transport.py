"""Open the byte stream to the board: a real port or pty, or the in-process emulator (imported
only when ``sim://`` is opened).

The port is an asyncio transport with a :class:`LineReceiver` protocol: every chunk the
kernel hands over is split into lines in the transport's own callback and passed on at once,
so an ``ok`` is handled (and the lines it frees are written) without a task switch.
"""

from __future__ import annotations

import asyncio
import os
import socket
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import serial
import serial_asyncio

from hostd.link.read_hold import HOLD_MIN_BUFFER, ReadHold
from hostd.link.settings import BITS_PER_BYTE, LinkSettings
from hostd.sim.settings import SimSettings

if TYPE_CHECKING:
    from hostd.sim.server import SocketEmulator

SIM_SCHEME = "sim://"
LinesHandler = Callable[[list[bytes]], None]
LostHandler = Callable[[str], None]


class LineReceiver(asyncio.Protocol):
    """Splits the received bytes into lines (without the newline).

    Lines that arrive before :meth:`attach` (the banner of a board that boots as the port
    opens) are kept and handed over on attaching.
    """

    def __init__(self) -> None:
        self._partial = b""
        self._early: list[bytes] = []
        self._lost: str | None = None
        self._on_lines: LinesHandler | None = None
        self._on_lost: LostHandler | None = None

    def attach(self, on_lines: LinesHandler, on_lost: LostHandler) -> None:
        """Route the lines (and the end of the connection) to these callbacks from now on."""
        self._on_lines, self._on_lost = on_lines, on_lost
        early, self._early = self._early, []
        if early:
            on_lines(early)
        if self._lost is not None:
            on_lost(self._lost)

    def detach(self) -> None:
        """Stop delivering (the link has moved on to another connection)."""
        self._on_lines = self._on_lost = None

    def data_received(self, data: bytes) -> None:
        *lines, self._partial = (self._partial + data).split(b"\n")
        if not lines:
            return
        if self._on_lines is None:
            self._early += lines
        else:
            self._on_lines(lines)

    def eof_received(self) -> bool:
        return False  # close the transport; connection_lost follows

    def connection_lost(self, exc: Exception | None) -> None:
        self._lost = str(exc) if exc is not None else "end of stream"
        if self._on_lost is not None:
            self._on_lost(self._lost)


class DirectSerialTransport(serial_asyncio.SerialTransport):
    """pyserial-asyncio's transport, writing at once when nothing is queued.

    The stock transport queues every write until the next loop iteration (a writer callback
    per line); asyncio's own socket and pipe transports try the write first, and so does this.
    It also reads and writes with a single ``os.read`` or ``os.write`` (the port is
    non-blocking: pyserial's calls add timeout bookkeeping, and its read a ``select``).

    With a :class:`ReadHold` it reads in batches while replies come at the wire's pace: after
    data, the port may be left unread for a moment and then read by a timer, so one wake-up
    takes in several ``ok``. When a timed read finds nothing, the port is watched again.
    """

    def __init__(self, loop: asyncio.AbstractEventLoop, protocol: asyncio.Protocol,
                 serial_instance: serial.Serial, *, hold: ReadHold | None = None) -> None:
        self._hold = hold
        self._held: asyncio.TimerHandle | None = None
        super().__init__(loop, protocol, serial_instance)

    def _read_ready(self) -> None:
        data = self._read_once(ready=True)
        if data:
            self._protocol.data_received(data)
            if self._hold is not None:
                self._hold_or_watch(data)

    def _read_once(self, *, ready: bool) -> bytes:
        """What the port holds, in one system call (``b""`` if nothing, or on closing).

        A tty read with nothing to read returns no bytes (pyserial sets ``VMIN = 0``): that
        means the device is gone only when the loop had reported the port ``ready``.
        """
        try:
            data = os.read(self._serial.fileno(), self._max_read_size)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError as exc:
            self._close(exc=serial.SerialException(f"read failed: {exc}"))
            return b""
        if not data and ready:
            self._close(exc=serial.SerialException("device disconnected"))
        return data

    def _hold_or_watch(self, data: bytes) -> None:
        """``data`` just arrived and was handled: hold the next read, or watch the port."""
        assert self._hold is not None
        now = self._loop.time()
        hold = self._hold.after_data(now, data.count(b"\n"))
        if self._closing:
            return
        if hold:
            self._remove_reader()
            self._held = self._loop.call_at(now + hold, self._read_held)
        else:
            self._ensure_reader()

    def _read_held(self) -> None:
        self._held = None
        if self._closing:
            return
        data = self._read_once(ready=False)
        if data:
            self._protocol.data_received(data)
            self._hold_or_watch(data)
        else:
            self._ensure_reader()

    def pause_reading(self) -> None:
        if self._held is not None:
            self._held.cancel()
            self._held = None
        super().pause_reading()

    def write(self, data: bytes) -> None:
        if self._hold is not None:
            self._hold.wrote(self._loop.time(), len(data))
        if self._closing or self._write_buffer or not data:
            super().write(data)
            return
        try:
            n = os.write(self._serial.fileno(), data)
        except (BlockingIOError, InterruptedError):
            n = 0
        except OSError as exc:
            self._fatal_error(serial.SerialException(f"write failed: {exc}"),
                              "Fatal write error on serial transport")
            return
        if n < len(data):
            super().write(data[n:])


@dataclass
class Connection:
    """An open port: its transport, the line receiver and, for ``sim://``, the emulator."""

    transport: asyncio.Transport
    receiver: LineReceiver
    emulator: SocketEmulator | None = None

    def write(self, data: bytes) -> None:
        """Queue bytes for the board (written at once when the port can take them)."""
        if not self.transport.is_closing():
            self.transport.write(data)

    def close(self) -> None:
        """Close the port (and stop the emulator)."""
        self.receiver.detach()
        if self.emulator is not None:
            self.emulator.unplug()
        self.transport.close()


async def open_port(settings: LinkSettings, sim: SimSettings | None) -> Connection:
    """Open ``settings.port``: ``sim://`` starts an emulator on a socket pair.

    Raises
    ------
    OSError
        The device cannot be opened (``serial.SerialException`` is an ``OSError``).
    """
    if settings.port.startswith(SIM_SCHEME):
        return await _open_sim(sim or SimSettings(baud=settings.baud))
    loop = asyncio.get_running_loop()
    port = serial.serial_for_url(settings.port, baudrate=settings.baud)
    receiver = LineReceiver()
    transport = DirectSerialTransport(loop, receiver, port, hold=read_hold(settings))
    return Connection(transport, receiver)


async def open_socket(sock: socket.socket) -> Connection:
    """A connection over a connected stream socket (the emulator's, or a test's)."""
    receiver = LineReceiver()
    transport, _ = await asyncio.get_running_loop().create_connection(lambda: receiver,
                                                                      sock=sock)
    return Connection(transport, receiver)


def read_hold(settings: LinkSettings) -> ReadHold | None:
    """Held reads for a real port in window mode with ``serial.read_hold`` > 0 and a receive
    buffer of :data:`HOLD_MIN_BUFFER` bytes or more. With one line in flight (ping-pong), or
    a buffer of less than 2.5 lines, a hold has at most one reply to collect: it could only
    delay it."""
    if (settings.flow_control != "window" or settings.read_hold <= 0
            or settings.rx_buffer_bytes < HOLD_MIN_BUFFER):
        return None
    return ReadHold(settings.read_hold, BITS_PER_BYTE / settings.baud)


async def _open_sim(sim: SimSettings) -> Connection:
    """The emulator on one end of a socket pair, the link on the other. The emulator is
    imported here, on its first use: a hostd that drives a printer never loads it."""
    from hostd.sim.server import SocketEmulator

    host, board = socket.socketpair()
    emulator = await SocketEmulator.serve(sim, board)
    conn = await open_socket(host)
    conn.emulator = emulator
    return conn
