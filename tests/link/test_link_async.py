"""The asyncio shell against the in-process emulator (``sim://``), in fast mode."""

from __future__ import annotations

import asyncio
import dataclasses
import random

import pytest

from hostd.link import (
    EmergencyStop,
    FirmwareReset,
    LinkLost,
    LinkSettings,
    SerialLink,
)
from hostd.link.replies import Position, Temperatures
from hostd.link.transport import Connection, open_port
from hostd.sim.firmware import Firmware
from hostd.sim.settings import SimSettings

FAST = LinkSettings(ok_timeout=0.3, nudges=3, handshake_timeout=0.5, reconnect_min=0.01,
                    reconnect_max=0.05)


def moves(n: int, seed: int = 0) -> list[str]:
    rng = random.Random(seed)
    return [f"G1 X{rng.uniform(0, 5):.2f} Y{rng.uniform(0, 5):.2f} C{rng.uniform(0, 9):.1f} "
            f"E{i * 0.02:.3f} F6000" for i in range(n)]


def board(link: SerialLink) -> Firmware:
    assert link.connection is not None and link.connection.emulator is not None
    return link.connection.emulator.firmware


def executed(firmware: Firmware) -> list[str]:
    """The numbered job lines the board executed: queries and ``M110`` s (the handshake, a
    resynchronisation) left out."""
    queries = ("M105", "M114", "M115")
    return [t for n, t in firmware.log
            if n is not None and n > 0 and t not in queries and not t.startswith("M110")]


async def collect(link: SerialLink, lines: list[str]) -> list[int]:
    return [i async for i in link.stream(lines)]


@pytest.mark.asyncio
@pytest.mark.parametrize("rx", [127, 63])
async def test_stream_with_faults_executes_everything_once_and_reports_status(rx: int) -> None:
    sim = SimSettings(bit_flip_prob=0.01, lost_ok_prob=0.002, busy_prob=0.01,
                      busy_seconds=0.5, rx_buffer_bytes=rx, seed=5)
    link = SerialLink(dataclasses.replace(FAST, rx_buffer_bytes=rx), sim)
    lines = ["; sliced", "", *moves(3000)]
    async with asyncio.timeout(60):
        await link.connect()
        firmware = board(link)
        acked = await collect(link, lines)
        status = link.status()
        position = await link.query("M114")
        temps = await link.query("M105")
        await link.close()
    assert acked == list(range(2, len(lines)))  # comment and blank line skipped
    assert executed(firmware) == lines[2:]
    assert status["connected"] and status["firmware_name"].startswith("Marlin")
    assert status["lines_acked"] >= 3000 and status["checksum_errors"] > 0
    assert status["lines_resent"] > 0 and status["ok_rtt"]["count"] > 0
    assert status["lines_split"] > 0 and firmware.dropped_bytes == 0  # lines went in parts
    assert isinstance(position, Position) and set("XYZAC") <= set(position.axes)
    assert isinstance(temps, Temperatures) and "T" in temps.heaters


@pytest.mark.asyncio
async def test_firmware_reset_interrupts_the_job_at_the_last_acknowledged_line() -> None:
    link = SerialLink(FAST, SimSettings(reset_at_line=250))
    lines = moves(1000)
    async with asyncio.timeout(30):
        await link.connect()
        firmware = board(link)
        with pytest.raises(FirmwareReset) as info:
            await collect(link, lines)
        await link.wait_connected()  # the link handshakes again by itself
        pos = await link.query("M114")
        await link.close()
    # The board rebooted after 250 numbered lines: M115 from connect() and 249 job lines.
    assert executed(firmware) == lines[:249]
    assert info.value.job_line is not None and info.value.job_line <= 248
    assert isinstance(pos, Position) and pos.axes["X"] == 0.0  # a fresh board


@pytest.mark.asyncio
async def test_a_silent_board_is_nudged_and_the_swallowed_lines_are_resent(
        caplog: pytest.LogCaptureFixture) -> None:
    link = SerialLink(FAST, SimSettings(silence_at_line=100, silence_lines=4))
    lines = moves(400)
    async with asyncio.timeout(30):
        await link.connect()
        firmware = board(link)
        acked = await collect(link, lines)
        timeouts = link.status()["timeouts"]
        await link.close()
    assert acked == list(range(400))
    assert executed(firmware) == lines
    assert timeouts >= 1
    # the journal tells the operator: each timeout (the first with its nudge; the line that
    # went out in parts when the board fell silent was swallowed too, and the drain after
    # the resend request waits a timeout for its answer), then the resend
    logged = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert sum("no ok for 0.3 s" in m for m in logged) == timeouts
    assert "nudge" in next(m for m in logged if "no ok for 0.3 s" in m)
    assert any(m.startswith("sim://: firmware asked for line") for m in logged)


@pytest.mark.asyncio
async def test_a_board_that_stays_silent_is_declared_lost() -> None:
    settings = LinkSettings(ok_timeout=0.1, nudges=1, reconnect_min=5.0)
    link = SerialLink(settings, SimSettings(silence_at_line=10, silence_lines=10**9))
    async with asyncio.timeout(30):
        await link.connect()
        with pytest.raises(LinkLost, match="nudge"):
            await collect(link, moves(100))
        await link.close()


@pytest.mark.asyncio
async def test_emergency_stop_overtakes_a_full_window() -> None:
    # 2400 baud: 240 bytes/s, so the 127-byte window stays full for a while.
    link = SerialLink(LinkSettings(ok_timeout=5.0), SimSettings(baud=2400, throttle=True))
    lines = moves(200)
    async with asyncio.timeout(30):
        await link.connect()
        board = link.connection.emulator.emulator  # type: ignore[union-attr]
        halted = asyncio.Event()
        write = board._write

        def spy(data: bytes) -> None:
            if b"halted" in data:
                halted.set()
            write(data)

        board._write = spy
        futures = link.enqueue(lines)
        await futures[0]
        assert link.status()["inflight_bytes"] > 60  # a window's worth is on the wire
        link.emergency_stop()
        results = await asyncio.gather(*futures, return_exceptions=True)
        await halted.wait()  # the M112 crossed the throttled wire
        await link.close()
    firmware = board.firmware
    assert firmware.log[-1] == (None, "M112")
    ran = [t for n, t in firmware.log if n is not None and n > 0 and t != "M115"]
    assert len(ran) < 10 and ran == lines[:len(ran)]
    assert any(isinstance(r, EmergencyStop) for r in results)


@pytest.mark.asyncio
async def test_the_link_reconnects_with_backoff_when_the_port_comes_back(
        caplog: pytest.LogCaptureFixture) -> None:
    attempts: list[str] = []
    available = asyncio.Event()
    available.set()

    async def flaky(settings: LinkSettings, sim: SimSettings | None) -> Connection:
        if not available.is_set():
            attempts.append("refused")
            available.set()  # the port comes back for the next attempt
            raise FileNotFoundError("no such device")
        attempts.append("opened")
        return await open_port(settings, sim)

    link = SerialLink(FAST, SimSettings(), opener=flaky)
    async with asyncio.timeout(30):
        await link.connect()
        await link.send("G1 X1")
        available.clear()
        assert link.connection is not None and link.connection.emulator is not None
        link.connection.emulator.unplug()
        with pytest.raises(LinkLost):
            await collect(link, moves(50))
        await link.wait_connected()
        await link.send("G1 X2")
        reconnects = link.reconnects
        await link.close()
    assert attempts[:3] == ["opened", "refused", "opened"]
    assert reconnects == 1
    # the journal: the loss with its cause, then the way back
    logged = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    lost = [i for i, m in enumerate(logged) if m.startswith("sim://: link lost (")]
    back = [i for i, m in enumerate(logged) if m == "sim://: link back after 2 attempt(s)"]
    assert len(lost) == len(back) == 1 and lost[0] < back[0]


@pytest.mark.asyncio
async def test_m114_shows_a_lost_step_on_c() -> None:
    sim = SimSettings(lost_step_axis="C", lost_step_degrees=1.8, lost_step_at_move=2)
    link = SerialLink(FAST, sim)
    async with asyncio.timeout(10):
        await link.connect()
        for c in (10, 20, 30):
            await link.send(f"G1 C{c} F3000")
        await link.send("G1 X5")  # no C change: not counted
        pos = await link.query("M114")
        await link.close()
    assert isinstance(pos, Position)
    assert pos.axes["C"] == pytest.approx(31.8)
    assert pos.axes["X"] == pytest.approx(5.0)


@pytest.mark.asyncio
async def test_a_long_heat_up_without_busy_keepalive_does_not_lose_the_link() -> None:
    """A board without Marlin's busy keepalive heats for several ok timeouts (2 s of wall
    time here; 0.5 s timeouts, one nudge): its once-a-second heater lines keep the link."""
    sim = SimSettings(busy_interval=0, realtime=True, time_scale=50.0)
    link = SerialLink(dataclasses.replace(FAST, ok_timeout=0.5, nudges=1), sim)
    lines = ["M109 S200", "G1 X1 F6000", "M105"]
    async with asyncio.timeout(30):
        await link.connect()
        firmware = board(link)
        acked = await collect(link, lines)
        status = link.status()
        await link.close()
    assert acked == [0, 1, 2] and [t for _, t in firmware.log[-3:]] == lines
    assert firmware.machine.hotend.temperature(firmware.now) == pytest.approx(200.0, abs=1.0)
    assert status["firmware_name"] and firmware.boots == 1
