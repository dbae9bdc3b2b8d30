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
from typing import Any

import pytest

from hostd.link import LinkSettings, SerialLink
from hostd.link.replies import Position, Temperatures
from hostd.link.transport import Connection, open_socket
from hostd.sim.settings import SimSettings

pytest.importorskip(
    "octoprint.plugins.virtual_printer.virtual",
    reason="OctoPrint is not installed (optional: pip install octoprint in a separate venv)")
from bench.virtual_printer import Noise, attach

# Marlin's errors, at fixed lines: a resend of the line, a checksum mismatch (both answered
# with ``Resend`` and an error ``ok``), and a line with no number (only an ``Error:``)
MARLIN_ERRORS = [
    *(f"{n}:resend" for n in range(12, 150, 25)),
    *(f"{n}:checksum_mismatch" for n in range(25, 150, 25)),
    "140:missing_lineno",
]


def opener_for(overrides: dict[str, Any], noise: Noise | None = None) -> Any:
    async def open_virtual(settings: LinkSettings, sim: SimSettings | None) -> Connection:
        host, board = socket.socketpair()
        attach(board, overrides, noise)
        return await open_socket(host)
    return open_virtual


@pytest.mark.asyncio
@pytest.mark.parametrize("overrides", [
    {},
    {"sendBusy": True, "okFormatString": "ok"},
    {"rxBuffer": 127, "commandBuffer": 4},
], ids=["defaults", "busy", "small-buffers"])
async def test_stream_against_octoprint_virtual_printer(
        overrides: dict[str, Any]) -> None:
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


@pytest.mark.asyncio
@pytest.mark.parametrize("mode", ["window", "pingpong"])
async def test_a_noisy_line_costs_no_ok_timeout_and_runs_every_line_once(mode: str) -> None:
    """Issue 38, item 6: 2 % of the host's lines corrupted (a bit flipped, caught by the
    checksum). The emulator counts the lines a window had in flight and refused, and at its
    next error asks for a line never sent; the link used to wait out the ok timeout there.
    Relative moves of E 1 each: the E at the end counts every line executed, each once."""
    noise = Noise(0.02, seed=3)
    link = SerialLink(LinkSettings(ok_timeout=5.0, handshake_timeout=2.0, flow_control=mode,
                                   rx_buffer_bytes=64),  # the emulator's receive buffer
                      opener=opener_for({"simulateReset": False, "simulated_errors": []},
                                        noise))
    n = 600
    lines = ["G91", *(["G1 E1 F60000"] * n), "M400"]
    async with asyncio.timeout(120):
        await link.connect()
        acked = [i async for i in link.stream(lines)]
        pos = await link.query("M114")
        status = link.status()
        await link.close()
    assert acked == list(range(len(lines)))
    assert isinstance(pos, Position) and pos.axes["E"] == pytest.approx(n)
    assert noise.corrupted >= 5 and status["resend_requests"] >= noise.corrupted
    assert status["timeouts"] == 0
