"""Open the byte stream to the board: a real port or pty, or the in-process emulator."""

from __future__ import annotations

import asyncio
import socket
from dataclasses import dataclass

import serial_asyncio

from hostd.link.settings import LinkSettings
from hostd.sim.server import SocketEmulator
from hostd.sim.settings import SimSettings

SIM_SCHEME = "sim://"


@dataclass
class Connection:
    """An open port: the stream pair and, for ``sim://``, the emulator behind it."""

    reader: asyncio.StreamReader
    writer: asyncio.StreamWriter
    emulator: SocketEmulator | None = None

    def close(self) -> None:
        """Close the port (and stop the emulator)."""
        if self.emulator is not None:
            self.emulator.unplug()
        self.writer.close()


async def open_port(settings: LinkSettings, sim: SimSettings | None) -> Connection:
    """Open ``settings.port``: ``sim://`` starts an emulator on a socket pair.

    Raises
    ------
    OSError
        The device cannot be opened (``serial.SerialException`` is an ``OSError``).
    """
    if settings.port.startswith(SIM_SCHEME):
        return await _open_sim(sim or SimSettings(baud=settings.baud))
    reader, writer = await serial_asyncio.open_serial_connection(
        url=settings.port, baudrate=settings.baud)
    return Connection(reader, writer)


async def _open_sim(sim: SimSettings) -> Connection:
    host, board = socket.socketpair()
    emulator = await SocketEmulator.serve(sim, board)
    reader, writer = await asyncio.open_connection(sock=host)
    return Connection(reader, writer, emulator)
