"""Starve nudges: a lost ``ok`` that leaves lines waiting for credit costs ``starve_timeout``,
not ``ok_timeout``; a board at work (keepalive, ``W:``, slow ``ok`` s) is not nudged, and what
a nudge puts past the credit never overfills a busy board's receive buffer."""

from __future__ import annotations

import asyncio
import logging

import pytest
from link_harness import VirtualBench, job_log
from test_link_property import assert_exactly_once
from test_link_protocol import acks, failures, notices, ready, wire

from hostd.link import LinkSettings, SerialLink
from hostd.link.actions import Action, Answer, Notice
from hostd.link.errors import LinkLost
from hostd.link.framing import framed
from hostd.link.notices import RESEND_INTERVAL, NoticeLog
from hostd.link.protocol import Protocol
from hostd.sim.settings import SimSettings

# 67 bytes framed at N1..N9: a lost ok's line and the next one overflow the 127-byte credit
CMD = "G1 X250.000 Y250.000 Z100.000 A10.000 C100.000 E0.02100 F1200"
TEMPS = "ok T:20.0 /0.0 B:20.0 /0.0"


def line(n: int, command: str = CMD) -> str:
    """Line ``n`` as framed on the wire."""
    return framed(n, command).decode()


def starved(**kw: object) -> Protocol:
    """Line 1 answered at 0.1, line 2 executed with its ok lost, line 3 out in part (the
    firmware waits for its rest), line 4 queued: the host stalls, as in ``bench/lost_ok.py``."""
    p = ready(**kw)
    out = "".join(wire(p.submit(CMD, 0.0)[1]) for _ in range(4))
    assert out == line(1) + line(2)[:127 - len(line(1))]
    out += wire(p.receive("ok", 0.1))
    assert out == line(1) + line(2) + line(3)[:127 - len(line(2))]
    return p


def starve_notices(actions: list[Action]) -> list[Notice]:
    return [a for a in actions if isinstance(a, Notice) and a.kind == "starved"]


def m105s(text: str) -> list[str]:
    """The M105 lines in ``text`` (as framed, without the newline)."""
    return [ln for ln in text.splitlines() if ln.partition("*")[0].split()[1:] == ["M105"]]


def test_a_lost_ok_is_nudged_after_starve_timeout_and_its_ok_t_resynchronises() -> None:
    p = starved()
    assert p.deadline() == pytest.approx(1.1)  # starve_timeout after the last ok
    assert wire(p.tick(1.09)) == ""
    actions = p.tick(1.1)
    rest = line(3)[127 - len(line(2)):]
    assert wire(actions) == rest + line(4, "M105")  # the line in parts finished first
    assert len(starve_notices(actions)) == 1 and p.counters.starve_nudges == 1
    # no credit released: line 2 (executed, its ok lost) still counts
    assert p.inflight_bytes == len(line(2)) + len(line(3)) + len(line(4, "M105"))
    assert p.counters.timeouts == 0 and p.deadline() == pytest.approx(10.1)  # clock as it was
    # the firmware answers line 3 (taken for line 2's), then the M105 with the temperatures:
    # line 3 and the M105 executed, and the stream goes on
    actions = p.receive("ok", 1.2)
    out = wire(actions)
    assert acks(actions) == [2] and out == line(5)[:127 - len(line(3)) - len(line(4, "M105"))]
    actions = p.receive(TEMPS, 1.3)
    out += wire(actions)
    assert acks(actions) == [3] and out == line(5)
    assert acks(p.receive("ok", 1.4)) == [4] and p.deadline() is None
    assert p.inflight_bytes == 0 and p.counters.timeouts == 0
    assert m105s(rest + line(4, "M105") + out) == [line(4, "M105").strip()]  # one M105


@pytest.mark.parametrize("starve_timeout", [1.0, 0.0])
def test_a_silent_board_times_out_and_is_lost_as_before(starve_timeout: float) -> None:
    """The starve nudge neither moves the ok timeout nor counts towards ``serial.nudges``:
    with it or without, the timeout nudges at 10.1 s and the link is lost at 20.1 s."""
    p = starved(starve_timeout=starve_timeout)
    sent = wire(p.tick(1.1))
    assert p.deadline() == pytest.approx(10.1)
    assert wire(p.tick(5.0)) == ""  # one starve nudge per stretch without an ok
    actions = p.tick(10.1)
    sent += wire(actions)
    n = 4 + (starve_timeout > 0)  # the timeout's M105 follows the starve nudge's
    assert notices(actions) == [
        f"no ok for 10 s (line 2 awaited, {n - 1} sent): M105 nudge 1 of 1"]
    assert sent.startswith(line(3)[127 - len(line(2)):])
    assert m105s(sent) == [line(k, "M105").strip() for k in range(4, n + 1)]
    assert p.deadline() == pytest.approx(20.1) and wire(p.tick(20.0)) == ""
    lost = failures(p.tick(20.1))
    assert len(lost) == 1 and isinstance(lost[0], LinkLost)
    assert "after 1 M105 nudge(s)" in str(lost[0]) and p.counters.timeouts == 2


def test_an_m105_that_does_not_fit_waits_first_in_the_queue() -> None:
    """Past the credit only what a busy board's buffer surely holds: here the rest of line
    2, not the M105 after it. A timeout then sends that M105, not one more."""
    p = ready(rx_buffer_bytes=72)
    for _ in range(3):
        p.submit(CMD, 0.0)
    assert wire(p.tick(1.0)) == line(2)[72 - len(line(1)):]  # line 1's ok was lost
    assert p.counters.starve_nudges == 1
    sent = wire(p.tick(10.0))
    assert sent.startswith(line(3, "M105") + "N4 ") and m105s(sent) == ["N3 M105*36"]


def test_starve_timeout_zero_turns_it_off() -> None:
    p = starved(starve_timeout=0.0)
    assert p.deadline() == pytest.approx(10.1)
    assert wire(p.tick(5.0)) == "" and p.counters.starve_nudges == 0


@pytest.mark.parametrize("progress", [
    "echo:busy: processing",
    " T:150.00 /210.00 B:22.00 /0.00 @:127 B@:0 W:?",  # an M109's wait line
])
def test_a_busy_board_gets_no_starve_nudge(progress: str) -> None:
    """Line 2 is a long move (its ok not lost, just late); the keepalive, or a heat-up's
    ``W:`` line, comes within ``starve_timeout`` each time: no nudge."""
    p = starved()
    for i in range(1, 10):
        p.receive(progress, 0.1 + 0.9 * i)
        assert wire(p.tick(p.deadline() - 1e-6)) == ""  # type: ignore[operator]
    assert p.deadline() == pytest.approx(8.2 + 1.0)
    assert acks(p.receive("ok", 8.3)) == [2]  # the move ends, the stream goes on
    assert p.counters.starve_nudges == 0


def test_slow_oks_get_no_starve_nudge() -> None:
    p = ready()
    for _ in range(20):
        p.submit(CMD, 0.0)
    for i in range(1, 15):
        t = 0.9 * i
        assert p.tick(t - 1e-6) == [] and acks(p.receive("ok", t)) == [i]
    assert p.counters.starve_nudges == 0 and m105s(wire(p.tick(12.6))) == []


def test_after_a_starve_nudge_only_an_ok_arms_the_next() -> None:
    """A keepalive every 2 s through a long command would otherwise bring a nudge each
    time; the busy lines still put the ok timeout off."""
    p = starved()
    p.tick(1.1)
    for t in (2.0, 4.0, 6.0, 8.0):
        p.receive("echo:busy: processing", t)
        assert p.deadline() == pytest.approx(t + 10.0)
    p.receive("ok", 9.0)  # line 3's: the M105 goes out
    p.submit(CMD, 9.0)
    assert p.deadline() == pytest.approx(10.0)  # armed again: lines wait for credit


@pytest.mark.parametrize("kw", [{"partial_lines": False}, {"flow_control": "pingpong"}])
def test_with_whole_lines_only_the_m105_goes_out_past_the_credit(kw: dict[str, object]) -> None:
    p = ready(**kw)
    for _ in range(3):
        p.submit(CMD, 0.0)
    assert wire(p.receive("ok", 0.1)) == line(2)  # line 2's ok will be lost
    actions = p.tick(1.1)
    assert wire(actions) == line(3, "M105") and len(starve_notices(actions)) == 1
    assert p.inflight_bytes == len(line(2)) + len(line(3, "M105"))
    actions = p.receive(TEMPS, 1.2)
    assert acks(actions) == [2] and wire(actions) == line(4)
    assert acks(p.receive("ok", 1.3)) == [3]


def test_an_m105_in_parts_is_finished_and_needs_no_other() -> None:
    """Its own ``ok T:`` resynchronises, and answers the query."""
    p = ready(rx_buffer_bytes=72)
    first = wire(p.submit(CMD, 0.0)[1])
    seq, actions = p.submit("M105", 0.0, kind="query")
    assert first == line(1) and wire(actions) == line(2, "M105")[:72 - len(line(1))]
    p.submit(CMD, 0.0)
    assert wire(p.tick(1.0)) == line(2, "M105")[72 - len(line(1)):]  # line 1's ok was lost
    out = p.receive(TEMPS, 1.1)
    assert acks(out) == [seq] and [a.line for a in out if isinstance(a, Answer)] == [seq]
    assert wire(out) == line(3) and m105s(wire(p.receive("ok", 1.2))) == []


def test_during_a_resend_the_nudge_is_the_next_line_resent() -> None:
    """A new number would be out of turn while the firmware waits for the resent lines."""
    short = "G1 X100.000 Y100.000 Z10.000 F12000"  # 42 bytes: three in the credit
    p = ready(partial_lines=False)
    for _ in range(5):
        p.submit(short, 0.0)
    assert wire(p.receive("ok", 0.1)) == line(4, short)  # line 1; lines 2 to 4 in flight
    for last in (1, 1, 1):  # line 2 garbled; 3 and 4 rejected as out of turn
        p.receive(f"Error:checksum mismatch, Last Line: {last}", 0.2)
        p.receive("Resend: 2", 0.2)
        out = wire(p.receive("ok", 0.2))
    assert out == line(1, "M110 N1")  # all three answered: the numbering set back first
    out = wire(p.receive("ok", 0.2))
    assert out == line(2, short)  # the halved window: one line; its ok will be lost
    actions = p.tick(1.2)
    assert wire(actions) == line(3, short) and len(starve_notices(actions)) == 1
    assert acks(p.receive("ok", 1.3)) == [2]  # (line 3's ok, taken for line 2's)


def test_advanced_ok_a_lost_last_ok_is_nudged_too() -> None:
    p = ready(rx_buffer_bytes=127)
    for _ in range(4):
        p.submit(CMD, 0.0)
    p.receive("ok N1 P15 B3", 0.1)  # line 2 goes out whole, line 3 in part
    out = wire(p.tick(1.1))  # line 2's ok N2 was lost
    assert out == line(3)[127 - len(line(2)):] + line(4, "M105")
    assert acks(p.receive("ok N3 P15 B3", 1.2)) == [3]  # resynchronises by itself
    assert acks(p.receive("ok N5 P15 B3", 1.3)) == [4]  # (the M105's ok T: lost too)
    assert p.counters.starve_nudges == 1


def test_nothing_goes_past_the_credit_when_the_buffer_may_be_full() -> None:
    """ADVANCED_OK shows lines 3 and 4 in the command queue (the planner full): the credit
    after them is the receive buffer's real content, so a wait is a busy board's, and
    nothing goes past it; the ok timeout comes as before."""
    p = ready()
    for _ in range(20):
        p.submit("G1 X10.000 Y10.000 E0.0100", 0.0)  # 33 bytes
    p.receive("ok N1 P10 B3", 0.1)
    p.receive("ok N2 P0 B0", 0.2)  # lines 3 and 4 read out of the receive buffer
    assert p.inflight_bytes > 127  # (counted: lines read out hold no credit)
    actions = p.tick(1.2)
    assert wire(actions) == "" and starve_notices(actions) == []
    assert p.counters.starve_nudges == 0 and p.deadline() == pytest.approx(10.2)


def test_long_moves_are_nudged_without_a_byte_lost_or_a_line_resent() -> None:
    """The planner full, moves of up to 10 s: starve nudges on the longest waits, all within
    what the busy firmware's receive buffer holds (plain oks: every line counted is in it or
    in the command queue; ADVANCED_OK: nothing past the credit it knows to be full)."""
    commands = [f"G1 X{i % 50 * 2} Y{i % 7} F600" for i in range(400)]
    for advanced_ok in (False, True):
        for partial in (False, True):
            sim = SimSettings(rx_buffer_bytes=63, queue_slots=4, advanced_ok=advanced_ok,
                              read_delay=0.003, seed=3)
            link = LinkSettings(rx_buffer_bytes=63, partial_lines=partial, ok_timeout=30.0)
            bench = VirtualBench(link, sim)
            assert bench.connect()
            bench.stream(commands)
            assert_exactly_once(bench, commands)
            counters = bench.protocol.counters
            assert bench.firmware.dropped_bytes == 0 and counters.lines_resent == 0
            assert counters.timeouts == 0
            if not advanced_ok:
                assert counters.starve_nudges > 0


def test_lost_oks_cost_no_timeout_on_the_virtual_bench() -> None:
    """Long five-axis lines, 1 % of the oks lost (20 here), moves on the emulated planner:
    without starve nudges nearly every loss stalls the stream for the ok timeout; with them
    none does. (A nudge whose own ``ok T:`` is lost still ends in the timeout: with 2 % lost,
    a few in a thousand lines.)"""
    commands = [CMD.replace("X250", f"X{200 + i % 97}") for i in range(1500)]
    runs = {}
    for starve in (0.0, 1.0):
        link = LinkSettings(starve_timeout=starve)
        bench = VirtualBench(link, SimSettings(lost_ok_prob=0.01, seed=0, baud=250000))
        assert bench.connect()
        bench.stream(commands)
        assert_exactly_once(bench, commands)
        assert bench.firmware.faults.lost_oks >= 15
        runs[starve] = bench
    without, starving = runs[0.0].protocol.counters, runs[1.0].protocol.counters
    assert without.timeouts >= 15 and without.starve_nudges == 0
    assert starving.timeouts == 0 and starving.starve_nudges >= 15
    assert runs[1.0].outcome.end_time < 0.6 * runs[0.0].outcome.end_time


@pytest.mark.asyncio
async def test_serial_link_with_lost_oks_runs_without_a_timeout() -> None:
    """End to end: SerialLink on the emulator, 2 % of the oks lost (23 here), long lines."""
    commands = [CMD.replace("X250", f"X{200 + i % 97}") for i in range(800)]
    link = SerialLink(LinkSettings(ok_timeout=5.0, starve_timeout=0.1),
                      SimSettings(lost_ok_prob=0.02, seed=7))
    async with asyncio.timeout(60):
        await link.connect()
        try:
            assert link.connection is not None and link.connection.emulator is not None
            firmware = link.connection.emulator.firmware
            acked = [i async for i in link.stream(commands)]
            status = link.status()
        finally:
            await link.close()
    assert acked == list(range(len(commands)))
    assert [t for t in job_log(firmware) if t != "M115"] == commands  # once each, in order
    assert firmware.faults.lost_oks >= 10
    assert status["timeouts"] == 0 and status["starve_nudges"] >= 1


def test_starve_nudges_are_logged_at_info_once_an_interval(
        caplog: pytest.LogCaptureFixture) -> None:
    log = NoticeLog("sim://")
    with caplog.at_level(logging.INFO, logger="hostd.link.notices"):
        for t in (0.0, 1.0, 2.0, RESEND_INTERVAL + 1.0):
            log.notice(Notice("starved", f"s{t:g}"), t)
    assert [(r.levelno, r.getMessage()) for r in caplog.records] == [
        (logging.INFO, "sim://: s0"),
        (logging.INFO, "sim://: s61 (2 more since the last one logged)")]


def test_the_config_key_reaches_the_link() -> None:
    from hostd.config import defaults, loads
    from hostd.link.settings import link_settings_from_config

    assert link_settings_from_config(defaults()).starve_timeout == 1.0
    cfg = loads("serial:\n  starve_timeout: 0\n", "x.yaml")
    assert link_settings_from_config(cfg).starve_timeout == 0.0
