"""``hostd-sim --pty`` as a separate process, driven by the link through the real port path."""

from __future__ import annotations

import asyncio
import sys
from pathlib import Path

import pytest

from hostd.link import LinkSettings, SerialLink
from hostd.link.replies import Position


@pytest.mark.asyncio
async def test_link_streams_through_the_pty_emulator(tmp_path: Path) -> None:
    log = tmp_path / "executed.log"
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "hostd.sim.main", "--pty", "--log", str(log), "--lost-step-axis", "C",
        "--lost-step-degrees", "0.5", "--lost-step-at-move", "1",
        stdout=asyncio.subprocess.PIPE)
    try:
        async with asyncio.timeout(30):
            assert proc.stdout is not None
            path = (await proc.stdout.readline()).decode().strip()
            assert path.startswith("/dev/")
            link = SerialLink(LinkSettings(port=path, ok_timeout=2.0))
            await link.connect()
            lines = [f"G1 X{i % 7} C{i} F6000" for i in range(300)]
            acked = [i async for i in link.stream(lines)]
            pos = await link.query("M114")
            status = link.status()
            await link.close()
    finally:
        proc.terminate()
        await proc.wait()
    assert acked == list(range(300))
    # written when the emulator stops: the stream once, in order, between the link's queries
    assert log.read_text().splitlines() == ["M115", *lines, "M114"]
    assert isinstance(pos, Position) and pos.axes["C"] == pytest.approx(299.5)
    assert status["firmware_name"].startswith("Marlin")


@pytest.mark.asyncio
async def test_a_heat_up_burst_on_a_throttled_pty_loses_no_ok() -> None:
    """In fast mode a heat-up's once-a-second reports come out together (21 KB here, more
    than a pty holds) while hostd holds its reads: every ``ok`` must still arrive, or the
    link waits for one the board sent and times out."""
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "hostd.sim.main", "--pty", "--throttle", "--baud", "250000",
        stdout=asyncio.subprocess.PIPE)
    try:
        async with asyncio.timeout(60):
            assert proc.stdout is not None
            path = (await proc.stdout.readline()).decode().strip()
            link = SerialLink(LinkSettings(port=path, baud=250000, ok_timeout=2.0))
            assert link.settings.read_hold > 0  # the daemon's held reads, as it streams
            await link.connect()
            lines = ["M190 S100", "M109 S260", *(f"G1 X{i % 9} Y{i % 7} E0.02 F1800"
                                                 for i in range(200))]
            acked = [i async for i in link.stream(lines)]
            status = link.status()
            await link.close()
    finally:
        proc.terminate()
        await proc.wait()
    assert acked == list(range(len(lines)))
    assert status["timeouts"] == 0 and status["resend_requests"] == 0
    assert status["temperatures"]["T"]["actual"] > 250
