"""The streamer on the real serial link and emulator: what only the wire's faults show."""

from __future__ import annotations

import asyncio

import pytest
from hostd_harness import make_gcode

from hostd.daemon import LinkPort
from hostd.link import LinkSettings, SerialLink
from hostd.printer.program import parse_program
from hostd.printer.streamer import Streamer, StreamSettings
from hostd.sim.settings import SimSettings

HOST_OWN = {"M105", "M110", "M115", "M400", "M114"}  # the link's and the streamer's commands


@pytest.mark.asyncio
@pytest.mark.parametrize("seed", [0, 1, 2])
async def test_lost_oks_cost_no_timeout_at_transitions_or_the_end(seed: int) -> None:
    """Plain ``ok`` s lost on the wire (about 1 in 100 here) leave the link counting lines in
    flight that the board executed. Where the streamer waits for every line (a sub-part
    transition, the job's end), its ``M105`` barrier acknowledges them at once; without it
    each such wait lasted a whole ``ok`` timeout (and a second loss there lost the link)."""
    link = SerialLink(LinkSettings(ok_timeout=3.0), SimSettings(lost_ok_prob=0.01, seed=seed))
    prog = parse_program(make_gcode(subparts=3, layers=2, per_layer=30))
    async with asyncio.timeout(60):
        await link.connect()
        try:
            assert link.connection is not None and link.connection.emulator is not None
            firmware = link.connection.emulator.firmware
            st = Streamer(LinkPort(link), prog, StreamSettings(lookahead=16))
            assert await st.run() == "completed"
            status = link.status()
        finally:
            await link.close()
    assert firmware.faults.lost_oks >= 1  # the case this test is about happened
    assert status["timeouts"] == 0 and st.stats.transitions == 2
    executed = [c for n, c in firmware.log if n and c.split()[0] not in HOST_OWN]
    assert executed == [c for c in prog.commands if c.split()[0] not in HOST_OWN]
