"""Open the byte stream to the board: a real port or pty, or the in-process emulator.

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

import serial
import serial_asyncio

from hostd.link.settings import LinkSettings
from hostd.sim.server import SocketEmulator
from hostd.sim.settings import SimSettings

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
    """

    def _read_ready(self) -> None:
        """Read what the port holds with one system call (pyserial's ``read`` adds a
        ``select`` and timeout bookkeeping to every call)."""
        try:
            data = os.read(self._serial.fileno(), self._max_read_size)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            self._close(exc=serial.SerialException(f"read failed: {exc}"))
            return
        if not data:
            self._close(exc=serial.SerialException("device disconnected"))
            return
        self._protocol.data_received(data)

    def write(self, data: bytes) -> None:  # type: ignore[override]
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
    transport = DirectSerialTransport(loop, receiver, port)
    return Connection(transport, receiver)


async def open_socket(sock: socket.socket) -> Connection:
    """A connection over a connected stream socket (the emulator's, or a test's)."""
    receiver = LineReceiver()
    transport, _ = await asyncio.get_running_loop().create_connection(lambda: receiver,
                                                                      sock=sock)
    return Connection(transport, receiver)


async def _open_sim(sim: SimSettings) -> Connection:
    host, board = socket.socketpair()
    emulator = await SocketEmulator.serve(sim, board)
    conn = await open_socket(host)
    conn.emulator = emulator
    return conn
