"""Property tests: random fault schedules, every line executed exactly once, in order.

The protocol and the emulator run on the virtual clock of ``link_harness`` (deterministic,
about a second per 10 000-line job).
"""

from __future__ import annotations

import random
from collections.abc import Callable
from typing import Any
from unittest.mock import patch

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from link_harness import VirtualBench, assert_whole_valid_lines, job_log

from hostd.link.actions import Acked, Action, Answer
from hostd.link.inflight import InFlight, Sent
from hostd.link.protocol import Protocol
from hostd.link.replies import Ok, parse_advanced_ok
from hostd.link.settings import LinkSettings
from hostd.sim.settings import SimSettings


def sliced_like(n: int, seed: int) -> list[str]:
    """A job that looks like sliced five-axis output: short XYZACE moves, some M-codes."""
    rng = random.Random(seed)
    out = []
    e = 0.0
    for i in range(n):
        if i % 997 == 500:
            out.append(f"M106 S{rng.randrange(256)}")
        elif i % 1499 == 700:
            out.append("M105 T0")  # a temperature poll inside the job
        else:
            e += 0.03
            out.append(f"G1 X{rng.uniform(0, 2):.3f} Y{rng.uniform(0, 2):.3f} "
                       f"A{rng.uniform(-3, 3):.2f} C{rng.uniform(0, 3):.2f} E{e:.4f} "
                       f"F{rng.choice((3000, 6000))}")
    return out


def run(commands: list[str], link: LinkSettings, sim: SimSettings) -> VirtualBench:
    bench = VirtualBench(link, sim)
    assert bench.connect()
    bench.stream(commands)
    return bench


def assert_exactly_once(bench: VirtualBench, commands: list[str]) -> None:
    outcome = bench.outcome
    assert outcome.failures == []
    assert job_log(bench.firmware) == commands
    assert bench.firmware.dropped_bytes == 0, "host overfilled the receive buffer"
    assert outcome.ack_ahead_of_execution == [], "acknowledged a line not yet executed"
    assert outcome.acked == sorted(set(outcome.acked))
    assert outcome.acked[-1] == len(commands)
    assert_whole_valid_lines(outcome.sent)


faults = st.fixed_dictionaries({
    "seed": st.integers(0, 2**31 - 1),
    "bit_flip_prob": st.sampled_from([0.0, 0.01, 0.03]),
    "lost_ok_prob": st.sampled_from([0.0, 0.002, 0.01]),
    "busy_prob": st.sampled_from([0.0, 0.01]),
    "advanced_ok": st.booleans(),
    "rx_buffer_bytes": st.sampled_from([63, 127]),
})


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(knobs=faults, flow=st.sampled_from(["window", "pingpong"]), length=st.integers(1, 1500),
       partial=st.booleans())
def test_random_fault_schedules_execute_every_line_once_in_order(
        knobs: dict[str, object], flow: str, length: int, partial: bool) -> None:
    commands = sliced_like(length, int(knobs["seed"]))  # type: ignore[call-overload]
    link = LinkSettings(flow_control=flow, rx_buffer_bytes=int(knobs["rx_buffer_bytes"]),  # type: ignore[call-overload]
                        partial_lines=partial, ok_timeout=5.0, nudges=3)
    bench = run(commands, link, SimSettings(**knobs))  # type: ignore[arg-type]
    assert_exactly_once(bench, commands)


QUERIES = ("M105 T0", "M114")


NOISY_PARTIAL = {"seed": 467408071, "bit_flip_prob": 0.01, "lost_ok_prob": 0.01, "busy_prob": 0.0,
                 "advanced_ok": False, "rx_buffer_bytes": 127}


def with_queries(commands: list[str], every: int,
                 queries: tuple[str, ...] = QUERIES) -> list[str]:
    """``commands`` with every ``every``-th replaced by a query, ``queries`` in turn."""
    out = list(commands)
    spots = range(every // 2, len(out), every)
    for k, i in enumerate(spots):
        out[i] = queries[k % len(queries)]
    return out


def tiny_moves(n: int, seed: int) -> list[str]:
    """Moves of hundredths of a millimetre: the planner keeps up, so the replies come as
    fast as the link carries them, several to a read."""
    rng = random.Random(seed)
    out, x, y, e = [], 0.0, 0.0, 0.0
    for _ in range(n):
        x, y, e = x + rng.uniform(0.005, 0.03), y + rng.uniform(-0.02, 0.02), e + 0.001
        out.append(f"G1 X{x:.3f} Y{y:.3f} E{e:.4f} F6000")
    return out


def assert_queries_answered(bench: VirtualBench, commands: list[str]) -> None:
    """Each query got exactly one answer, in order, holding at least the ok that executed
    it (an M105's ``ok T:`` may come after a timeout's nudge went out, and execute both)."""
    asked = [i + 1 for i, c in enumerate(commands) if c in QUERIES]
    answers = bench.outcome.answers
    assert [a.line for a in answers] == asked
    assert all(any(isinstance(r, Ok) for r in a.replies) for a in answers)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(knobs=faults, length=st.integers(1, 1500), every=st.integers(2, 60),
       flow=st.sampled_from(["window", "pingpong"]), partial=st.booleans())
# found by CI: the ok of line 217 lost, then 218 corrupted while 219 went out in parts; the
# timeout released the part-sent line's credit, so the error ok of its rejection was taken
# for a later line's and the link ran one acknowledgement ahead (220: a line never ran)
@example(knobs=NOISY_PARTIAL, length=264, every=28, flow="window", partial=True)
@example(knobs=NOISY_PARTIAL, length=220, every=28, flow="window", partial=True)
def test_every_query_is_answered_once_with_its_ok(
        knobs: dict[str, object], length: int, every: int, flow: str, partial: bool) -> None:
    commands = with_queries(sliced_like(length, int(knobs["seed"])), every)  # type: ignore[call-overload]
    link = LinkSettings(flow_control=flow, partial_lines=partial, ok_timeout=5.0, nudges=3,
                        rx_buffer_bytes=int(knobs["rx_buffer_bytes"]))  # type: ignore[call-overload]
    bench = VirtualBench(link, SimSettings(**knobs))  # type: ignore[arg-type]
    assert bench.connect()
    bench.stream(commands, queries=QUERIES)
    assert_exactly_once(bench, commands)
    assert_queries_answered(bench, commands)


@pytest.mark.parametrize(("rx", "seed"), [(63, 21), (63, 22), (127, 23)])
def test_queries_whose_oks_are_lost_are_answered_after_the_nudge(rx: int, seed: int) -> None:
    """With a 63-byte buffer, queries often go out in parts when a timeout comes."""
    commands = with_queries(sliced_like(3000, seed), 5)
    sim = SimSettings(lost_ok_prob=0.02, rx_buffer_bytes=rx, seed=seed)
    bench = VirtualBench(LinkSettings(rx_buffer_bytes=rx, ok_timeout=5.0, nudges=3), sim)
    assert bench.connect()
    bench.stream(commands, queries=QUERIES)
    assert_exactly_once(bench, commands)
    assert_queries_answered(bench, commands)
    assert bench.protocol.counters.timeouts > 0  # oks really were lost, and nudges sent


@pytest.mark.parametrize(("flow", "advanced_ok", "rx", "seed"), [
    ("window", False, 127, 11), ("window", True, 127, 12), ("pingpong", False, 127, 13),
    ("window", False, 63, 14),
])
def test_ten_thousand_lines_with_one_percent_corruption_lost_oks_and_busy(
        flow: str, advanced_ok: bool, rx: int, seed: int) -> None:
    commands = sliced_like(10_000, seed)
    sim = SimSettings(bit_flip_prob=0.01, lost_ok_prob=0.003, busy_prob=0.005,
                      advanced_ok=advanced_ok, rx_buffer_bytes=rx, seed=seed)
    link = LinkSettings(flow_control=flow, rx_buffer_bytes=rx, ok_timeout=5.0, nudges=3)
    bench = run(commands, link, sim)
    assert_exactly_once(bench, commands)
    assert bench.firmware.faults.flipped > 50  # the faults really happened
    assert bench.protocol.counters.checksum_errors > 0
    assert bench.protocol.counters.lines_resent >= bench.firmware.faults.flipped
    assert (bench.protocol.counters.lines_split > 0) == (flow == "window")


def test_a_host_that_ignores_the_window_is_caught_by_the_emulator() -> None:
    """Sanity check of the emulator: overfilling a board with a full planner loses bytes."""
    from hostd.link.framing import encode, frame
    from hostd.sim.firmware import Firmware

    fw = Firmware(SimSettings())
    fw.receive(encode(frame(0, "M110 N0")))
    burst = b"".join(encode(frame(n, f"G1 X{n * 10} F600")) for n in range(1, 60))
    fw.receive(burst)
    assert fw.dropped_bytes > 0


ANY_QUERY = ("M114", "M400", "M105 T0")  # M400 is answered by a plain ok


def assert_same_outcome(knobs: dict[str, object], length: int, every: int, partial: bool,
                        read_every: float, patched: Callable[[bool, list[Any]], Any]
                        ) -> tuple[list[Any], list[Any]]:
    """Run a job with queries twice, under the patch ``patched(True, log)`` (the short path
    taken) and ``patched(False, log)`` (declined), and check that both put the same bytes
    on the wire at the same moments, answer the same queries with the same replies,
    acknowledge the same lines in the same order and end in the same state. Returns the two
    logs the patches kept."""
    commands = with_queries(tiny_moves(length, int(knobs["seed"])), every, ANY_QUERY)  # type: ignore[call-overload]
    link = LinkSettings(partial_lines=partial, ok_timeout=5.0, nudges=3,
                        rx_buffer_bytes=int(knobs["rx_buffer_bytes"]))  # type: ignore[call-overload]
    runs = []
    for short in (True, False):
        bench = VirtualBench(link, SimSettings(**knobs), read_every=read_every)  # type: ignore[arg-type]
        log: list[Any] = []
        with patched(short, log):
            assert bench.connect()
            bench.stream(commands, queries=ANY_QUERY)
        runs.append((bench, log))
    (fast, taken), (slow, declined) = runs
    assert fast.outcome.sent == slow.outcome.sent and fast.now == slow.now
    assert _in_order(fast.outcome.events) == _in_order(slow.outcome.events)
    assert fast.protocol.snapshot() == slow.protocol.snapshot()
    assert (fast.protocol._read_through, fast.protocol._slots_seen) == \
        (slow.protocol._read_through, slow.protocol._slots_seen)  # the queue credit
    return taken, declined


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(knobs=faults, length=st.integers(1, 600), every=st.integers(2, 60),
       partial=st.booleans(), read_every=st.sampled_from([0.0, 0.001, 0.003]))
def test_oks_read_together_take_the_short_path_to_the_same_outcome(
        knobs: dict[str, object], length: int, every: int, partial: bool,
        read_every: float) -> None:
    """The oks of one read are executed in one step (``Protocol._ok_run``) while the
    transmissions are in order. Under random faults, with replies read several at a time,
    the same job with that step and with one ``_execute_through`` per ok (``pop_run``
    patched to decline) has the same outcome (:func:`assert_same_outcome`; round trips and
    window included)."""
    def patched(short: bool, log: list[Any]) -> Any:
        return patch.object(InFlight, "pop_run", side_effect=_counted(log, short),
                            autospec=True)
    taken, declined = assert_same_outcome(knobs, length, every, partial, read_every, patched)
    assert len(taken) == len(declined)  # the same reads met the same choice


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(knobs=faults, length=st.integers(1, 600), every=st.integers(2, 60),
       partial=st.booleans(), read_every=st.sampled_from([0.0, 0.001, 0.003]))
def test_advanced_oks_in_sequence_join_the_run_to_the_same_outcome(
        knobs: dict[str, object], length: int, every: int, partial: bool,
        read_every: float) -> None:
    """ADVANCED_OK's ``ok N<n> P<p> B<b>`` numbered in sequence join the run of the read
    (``parse_advanced_ok`` in ``receive_lines``). Under random faults, the same job with
    that and with every such ok parsed and handled on its own (``parse_advanced_ok`` patched
    to decline) has the same outcome (:func:`assert_same_outcome`; the queue credit,
    ``planner_free`` and ``buffer_free`` included)."""
    def patched(join: bool, log: list[Any]) -> Any:
        return patch("hostd.link.protocol.parse_advanced_ok", side_effect=_noted(log, join))
    joined, declined = assert_same_outcome({**knobs, "advanced_ok": True}, length, every,
                                           partial, read_every, patched)
    # the same lines were offered to the short path (a job whose every ADVANCED_OK reply is
    # lost or out of sequence joins none: the test below shows that a plain job joins them)
    assert len(joined) == len(declined)


@pytest.mark.parametrize("read_every", [0.001, 0.003])
def test_a_plain_job_takes_the_short_path_for_runs_of_oks(read_every: float) -> None:
    """Without faults and with replies read a few milliseconds at a time (as the daemon's
    held reads), most oks go the short path, many in runs of two or more."""
    commands = tiny_moves(600, 5)
    bench = VirtualBench(LinkSettings(), SimSettings(), read_every=read_every)
    taken: list[int] = []
    with patch.object(InFlight, "pop_run", side_effect=_counted(taken, True), autospec=True):
        assert bench.connect()
        bench.stream(commands)
    assert_exactly_once(bench, commands)
    assert sum(taken) >= 0.9 * len(commands) and max(taken) >= 2


def test_a_job_with_advanced_ok_takes_the_short_path() -> None:
    """Without faults, nearly every ADVANCED_OK reply joins a run: the emulator numbers its
    oks in sequence, so they are handled as plain ones, plus their fields."""
    commands = tiny_moves(600, 6)
    bench = VirtualBench(LinkSettings(), SimSettings(advanced_ok=True), read_every=0.003)
    joined: list[int] = []  # the ADVANCED_OK replies of each run

    def ok_run(self: Protocol, oks: list[Ok], now: float) -> None:
        joined.append(sum(ok.line is not None for ok in oks))
        _OK_RUN(self, oks, now)

    with patch.object(Protocol, "_ok_run", side_effect=ok_run, autospec=True):
        assert bench.connect()
        bench.stream(commands)
    assert_exactly_once(bench, commands)
    assert sum(joined) >= 0.9 * len(commands) and max(joined) >= 2
    assert bench.protocol.observed.advanced_ok
    assert bench.protocol._read_through > 0  # the fields were taken in


def _noted(log: list[Ok | None], join: bool) -> Callable[[str | bytes], Ok | None]:
    """``parse_advanced_ok`` as it is, noting each result, or declining every line."""
    def parse(line: str | bytes) -> Ok | None:
        ok = _PARSE_ADVANCED_OK(line) if join else None
        log.append(ok)
        return ok
    return parse


def _in_order(events: list[Action]) -> list[tuple[str, object]]:
    """The events of a job, a run of acknowledgements in a row counted as its last one (one
    ``Acked`` for several lines resolves the same futures, in the same order)."""
    out: list[tuple[str, object]] = []
    for event in events:
        if isinstance(event, Acked):
            if out and out[-1][0] == "acked":
                out.pop()
            out.append(("acked", event.line))
        elif isinstance(event, Answer):
            out.append(("answer", (event.line, event.replies)))
        else:
            out.append((type(event).__name__, str(getattr(event, "error", ""))))
    return out


def _counted(log: list[int], short: bool) -> Callable[..., list[Sent] | None]:
    """``InFlight.pop_run`` as it is, noting how many lines each call took (0 when it
    declined: transmissions out of order), or declining every time."""
    def pop_run(self: InFlight, first: int, last: int) -> list[Sent] | None:
        if not short:
            log.append(0)
            return None
        out = _POP_RUN(self, first, last)
        log.append(0 if out is None else last - first + 1)
        return out
    return pop_run


_POP_RUN = InFlight.pop_run
_PARSE_ADVANCED_OK = parse_advanced_ok
_OK_RUN = Protocol._ok_run
