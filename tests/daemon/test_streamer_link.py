"""The streamer on the real serial link and emulator: what only the wire's faults show."""

from __future__ import annotations

import asyncio
import random
from collections import Counter

import pytest
from hostd_harness import make_gcode

from hostd.daemon import LinkPort
from hostd.link import LinkSettings, SerialLink
from hostd.printer.program import parse_program
from hostd.printer.streamer import Hooks, Streamer, StreamSettings
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


def _zigzag(lines: int) -> str:
    """Moves of 5 mm at 100 mm/s (50 ms each), a layer every 50 lines, no heat-up."""
    out = ["G90", "M83"]
    for i in range(lines):
        if i % 50 == 0:
            out.append(f';HOSTD_LAYER {{"subpart": 0, "index": {i // 50}}}')
        out.append(f"G1 X{100 + 5 * (i % 2)} Y{100 + (i // 2) % 3} Z{0.2 * (1 + i // 50):.1f} "
                   "E0.05 F6000")
    return "\n".join(out) + "\n"


@pytest.mark.asyncio
@pytest.mark.parametrize("then", ["resume", "cancel"])
async def test_a_pause_takes_back_the_lines_not_sent_and_resume_sends_them_once(then: str) -> None:
    """With the firmware slower than the wire, most of the lookahead waits in the link's queue;
    a pause takes those lines back, so what still runs before the pause's retract is only
    what was on the wire when it was asked for. Resumed, every line runs once, in order."""
    link = SerialLink(LinkSettings(), SimSettings(realtime=True, time_scale=10.0, seed=1))
    prog = parse_program(_zigzag(400))
    seen: dict[str, int] = {}

    def progress(st: Streamer) -> None:
        if st.acked >= 100 and not seen:
            status = link.status()
            seen.update(acked=st.acked, wire=status["inflight_lines"],
                        queued=status["queued_lines"])
            st.request_pause()

    def paused(st: Streamer, reason: str) -> None:
        seen["at_pause"] = st.acked
        st.request_resume() if then == "resume" else st.request_cancel()

    async with asyncio.timeout(60):
        await link.connect()
        try:
            assert link.connection is not None and link.connection.emulator is not None
            firmware = link.connection.emulator.firmware
            st = Streamer(LinkPort(link), prog, StreamSettings(lookahead=64),
                          Hooks(progress=progress, paused=paused))
            result = await st.run()
            status = link.status()
        finally:
            await link.close()
    assert seen["queued"] > 0  # lines were waiting in the link: the case of this test
    assert seen["at_pause"] - seen["acked"] <= seen["wire"]
    assert status["lines_withdrawn"] >= seen["queued"]
    job, other = _split_log([c for n, c in firmware.log if n], prog.commands)
    link_own = Counter({"M105": 99, "M115": 1})  # nudges and the handshake's query
    assert Counter(other) - Counter(st.stats.extra_commands) <= link_own
    if then == "resume":
        assert result == "completed" and job == prog.commands  # each once, in order
    else:
        assert result == "cancelled" and job == prog.commands[:seen["at_pause"]]


def _split_log(log: list[str], commands: list[str]) -> tuple[list[str], list[str]]:
    """The log's lines matched in order against the file's commands, and the others (the
    host's own: pause, resume, barriers, the link's ``M105`` nudges)."""
    job: list[str] = []
    other: list[str] = []
    for cmd in log:
        if len(job) < len(commands) and cmd == commands[len(job)]:
            job.append(cmd)
        else:
            other.append(cmd)
    return job, other


@pytest.mark.asyncio
@pytest.mark.parametrize("seed", range(6))
async def test_pauses_at_random_moments_on_a_faulty_wire_run_every_line_once(seed: int) -> None:
    """Flipped bits (resends), lost ``ok`` s and pauses asked at random moments, some during a
    transition: the lines taken back are sent again on resume, and the board runs each of the
    file's lines once, in order, with only the host's own commands between them."""
    rng = random.Random(seed)
    sim = SimSettings(realtime=True, time_scale=200.0, bit_flip_prob=0.005, lost_ok_prob=0.005,
                      seed=seed)
    link = SerialLink(LinkSettings(ok_timeout=2.0, starve_timeout=0.2), sim)
    prog = parse_program(make_gcode(subparts=3, layers=2, per_layer=60))
    pauses = sorted(rng.sample(range(20, prog.total - 100), 3))  # each with acks after it

    def progress(st: Streamer) -> None:
        if pauses and st.acked >= pauses[0]:
            pauses.pop(0)
            st.request_pause()

    async def resume_soon(st: Streamer) -> None:
        await asyncio.sleep(rng.uniform(0, 0.05))  # the operator's reaction, not a sync
        st.request_resume()

    resumes: list[asyncio.Task[None]] = []
    async with asyncio.timeout(90):
        await link.connect()
        try:
            assert link.connection is not None and link.connection.emulator is not None
            firmware = link.connection.emulator.firmware
            st = Streamer(LinkPort(link), prog, StreamSettings(lookahead=64), Hooks(
                progress=progress,
                paused=lambda s, r: resumes.append(asyncio.create_task(resume_soon(s)))))
            assert await st.run() == "completed"
            await asyncio.gather(*resumes)
            resyncs = link.status()["resyncs"]
        finally:
            await link.close()
    assert len(resumes) >= 2  # two asked during one transition make one pause after it
    job, other = _split_log([c for n, c in firmware.log if n], prog.commands)
    assert job == prog.commands
    m110 = [c for c in other if c.startswith("M110 ")]  # the link's resyncs after lost oks
    assert len(m110) <= resyncs
    rest = [c for c in other if not c.startswith("M110 ")]
    assert Counter(rest) - Counter(st.stats.extra_commands) <= Counter({"M105": 99, "M115": 1})
