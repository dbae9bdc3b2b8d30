"""The link, unchanged, against another project's Marlin emulator: OctoPrint's virtual printer.

Skipped when OctoPrint is not installed (it is a large web application and not a dependency of
hostd). To run it: install ``octoprint`` in a separate virtualenv together with hostd's test
requirements and run this file with ``PYTHONPATH`` pointing at the checkout.

Its line errors are Marlin's only. Marlin moves ``last_N`` once a line passes its checks and
answers a bad line with ``Resend: last_N + 1``, the line it rejected. Two of the emulator's own
error modes lose a line instead, which no host can account for, so they are not used:

- ``resend_ratio`` draws its errors after the line is accepted (``lastN`` already holds its
  number): the line is discarded and the *next* one requested, which may already be on the
  wire and is then accepted;
- ``resend_with_timeout`` (in its default ``simulated_errors``) requests the line, records it
  as received anyway and swallows the next line.

Against those the oks run one line short of the lines sent, so the host counts them a line
behind until a nudge's ``ok T:`` resynchronises, and a rewind to a line the board already
holds draws a ``Resend`` for the next one: each lost line costs a few ``ok`` timeouts.

Nor is its ``okFormatString`` given ADVANCED_OK fields (``ok N{lastN} P… B{buffer}``): it
answers a line when it queues it, with the last line received and the slots free after it
(``B`` reaches the full queue size). Marlin answers a line once it is processed, while it
still holds its slot, which is what hostd's credit counts on (:mod:`hostd.link.protocol`);
with the emulator's format hostd takes queued lines for read out of the receive buffer and
overfills it.
"""

from __future__ import annotations

import asyncio
import socket
import tempfile
import threading
from typing import Any

import pytest

from hostd.link import LinkSettings, SerialLink
from hostd.link.replies import Position, Temperatures
from hostd.link.transport import Connection, open_socket
from hostd.sim.settings import SimSettings

virtual = pytest.importorskip(
    "octoprint.plugins.virtual_printer.virtual",
    reason="OctoPrint is not installed (optional: pip install octoprint in a separate venv)")
plugin = pytest.importorskip("octoprint.plugins.virtual_printer")

from bench.virtual_printer import NoPlugins, Profiles, Settings  # noqa: E402  (OctoPrint's)


def _pump_writes(sock: socket.socket, printer: Any) -> None:
    buf = b""
    while True:
        data = sock.recv(4096)
        if not data:
            return
        buf += data
        *lines, buf = buf.split(b"\n")
        for line in lines:
            printer.write(line + b"\n")


def _pump_reads(sock: socket.socket, printer: Any, stop: threading.Event) -> None:
    while not stop.is_set():
        line = printer.readline()  # without its newline, unlike a real port
        if line:
            try:
                sock.sendall(line.rstrip(b"\r\n") + b"\n")
            except OSError:
                return


# Marlin's errors, at fixed lines: a resend of the line, a checksum mismatch (both answered
# with ``Resend`` and an error ``ok``), and a line with no number (only an ``Error:``)
MARLIN_ERRORS = [
    *(f"{n}:resend" for n in range(12, 150, 25)),
    *(f"{n}:checksum_mismatch" for n in range(25, 150, 25)),
    "140:missing_lineno",
]


def opener_for(overrides: dict[str, Any]) -> Any:
    async def open_virtual(settings: LinkSettings, sim: SimSettings | None) -> Connection:
        host, board = socket.socketpair()
        printer = virtual.VirtualPrinter(Settings(overrides), Profiles(),
                                         tempfile.mkdtemp(), read_timeout=0.1)
        stop = threading.Event()
        threading.Thread(target=_pump_writes, args=(board, printer), daemon=True).start()
        threading.Thread(target=_pump_reads, args=(board, printer, stop), daemon=True).start()
        return await open_socket(host)
    return open_virtual


@pytest.mark.asyncio
@pytest.mark.parametrize("overrides", [
    {},
    {"sendBusy": True, "okFormatString": "ok"},
    {"rxBuffer": 127, "commandBuffer": 4},
], ids=["defaults", "busy", "small-buffers"])
async def test_stream_against_octoprint_virtual_printer(
        overrides: dict[str, Any], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(virtual, "plugin_manager", NoPlugins)
    # The virtual printer emulates a 64-byte receive buffer unless told otherwise.
    rx = int(overrides.get("rxBuffer", 64))
    link = SerialLink(LinkSettings(ok_timeout=2.0, nudges=3, handshake_timeout=2.0,
                                   rx_buffer_bytes=rx),
                      opener=opener_for({"simulateReset": False,
                                          "simulated_errors": MARLIN_ERRORS, **overrides}))
    lines = ["G90", *(f"G1 X{i % 10} Y{i % 6} F12000" for i in range(150)), "M400"]
    async with asyncio.timeout(120):
        await link.connect()
        acked = [i async for i in link.stream(lines)]
        pos = await link.query("M114")
        temps = await link.query("M105")
        status = link.status()
        await link.close()
    assert acked == list(range(len(lines)))
    assert isinstance(pos, Position) and pos.axes["X"] == pytest.approx(149 % 10)
    assert pos.axes["Y"] == pytest.approx(149 % 6)
    assert isinstance(temps, Temperatures) and "T" in temps.heaters
    assert status["firmware_name"]
    assert status["lines_resent"] > 0
