"""Taking back lines not yet sent (a pause or cancel acts on the firmware's few lines, not on
the whole queue): the protocol by hand, then the asyncio shell against the emulator."""

from __future__ import annotations

import asyncio

import pytest
from test_link_async import FAST, board, executed, moves
from test_link_protocol import acks, ready, wire

from hostd.link import SerialLink
from hostd.link.framing import checksum
from hostd.sim.settings import SimSettings

CMD = "G1 X{0}.000 Y{0}.000 Z{0}.000 E0.0100"  # 37-39 bytes framed


def wire_lines(text: str) -> list[tuple[int, str]]:
    """(number, command) of each whole line on the wire, its checksum verified."""
    out = []
    for raw in text.splitlines(keepends=True):
        if not raw.endswith("\n"):
            continue
        body, star = raw.rstrip("\n").rsplit("*", 1)
        assert int(star) == checksum(body), raw
        number, command = body.split(" ", 1)
        out.append((int(number[1:]), command))
    return out


@pytest.mark.parametrize("partial", [True, False])
def test_only_lines_with_no_byte_out_are_taken_back_and_the_rest_is_numbered_on(
        partial: bool) -> None:
    p = ready(rx_buffer_bytes=63, partial_lines=partial)
    first, actions = p.submit_many([CMD.format(i) for i in range(10)], 0.0)
    sent = wire(actions)
    begun = sent.count("N")  # lines with at least their first byte out (one in parts)
    assert 1 <= begun < 10
    taken = p.withdraw(first, first + 9)
    assert taken == 10 - begun and p.counters.lines_withdrawn == taken
    assert p.snapshot()["queued_lines"] == 0
    seq, actions = p.submit("G1 X99", 0.0)  # the next line goes out as the next number
    sent += wire(actions)
    done: list[int] = []
    for k in range(begun + 1):
        actions = p.receive("ok", 0.1 * (k + 1))
        sent += wire(actions)
        done += acks(actions)
    lines = wire_lines(sent)
    assert [n for n, _ in lines] == list(range(1, begun + 2))  # no gap, no line twice
    assert [c for _, c in lines] == [CMD.format(i) for i in range(begun)] + ["G1 X99"]
    assert done[-1] == seq


def test_queries_and_lines_outside_the_range_stay() -> None:
    p = ready(rx_buffer_bytes=63, partial_lines=False)
    first, _ = p.submit_many([CMD.format(i) for i in range(4)], 0.0)
    query, _ = p.submit("M114", 0.0, kind="query")
    other, _ = p.submit("M117 hello", 0.0)
    later, _ = p.submit_many([CMD.format(i) for i in range(4, 8)], 0.0)
    assert p.withdraw(later, later + 3) == 4
    assert p.withdraw(first, query) == 3  # the first went out; the query is not a job line
    sent = ""
    for k in range(4):
        sent += wire(p.receive("ok", 0.1 * (k + 1)))
    assert [c for _, c in wire_lines(sent)] == ["M114", "M117 hello"]
    assert p.last_acked == other


def test_nothing_is_taken_back_once_sent_or_when_another_range_is_named() -> None:
    p = ready()  # a 127-byte buffer takes three such lines whole
    first, actions = p.submit_many([CMD.format(i) for i in range(3)], 0.0)
    assert len(wire_lines(wire(actions))) == 3
    assert p.withdraw(first, first + 2) == 0
    assert p.withdraw(first + 3, first + 10) == 0
    assert p.counters.lines_withdrawn == 0


@pytest.mark.asyncio
async def test_the_link_keeps_the_futures_of_what_it_kept_and_cancels_the_rest() -> None:
    """A batch cut short resolves when its last kept line is acknowledged, with that line's
    number; a batch taken back whole is cancelled; the firmware executes exactly the lines
    that went out, once, in order, and what is submitted afterwards follows them."""
    link = SerialLink(FAST, SimSettings(seed=3))
    lines = moves(40, seed=1)
    async with asyncio.timeout(20):
        await link.connect()
        firmware = board(link)
        a_first, a_done = link.submit_many(lines[:20])
        b_first, b_done = link.submit_many(lines[20:])
        assert link.withdraw(b_first, b_first + 19) == 20
        a_taken = link.withdraw(a_first, a_first + 19)
        assert 0 < a_taken < 20  # the firmware's buffer holds a few lines
        kept = a_first + 19 - a_taken
        assert await a_done == kept and b_done.cancelled()
        assert await link.send("G1 X1 F600") == b_first + 20
        status = link.status()
        await link.close()
    assert executed(firmware) == [*lines[:20 - a_taken], "G1 X1 F600"]
    assert status["lines_withdrawn"] == 20 + a_taken and status["queued_lines"] == 0


@pytest.mark.asyncio
async def test_a_future_left_waiting_for_a_line_already_acknowledged_resolves_at_once() -> None:
    """Lines go out in order, so a line kept is rarely acknowledged while a later one of its
    batch has not gone out; if it is, its batch's future must not wait for an ``ok`` that
    has come already (the streamer would wait for ever)."""
    link = SerialLink(FAST, SimSettings(seed=4))
    async with asyncio.timeout(20):
        await link.connect()
        first, done = link.submit_many(moves(3))
        await done
        late: asyncio.Future[int] = asyncio.get_running_loop().create_future()
        link._lines.append((first + 5, late))  # a batch of 6 whose last 3 were taken back
        link._rekey(first, first + 5, first + 2)
        assert late.done() and late.result() == first + 2 and not link._lines
        await link.close()
