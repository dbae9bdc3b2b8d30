"""Held reads on a real port (``serial.read_hold``): quick replies are read in batches, and
nothing is lost, reordered or mistaken for a vanished device. The hold itself is a pure
decision (:class:`ReadHold`), checked on its own below."""

from __future__ import annotations

import asyncio
import os
import tty
from collections.abc import Iterator

import pytest
import serial
from hypothesis import given, settings
from hypothesis import strategies as st

from hostd.link import LinkSettings
from hostd.link.read_hold import READ_HOLD_MARGIN_S, ReadHold
from hostd.link.transport import DirectSerialTransport, LineReceiver, read_hold

HOLD_S = 1.0  # long beside the test's own steps, so the grouping below is certain
WIRE = b"G1 X1\n"  # at 0.25 s a byte (a 40-baud wire), 1.5 s on the wire: holds of HOLD_S
# (and with no gap learnt, span=0, the first reply already counts as quick)


class WatchedTransport(DirectSerialTransport):
    """Signals each time the port is watched again (a held read found nothing)."""

    rearmed: asyncio.Event

    def _ensure_reader(self) -> None:
        was = self._has_reader
        super()._ensure_reader()
        if self._has_reader and not was:
            self.rearmed.set()


class Board:
    """The far end of a pty: writes replies and collects what the host receives."""

    def __init__(self) -> None:
        self.master, slave = os.openpty()
        tty.setraw(slave)
        self.path = os.ttyname(slave)
        self.slave = slave
        self.chunks: list[list[bytes]] = []
        self.lost: list[str] = []
        self.arrived = asyncio.Event()
        self.gone = asyncio.Event()

    def on_lost(self, reason: str) -> None:
        self.lost.append(reason)
        self.gone.set()

    def on_lines(self, lines: list[bytes]) -> None:
        self.chunks.append(lines)
        self.arrived.set()

    async def reply(self, *texts: bytes) -> None:
        """Write each text as its own write, then wait until the host has received them."""
        want = sum(len(c) for c in self.chunks) + len(texts)
        for text in texts:
            os.write(self.master, text + b"\n")
        while sum(len(c) for c in self.chunks) < want:
            self.arrived.clear()
            await self.arrived.wait()


@pytest.fixture
def board() -> Iterator[Board]:
    b = Board()
    yield b
    os.close(b.master)
    os.close(b.slave)


async def open_held(board: Board, hold: bool) -> WatchedTransport:
    """The host end, with a line on a slow wire so that quick replies are held ``HOLD_S``."""
    port = serial.serial_for_url(board.path, baudrate=115200)
    receiver = LineReceiver()
    policy = ReadHold(share=0.9, byte_s=0.25, hold_max=HOLD_S, span=0.0) if hold else None
    transport = WatchedTransport(asyncio.get_running_loop(), receiver, port, hold=policy)
    transport.rearmed = asyncio.Event()
    receiver.attach(board.on_lines, board.on_lost)
    await transport.rearmed.wait()  # watched from the first loop iteration
    transport.write(WIRE)
    return transport


@pytest.mark.asyncio
async def test_quick_replies_are_read_in_one_batch_after_the_hold(board: Board) -> None:
    async with asyncio.timeout(10):
        t = await open_held(board, True)
        assert t._has_reader and t._held is None  # watched until a reply comes
        await board.reply(b"ok 1")
        assert not t._has_reader and t._held is not None  # then the next read is held
        await board.reply(b"ok 2", b"ok 3")  # two writes, one timed read
        t.close()
    assert board.chunks == [[b"ok 1"], [b"ok 2", b"ok 3"]]


@pytest.mark.asyncio
async def test_a_held_read_that_finds_nothing_watches_the_port_again(board: Board) -> None:
    """A tty read with nothing to read returns no bytes: not a vanished device."""
    async with asyncio.timeout(10):
        t = await open_held(board, True)
        t.rearmed.clear()
        await board.reply(b"ok 1")
        await t.rearmed.wait()  # the held read found nothing
        assert not t.is_closing() and board.lost == []
        await board.reply(b"ok 2")
        t.close()
    assert board.chunks == [[b"ok 1"], [b"ok 2"]]


@pytest.mark.asyncio
async def test_without_a_hold_every_reply_is_read_as_it_comes(board: Board) -> None:
    async with asyncio.timeout(10):
        t = await open_held(board, False)
        for n in range(4):
            await board.reply(b"ok %d" % n)
        t.close()
    assert board.chunks == [[b"ok %d" % n] for n in range(4)]


@pytest.mark.asyncio
async def test_a_closed_far_end_is_still_reported_while_reads_are_held(board: Board) -> None:
    async with asyncio.timeout(10):
        t = await open_held(board, True)
        await board.reply(b"ok 1")
        assert t._held is not None
        os.close(board.master)
        board.master = os.open(os.devnull, os.O_RDONLY)  # for the fixture's close
        await board.gone.wait()
    assert t.is_closing()
    assert len(board.lost) == 1 and ("disconnected" in board.lost[0]
                                     or "failed" in board.lost[0])


@pytest.mark.parametrize(("flow", "share", "rx", "held"), [
    ("window", 0.5, 127, True), ("window", 0.0, 127, False),
    ("pingpong", 0.5, 127, False),  # one line in flight: a hold would only delay its ok
    ("window", 0.5, 63, False),  # room for 1.3 lines: at most one reply per hold
])
def test_held_reads_only_in_window_mode_with_room_for_lines(flow: str, share: float, rx: int,
                                                             held: bool) -> None:
    policy = read_hold(LinkSettings(flow_control=flow, baud=250000, read_hold=share,
                                    rx_buffer_bytes=rx))
    assert (policy is not None) == held
    if policy is not None:
        assert policy.share == share and policy.byte_s == pytest.approx(10 / 250000)


def test_the_wire_clock_queues_each_write_after_the_last() -> None:
    h = ReadHold(share=0.5, byte_s=0.001)
    h.wrote(0.0, 10)
    h.wrote(0.004, 10)  # behind the first: leaves at 0.02
    assert h.wire_free == pytest.approx(0.02)
    h.wrote(0.05, 10)  # the wire was idle: leaves 10 ms after it was written
    assert h.wire_free == pytest.approx(0.06)


def steady(h: ReadHold, every: float, count: int = 60) -> list[float]:
    """Replies every ``every`` s, each followed by writes that bring the wire back to 127
    bytes queued (at 250000 baud); the holds decided."""
    holds = []
    for k in range(1, count + 1):
        now = every * k
        h.wrote(now, round((now + 127 * h.byte_s - max(h.wire_free, now)) / h.byte_s))
        holds.append(h.after_data(now, 1))
    return holds


def test_replies_slower_than_the_wire_are_read_at_once() -> None:
    """The planner sets the pace: an ok every 30 ms, one 40-byte line written for each."""
    h = ReadHold(share=0.9, byte_s=10 / 250000)
    holds = []
    for k in range(50):
        h.wrote(0.03 * k, 40)
        holds.append(h.after_data(0.03 * k + 0.0001, 1))
    assert holds == [0.0] * 50


def test_replies_at_the_wire_pace_are_held() -> None:
    """An ok every 1.6 ms: once the mean gap is learnt (from a long one), every read is held,
    and each hold leaves the margin and ``1 - share`` of the queued wire time."""
    h = ReadHold(share=0.5, byte_s=10 / 250000)
    holds = steady(h, 0.0016)
    assert holds[0] == 0.0  # nothing learnt yet
    queued = 127 * h.byte_s
    assert holds[-40:] == pytest.approx([min(0.5 * queued, queued - READ_HOLD_MARGIN_S)] * 40)


def test_a_hold_that_would_likely_find_no_new_reply_is_not_taken() -> None:
    """Replies 8 ms apart with 5.1 ms queued: a 3.6 ms hold would mostly be a wake-up for
    nothing, so each reply is read as it comes."""
    assert steady(ReadHold(share=0.7, byte_s=10 / 250000), 0.008) == [0.0] * 60


@settings(max_examples=300, deadline=None)
@given(share=st.floats(0.0, 0.9), hold_max=st.floats(0.001, 0.05),
       steps=st.lists(st.tuples(st.floats(0.0, 0.02), st.integers(0, 200), st.integers(0, 4)),
                      min_size=1, max_size=60))
def test_a_hold_never_outlasts_its_share_of_the_queued_wire_time(
        share: float, hold_max: float, steps: list[tuple[float, int, int]]) -> None:
    """Whatever the writes and replies: a hold ends while the wire still carries the margin
    and ``1 - share`` of what was queued, and never exceeds ``hold_max``."""
    h = ReadHold(share=share, byte_s=10 / 250000, hold_max=hold_max)
    now = 0.0
    for gap, nbytes, replies in steps:
        now += gap
        if nbytes:
            h.wrote(now, nbytes)
        queued = h.wire_free - now
        hold = h.after_data(now, replies)
        assert 0.0 <= hold <= hold_max
        assert hold == 0.0 or hold <= min(share * queued, queued - READ_HOLD_MARGIN_S)
