"""Buffer credit: the host never overfills the emulated board's receive buffer.

The emulated board reads its receive buffer only while its command queue has a free slot and
silently drops what does not fit, as Marlin does. With ADVANCED_OK the host counts the lines
that ``ok N<k> B<b>`` shows in the command queue as out of the receive buffer, so it may have
more unanswered bytes out than the buffer holds; these tests check that this never loses a
byte, with faults, and that the credit is really used.
"""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from link_harness import VirtualBench
from test_link_property import assert_exactly_once, sliced_like

from hostd.link.actions import Action, Write
from hostd.link.framing import encode, frame
from hostd.link.protocol import Protocol
from hostd.link.settings import LinkSettings
from hostd.sim.settings import SimSettings

knobs = st.fixed_dictionaries({
    "seed": st.integers(0, 2**31 - 1),
    "rx_buffer_bytes": st.sampled_from([63, 96, 127]),
    "queue_slots": st.sampled_from([1, 2, 4, 8]),
    "planner_blocks": st.sampled_from([4, 16]),
    "bit_flip_prob": st.sampled_from([0.0, 0.02]),
    "lost_ok_prob": st.sampled_from([0.0, 0.005]),
    "busy_prob": st.sampled_from([0.0, 0.01]),
    "advanced_ok": st.booleans(),
    "read_delay": st.sampled_from([0.0, 0.004]),
})


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(sim=knobs, length=st.integers(1, 600), latency=st.sampled_from([0.0001, 0.002]),
       partial=st.booleans())
def test_the_board_never_drops_a_byte_under_the_hosts_credit(
        sim: dict[str, object], length: int, latency: float, partial: bool) -> None:
    commands = sliced_like(length, int(sim["seed"]))  # type: ignore[call-overload]
    link = LinkSettings(rx_buffer_bytes=int(sim["rx_buffer_bytes"]),  # type: ignore[call-overload]
                        partial_lines=partial, ok_timeout=5.0, nudges=3)
    bench = VirtualBench(link, SimSettings(**sim), latency=latency)  # type: ignore[arg-type]
    assert bench.connect()
    bench.stream(commands)
    assert_exactly_once(bench, commands)
    assert bench.firmware.rx_high_water <= int(sim["rx_buffer_bytes"])  # type: ignore[call-overload]


def stream_planner_bound(advanced_ok: bool, bit_flip_prob: float = 0.0,
                         partial: bool = False) -> VirtualBench:
    """Long moves: the planner is full, commands wait in the queue, the buffer fills; after
    each command the main loop leaves the buffer alone for a while (so a line the host wrongly
    believes read out is still there). No starve nudges: on the long moves they go past the
    credit on purpose (``tests/link/test_starve_nudge.py``); these tests are about the credit."""
    commands = [f"G1 X{i % 50 * 2} Y{i % 7} F600" for i in range(400)]
    sim = SimSettings(rx_buffer_bytes=63, queue_slots=4, advanced_ok=advanced_ok,
                      bit_flip_prob=bit_flip_prob, read_delay=0.003, seed=3)
    link = LinkSettings(rx_buffer_bytes=63, partial_lines=partial, ok_timeout=30.0, nudges=3,
                        starve_timeout=0.0)
    bench = VirtualBench(link, sim)
    assert bench.connect()
    bench.stream(commands)
    assert_exactly_once(bench, commands)
    return bench


def test_without_advanced_ok_the_host_stays_within_the_receive_buffer() -> None:
    bench = stream_planner_bound(advanced_ok=False)
    assert bench.outcome.max_inflight_bytes <= 63


def test_lines_in_parts_fill_the_receive_buffer_to_the_byte_without_a_loss() -> None:
    bench = stream_planner_bound(advanced_ok=False, partial=True)
    assert bench.outcome.max_inflight_bytes == 63 and bench.firmware.rx_high_water == 63
    assert bench.protocol.counters.lines_split > 0


@pytest.mark.parametrize("partial", [False, True])
def test_advanced_ok_lets_the_queued_lines_out_of_the_credit_without_a_loss(
        partial: bool) -> None:
    bench = stream_planner_bound(advanced_ok=True, partial=partial)
    assert bench.outcome.max_inflight_bytes > 63  # the command queue's lines left the credit
    assert bench.firmware.rx_high_water <= 63 and bench.firmware.dropped_bytes == 0


@pytest.mark.parametrize("partial", [False, True])
def test_advanced_ok_credit_survives_corrupted_lines(partial: bool) -> None:
    bench = stream_planner_bound(advanced_ok=True, bit_flip_prob=0.05, partial=partial)
    assert bench.protocol.counters.lines_resent > 0
    assert bench.outcome.max_inflight_bytes > 63


def handshaken(rx: int) -> Protocol:
    proto = Protocol(LinkSettings(rx_buffer_bytes=rx, partial_lines=False))
    proto.start(0.0)
    proto.receive("ok", 0.0)
    return proto


def written(actions: list[Action]) -> int:
    return sum(isinstance(a, Write) for a in actions)


LINE = "G1 X100.000 Y100.000"  # 27 bytes framed with N1 … N9: two fit into 64
SIZE = 27


def test_lines_in_the_command_queue_free_credit() -> None:
    proto = handshaken(rx=64)
    assert all(len(encode(frame(n, LINE))) == SIZE for n in range(1, 10))
    assert sum(written(proto.submit(LINE, 0.0)[1]) for _ in range(8)) == 2
    # line 1 processed while alone in the queue (B = 4 - 1): only its own bytes come back
    assert written(proto.receive("ok N1 P10 B3", 0.0)) == 1
    # line 2 processed with line 3 behind it in the queue: 3 has left the receive buffer
    assert written(proto.receive("ok N2 P10 B2", 0.0)) == 2
    assert proto.inflight_bytes == 3 * SIZE  # 3, 4, 5 unanswered; only 4 and 5 in the buffer


def test_a_queue_claim_beyond_the_lines_sent_frees_only_what_was_sent() -> None:
    proto = handshaken(rx=64)
    for _ in range(8):
        proto.submit(LINE, 0.0)
    proto.receive("ok N1 P10 B3", 0.0)
    # B0 would put lines 3, 4 and 5 in the queue, but 4 and 5 were never sent
    assert written(proto.receive("ok N2 P10 B0", 0.0)) == 2


def test_plain_oks_free_only_what_they_acknowledge() -> None:
    proto = handshaken(rx=64)
    for _ in range(8):
        proto.submit(LINE, 0.0)
    assert written(proto.receive("ok", 0.0)) == 1
    assert written(proto.receive("ok P10 B0", 0.0)) == 1  # no N: no queue information
    assert proto.inflight_bytes == 2 * SIZE


def test_the_credit_holds_past_line_100000_where_numbers_grow_longer() -> None:
    command = "G1 X1.5 Y2.5 E0.01"
    size = max(len(encode(frame(n, command))) for n in range(100_000, 100_100))
    proto = handshaken(rx=2 * size - 1)  # two of the longest lines do not fit, by one byte
    seen = 0
    for _ in range(3):
        proto.submit(command, 0.0)
    for _ in range(100_010):
        proto.submit(command, 0.0)  # lines keep waiting for credit
        proto.receive("ok", 0.0)
        seen = max(seen, proto.inflight_bytes)
    assert proto.last_acked >= 100_000
    assert seen <= 2 * size - 1
