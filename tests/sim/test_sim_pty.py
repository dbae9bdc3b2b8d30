"""``hostd-sim --pty`` as a separate process, driven by the link through the real port path."""

from __future__ import annotations

import asyncio
import contextlib
import sys
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from hostd.link import LinkSettings, SerialLink
from hostd.link.replies import Position


@contextlib.asynccontextmanager
async def pty_emulator(*args: str) -> AsyncIterator[str]:
    """``hostd-sim --pty ARGS`` in a process of its own: the pty's path; stopped on leaving
    (which writes its ``--log``)."""
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "hostd.sim.main", "--pty", *args, stdout=asyncio.subprocess.PIPE)
    try:
        assert proc.stdout is not None
        path = (await proc.stdout.readline()).decode().strip()
        assert path.startswith("/dev/")
        yield path
    finally:
        proc.terminate()
        await proc.wait()


@pytest.mark.asyncio
async def test_link_streams_through_the_pty_emulator(tmp_path: Path) -> None:
    log = tmp_path / "executed.log"
    async with asyncio.timeout(30), pty_emulator(
            "--log", str(log), "--lost-step-axis", "C", "--lost-step-degrees", "0.5",
            "--lost-step-at-move", "1") as path:
        link = SerialLink(LinkSettings(port=path, ok_timeout=2.0))
        await link.connect()
        lines = [f"G1 X{i % 7} C{i} F6000" for i in range(300)]
        acked = [i async for i in link.stream(lines)]
        pos = await link.query("M114")
        status = link.status()
        await link.close()
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
    async with asyncio.timeout(60), pty_emulator("--throttle", "--baud", "250000") as path:
        link = SerialLink(LinkSettings(port=path, baud=250000, ok_timeout=2.0))
        assert link.settings.read_hold > 0  # the daemon's held reads, as it streams
        await link.connect()
        lines = ["M190 S100", "M109 S260", *(f"G1 X{i % 9} Y{i % 7} E0.02 F1800"
                                             for i in range(200))]
        acked = [i async for i in link.stream(lines)]
        status = link.status()
        await link.close()
    assert acked == list(range(len(lines)))
    assert status["timeouts"] == 0 and status["resend_requests"] == 0
    assert status["temperatures"]["T"]["actual"] > 250
