"""The emulator's throttled wire: replies leave line by line, never before the wire allows."""

from __future__ import annotations

import asyncio

import pytest

from hostd.link.framing import encode, frame
from hostd.sim.firmware import Firmware
from hostd.sim.server import Emulator
from hostd.sim.settings import SimSettings

HEAT_UP = ["M190 S100", "M109 S260"]  # fast mode: some 500 report lines at once


def framed(commands: list[str]) -> bytes:
    return b"".join(encode(frame(n, c)) for n, c in enumerate(commands, 1))


def fast_mode_output(settings: SimSettings, data: bytes) -> bytes:
    """What the firmware alone answers to ``data``, settled at once."""
    fw = Firmware(settings)
    fw.take_output()  # the boot banner
    fw.receive(data)
    fw.settle()
    return fw.take_output()


@pytest.mark.asyncio
async def test_a_burst_of_replies_crosses_the_wire_line_by_line() -> None:
    settings = SimSettings(baud=115200, throttle=True)
    loop = asyncio.get_running_loop()
    data = framed(HEAT_UP)
    banner, expected = Firmware(settings).take_output(), fast_mode_output(settings, data)
    writes: list[tuple[float, bytes]] = []
    done = asyncio.Event()

    def record(chunk: bytes) -> None:
        writes.append((loop.time(), chunk))
        if sum(len(d) for _, d in writes) >= len(banner) + len(expected):
            done.set()

    booted = loop.time()
    emulator = Emulator(settings, record)
    fed = loop.time()
    emulator.feed(data)
    async with asyncio.timeout(30):
        await done.wait()
    emulator.close()
    assert b"".join(d for _, d in writes) == banner + expected
    rate = settings.wire_bytes_per_second
    # the wire carries the banner, then the replies once the first command is in: no byte
    # leaves before the wire could have carried it
    first_in = fed + len(framed(HEAT_UP[:1])) / rate
    earliest = wire_times(writes, len(banner), booted, first_in, rate)
    assert all(when >= ready - 1e-6 for (when, _), ready in zip(writes, earliest, strict=True))
    # the burst (21 KB, 1.8 s of wire) arrives as it crosses, not in one write at the end
    assert len(writes) > 10 and all(chunk.endswith(b"\n") for _, chunk in writes)


def wire_times(writes: list[tuple[float, bytes]], banner: int, booted: float,
               replies_from: float, rate: float) -> list[float]:
    """The earliest each write could arrive: the ``banner`` bytes from the boot, the rest
    from ``replies_from``, one after another at ``rate``."""
    out, free, seen = [], booted, 0
    for _, chunk in writes:
        start = free if seen < banner else max(free, replies_from)
        seen += len(chunk)
        free = start + len(chunk) / rate
        out.append(free)
    return out
