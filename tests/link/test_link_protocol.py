"""The pure protocol state machine, driven by hand-written firmware replies."""

from __future__ import annotations

import pytest

from hostd.link.actions import Acked, Action, Answer, Connected, Failed, Notice, Write
from hostd.link.errors import (
    EmergencyStop,
    FirmwareHalted,
    FirmwareReset,
    HistoryExhausted,
    LinkLost,
    NotConnected,
    ResendLoop,
)
from hostd.link.framing import encode, frame
from hostd.link.protocol import Protocol
from hostd.link.settings import LinkSettings


def writes(actions: list[Action]) -> list[str]:
    return [a.data.decode().strip() for a in actions if isinstance(a, Write)]


def wire(actions: list[Action]) -> str:
    """The bytes written, joined (a line may go out in parts)."""
    return b"".join(a.data for a in actions if isinstance(a, Write)).decode()


def acks(actions: list[Action]) -> list[int]:
    return [a.line for a in actions if isinstance(a, Acked)]


def notices(actions: list[Action]) -> list[str]:
    return [a.message for a in actions if isinstance(a, Notice)]


def failures(actions: list[Action]) -> list[object]:
    return [a.error for a in actions if isinstance(a, Failed)]


def ready(**kw: object) -> Protocol:
    p = Protocol(LinkSettings(**kw))  # type: ignore[arg-type]
    assert writes(p.start(0.0)) == ["N0 M110 N0*125"]
    assert any(isinstance(a, Connected) for a in p.receive("ok", 0.0))
    return p


def test_window_keeps_unacknowledged_bytes_within_the_buffer() -> None:
    p = ready(rx_buffer_bytes=63, partial_lines=False)
    sent: list[str] = []
    for i in range(10):
        sent += writes(p.submit(f"G1 X{i}.000 Y{i}.000", 0.0)[1])
    assert sum(len(s) + 1 for s in sent) <= 63
    assert sent[0].startswith("N1 G1 X0.000")
    more = writes(p.receive("ok", 0.1))
    assert more and more[0].startswith(f"N{len(sent) + 1} ")


def test_partial_lines_fill_the_buffer_to_the_byte_and_finish_the_line_first() -> None:
    p = ready(rx_buffer_bytes=63)
    cmd = "G1 X{0}.000 Y{0}.000 Z{0}.000 E0.0100"  # 38 bytes framed: one whole line fits
    sent = "".join(wire(p.submit(cmd.format(i), 0.0)[1]) for i in range(10))
    assert len(sent) == 63 and p.inflight_bytes == 63
    first, part = sent.split("\n")
    assert first.startswith("N1 ") and part.startswith("N2 G1 X1.000")
    more = wire(p.receive("ok", 0.1))  # line 1 done: its 38 bytes of credit come back
    assert (part + more).startswith(f"N2 {cmd.format(1)}*") and len(more) == len(first) + 1
    assert (part + more).split("\n")[1].startswith("N3 ")
    assert p.inflight_bytes == 63 and p.counters.lines_split == 2


def test_replies_received_together_count_as_one_read() -> None:
    p = ready()
    for i in range(3):
        p.submit(f"G1 X{i}", 0.0)
    before = p.counters.reads
    assert acks(p.receive_lines(["ok", "ok"], 0.1)) == [2]  # both lines, acknowledged at once
    assert acks(p.receive_lines(["ok"], 0.2)) == [3]
    assert p.rtt.buckets.n == 3  # a round trip per line all the same
    assert p.counters.reads - before == 2 and p.snapshot()["reads"] == p.counters.reads


@pytest.mark.parametrize("partial", [True, False])
def test_submit_many_puts_on_the_wire_what_a_submit_each_does(partial: bool) -> None:
    """The lines of one submit_many go out, ok by ok, exactly as when each is submitted on
    its own, and are acknowledged alike."""
    one, many = ready(partial_lines=partial), ready(partial_lines=partial)
    warm = "G28"
    one.submit(warm, 0.0)
    many.submit(warm, 0.0)
    cmds = [f"G1 X{i}.000 Y{2 * i}.500 E0.0{i % 10}" for i in range(30)]
    one_wire = "".join(wire(one.submit(c, 0.0)[1]) for c in cmds)
    first, actions = many.submit_many(cmds, 0.0)
    assert first == 2 and wire(actions) == one_wire
    for k in range(len(cmds) + 1):
        want, got = one.receive("ok", 0.1 * k), many.receive("ok", 0.1 * k)
        assert wire(got) == wire(want) and many.last_acked == one.last_acked == k + 1
    assert many.snapshot() | {"ok_rtt": None} == one.snapshot() | {"ok_rtt": None}


def test_submit_many_needs_a_connection() -> None:
    with pytest.raises(NotConnected):
        Protocol(LinkSettings()).submit_many(["G28"], 0.0)


def test_pingpong_has_one_line_in_flight() -> None:
    p = ready(flow_control="pingpong")
    first = writes(p.submit("G28", 0.0)[1])
    second = writes(p.submit("G1 X1", 0.0)[1])
    assert len(first) == 1 and second == []
    actions = p.receive("ok", 0.1)
    assert acks(actions) == [1] and writes(actions)[0].startswith("N2 G1 X1")


def test_resend_rewinds_and_duplicate_requests_are_ignored() -> None:
    p = ready()
    for cmd in ("G1 X1", "G1 X2", "G1 X3"):
        p.submit(cmd, 0.0)
    # Line 1 garbled: line 1 and the lines after it are each rejected with "Resend: 1".
    resent = ""
    for _ in range(3):
        p.receive("Error:checksum mismatch, Last Line: 0", 0.1)
        resent += wire(p.receive("Resend: 1", 0.1))
        resent += wire(p.receive("ok", 0.1))
    # all three answered, three refused: the numbering is set back, then the replay
    assert resent == "N0 M110 N0*125\n"
    resent += wire(p.receive("ok", 0.1))
    assert [r.split()[0] for r in resent.splitlines()] == ["N0", "N1", "N2", "N3"]
    assert p.counters.duplicate_resends == 2 and p.counters.lines_resent == 3
    actions = p.receive("ok", 0.2) + p.receive("ok", 0.2) + p.receive("ok", 0.2)
    assert acks(actions) == [1, 2, 3]


def test_a_resend_is_noted_for_the_log_once_per_request_acted_on() -> None:
    p = ready()
    for cmd in ("G1 X1", "G1 X2", "G1 X3"):
        p.submit(cmd, 0.0)
    p.receive("Error:checksum mismatch, Last Line: 1", 0.1)
    assert notices(p.receive("Resend: 2", 0.1)) == [
        "firmware asked for line 2 again: resending 2 line(s)"]
    p.receive("ok", 0.1)
    p.receive("Error:Line Number is not Last Line Number+1, Last Line: 1", 0.1)
    assert notices(p.receive("Resend: 2", 0.1)) == []  # the line after it, rejected too


def test_a_line_rejected_too_often_fails_the_job() -> None:
    p = ready(resend_limit=3)
    p.receive("ok T:210.00 /210.00 B:60.00 /60.00 @:40 B@:0", 0.0)
    p.submit("G1 X1", 0.0)
    errors: list[object] = []
    for _ in range(4):
        actions = p.receive("Resend: 1", 0.1)
        errors += failures(actions)
        p.receive("ok", 0.1)
    assert len(errors) == 1 and isinstance(errors[0], ResendLoop)
    assert "line 1" in str(errors[0])
    # the host gives the board up: it halts it (heaters off) rather than leave it heating,
    # and shows no temperatures it can no longer read
    assert writes(actions)[-1] == "M112" and p.state == "halted"
    assert p.snapshot()["temperatures"] == {}


def test_advanced_ok_resynchronises_after_lost_oks() -> None:
    p = ready()
    for i in range(3):
        p.submit(f"G1 X{i}", 0.0)
    assert acks(p.receive("ok N3 P10 B3", 0.1)) == [3]  # the oks of 1 and 2 were lost


def test_m105_answer_is_a_barrier_after_a_timeout() -> None:
    p = ready(ok_timeout=1.0)
    p.submit("G1 X1", 0.0)
    p.submit("G1 X2", 0.0)
    assert p.deadline() == pytest.approx(1.0)
    assert notices(p.tick(0.99)) == []
    actions = p.tick(1.0)
    assert writes(actions) == ["N3 M105*36"]
    assert notices(actions) == ["no ok for 1 s (line 1 awaited, 2 sent): M105 nudge 1 of 1"]
    assert acks(p.receive("ok T:20.0 /0.0 B:20.0 /0.0", 1.1)) == [2]


def test_a_late_query_answer_after_the_nudge_still_answers_the_query() -> None:
    """An ``M105`` query's ``ok T:`` arriving after the timeout's nudge went out executes
    the nudge's line too: the query is answered with the temperatures, not with nothing."""
    p = ready(ok_timeout=1.0)
    seq, _ = p.submit("M105", 0.0, kind="query")
    assert writes(p.tick(1.0)) == ["N2 M105*37"]
    out = p.receive("ok T:21.5 /0.0 B:20.0 /0.0", 1.1)
    answers = [a for a in out if isinstance(a, Answer)]
    assert [a.line for a in answers] == [seq] and acks(out) == [seq]
    temps = [r.temperatures for r in answers[0].replies if hasattr(r, "temperatures")]
    assert temps and temps[-1] is not None and temps[-1].heaters["T"].actual == 21.5


def test_an_m105_finished_by_the_timeout_keeps_its_own_ok() -> None:
    """An M105 going out in parts when the timeout comes is finished then, before the nudge:
    the firmware answers it first, so the first ``ok T:`` is its, not the nudge's (else
    every later line would be acknowledged one ``ok`` early)."""
    p = ready(rx_buffer_bytes=63, ok_timeout=1.0)
    long = "G1 X100.000 Y100.000 Z100.000 A10.0000 C1.0"
    first = wire(p.submit(long, 0.0)[1])
    assert first == encode(frame(1, long)).decode()
    seq, actions = p.submit("M105 T0", 0.0, kind="query")
    part = wire(actions)
    assert part and not part.endswith("\n")  # in parts: the buffer is nearly full
    assert wire(p.tick(1.0)).endswith("N3 M105*36\n")  # rest of line 2, then the nudge
    out = p.receive("ok T:21.0 /0.0 B:20.0 /0.0", 1.1)  # line 2's (line 1's ok was lost)
    assert acks(out) == [seq] and [a.line for a in out if isinstance(a, Answer)] == [seq]
    later, _ = p.submit("G1 X1", 1.1)
    assert acks(p.receive("ok T:21.0 /0.0 B:20.0 /0.0", 1.2)) == []  # the nudge's
    assert acks(p.receive("ok", 1.3)) == [later]


def test_a_rejection_after_a_timeout_frees_a_line_sent_since() -> None:
    """A line rejected with no ``Resend`` (or whose ``Resend`` was lost) is followed by a
    timeout and its nudge, which the firmware rejects in turn. That error ``ok`` answers the
    nudge, not the line from before the timeout, whose credit the timeout already released:
    the nudge's credit is freed and the line goes out again at once, not a timeout later."""
    p = ready(rx_buffer_bytes=63, ok_timeout=1.0, partial_lines=False)
    long = "G1 X100.000 Y100.000 Z10.000 F12000"
    p.submit(long, 0.0)
    p.receive("Error:No Line Number with checksum, Last Line: 0", 0.1)  # and no Resend
    assert writes(p.tick(1.0)) == ["N2 M105*37"]
    p.receive("Error:Line Number is not Last Line Number+1, Last Line: 0", 1.1)
    p.receive("Resend: 1", 1.1)
    resent = writes(p.receive("ok", 1.1))  # the nudge's rejection; the window is halved
    assert resent == [encode(frame(1, long)).decode().strip()]
    assert acks(p.receive("ok", 1.2)) == [1]
    assert writes(p.receive("ok", 1.2)) == [] and p.inflight_bytes == 0


def test_no_answer_to_the_nudge_loses_the_link() -> None:
    p = ready(ok_timeout=1.0)
    p.submit("G1 X1", 0.0)
    p.tick(1.0)
    lost = failures(p.tick(2.0))
    assert len(lost) == 1 and isinstance(lost[0], LinkLost)


def test_busy_extends_the_timeout() -> None:
    p = ready(ok_timeout=1.0)
    p.submit("M109 S210", 0.0)
    p.receive("echo:busy: processing", 0.9)
    assert p.deadline() == pytest.approx(1.9)
    assert writes(p.tick(1.5)) == []


def test_a_heating_waits_temperature_lines_extend_the_timeout_and_autoreports_do_not() -> None:
    """Without Marlin's busy keepalive, an ``M109`` still prints the heaters with ``W:`` each
    second while it waits: the firmware is at work, no nudge goes out. An autoreport (no
    ``W:``) is no such sign: a lost ``ok`` still times out."""
    p = ready(ok_timeout=1.0)
    seq, _ = p.submit("M109 S210", 0.0)
    for second in range(1, 6):
        p.receive(f"T:{40 * second}.00 /210.00 B:22.00 /0.00 @:127 B@:0 W:?", second - 0.1)
        assert writes(p.tick(float(second))) == []
    assert acks(p.receive("ok", 5.5)) == [seq]
    p.submit("G1 X1", 5.5)
    p.receive("T:210.00 /210.00 B:22.00 /0.00 @:40 B@:0", 6.0)  # M155: the ok is lost
    assert writes(p.tick(6.5)) == [encode(frame(3, "M105")).decode().strip()]


def test_start_banner_mid_print_interrupts_at_the_last_ack_and_handshakes_again() -> None:
    p = ready()
    for i in range(3):
        p.submit(f"G1 X{i}", 0.0)
    p.receive("ok", 0.1)
    actions = p.receive("start", 0.2)
    (error,) = failures(actions)
    assert isinstance(error, FirmwareReset) and error.last_acked == 1
    assert writes(actions) == ["N0 M110 N0*125"] and p.state == "handshake"


@pytest.mark.parametrize("restart", ["banner", "start"])
def test_a_restarted_board_forgets_its_temperatures_and_position(restart: str) -> None:
    p = ready()
    p.receive("ok T:210.00 /210.00 B:60.00 /60.00 @:40 B@:0", 0.1)
    p.receive("X:1.00 Y:2.00 Z:3.00 E:0.00 Count X:0 Y:0 Z:0", 0.2)
    before = p.snapshot()
    assert before["temperatures"]["T"]["target"] == 210.0 and before["position"]
    if restart == "banner":
        p.receive("start", 0.3)
    else:  # the port reopened (a firmware restart, a reconnect)
        p.start(0.3)
    after = p.snapshot()
    assert after["temperatures"] == {} and after["position"] == {}
    p.receive("ok", 0.4)  # the handshake
    p.receive("ok T:25.00 /0.00 B:24.00 /0.00 @:0 B@:0", 0.5)
    assert p.snapshot()["temperatures"]["T"]["target"] == 0.0


@pytest.mark.parametrize("line", ["Error:Printer halted. kill() called!", "!!"])
def test_halt_fails_the_job(line: str) -> None:
    p = ready()
    p.submit("G1 X1", 0.0)
    (error,) = failures(p.receive(line, 0.1))
    assert isinstance(error, FirmwareHalted) and p.state == "halted"


@pytest.mark.parametrize("partial", [True, False])
def test_m112_bypasses_a_full_window(partial: bool) -> None:
    p = ready(rx_buffer_bytes=40, partial_lines=partial)
    sent = "".join(wire(p.submit(f"G1 X{i}.0000 Y{i}.0000", 0.0)[1]) for i in range(20))
    actions = p.emergency_stop(0.0)
    # a line that went out in part is finished first: M112 follows a newline
    lines = (sent + wire(actions)).splitlines()
    assert lines[-1] == "M112"
    assert [n.split()[0] for n in lines[:-1]] == (["N1", "N2"] if partial else ["N1"])
    assert isinstance(failures(actions)[0], EmergencyStop)
    assert writes(p.receive("ok", 0.1)) == []  # nothing more is sent


def test_the_window_halves_on_a_resend_and_regrows_with_clean_oks() -> None:
    p = ready(rx_buffer_bytes=127, partial_lines=False)
    for i in range(40):
        p.submit(f"G1 X{i}", 0.0)
    assert p.snapshot()["window_bytes"] == 127
    p.receive("Resend: 1", 0.1)
    assert p.snapshot()["window_bytes"] == 63
    sizes, over = [], []
    for k in range(30):
        sent = writes(p.receive("ok", 0.2 + k / 100))
        sizes.append(p.snapshot()["window_bytes"])
        if sent and p.inflight_bytes > sizes[-1]:  # the rewound lines went out beyond it
            over.append((k, p.inflight_bytes, sizes[-1]))
    assert sizes[:2] == [63, 67]  # the rejection's own ok frees nothing; clean ones grow it
    assert sizes == sorted(sizes) and sizes[-1] == 127
    assert over == []


def test_m155_autoreports_update_temperatures_and_acknowledge_nothing() -> None:
    p = ready()
    for i in range(3):
        p.submit(f"G1 X{i}", 0.0)
    for k, temp in enumerate((25.0, 80.5, 150.25)):
        assert acks(p.receive(f" T:{temp} /210.0 B:40.0 /60.0 @:127 B@:0", 0.1 + k)) == []
    temps = p.snapshot()["temperatures"]
    assert (temps["T"]["actual"], temps["T"]["target"]) == (150.25, 210.0)
    assert (temps["B"]["actual"], temps["B"]["target"]) == (40.0, 60.0)
    assert acks(p.receive("ok", 4.0)) == [1]


def test_resends_reach_back_history_size_lines_and_no_further() -> None:
    p = ready(flow_control="pingpong", history_size=16)
    for i in range(1, 41):
        p.submit(f"G1 X{i}", 0.0)
        assert acks(p.receive("ok", 0.1)) == [i]
    # the last 16 lines are kept; a request for one the firmware took (every one of the 40
    # was answered) is out of step: the numbering is set back, and nothing runs twice
    assert writes(p.receive("Resend: 25", 0.2)) == []  # its error ok first
    actions = p.receive("ok", 0.2)
    assert not failures(actions) and writes(actions) == ["N40 M110 N40*125"]
    assert writes(p.receive("ok", 0.3)) == [] and p.counters.resyncs == 1
    # a line executed more than history_size lines ago is gone: the job cannot go on
    p = ready(flow_control="pingpong", history_size=16)
    for i in range(1, 41):
        p.submit(f"G1 X{i}", 0.0)
        p.receive("ok", 0.1)
    actions = p.receive("Resend: 5", 0.2)
    (error,) = failures(actions)
    assert isinstance(error, HistoryExhausted) and "line 5" in str(error)
    assert writes(actions) == ["M112"]


@pytest.mark.parametrize("many", [False, True])
def test_lines_framed_ahead_are_framed_again_when_a_nudge_takes_their_number(
        many: bool) -> None:
    """Lines are framed when submitted, with the numbers they will most likely get. A
    timeout's M105 nudge takes the next number first: the lines still waiting then go out
    numbered after it, each with its own valid checksum."""
    p = ready(ok_timeout=1.0, rx_buffer_bytes=40, partial_lines=False)
    commands = [f"G1 X{i} Y{i} E0.1" for i in range(6)]
    first = writes(p.submit_many(commands, 0.0)[1] if many else
                   [a for c in commands for a in p.submit(c, 0.0)[1]])
    assert first == [frame(1, commands[0]), frame(2, commands[1])]  # the window holds two
    out = writes(p.tick(1.0))  # the credit released: the nudge, then the next line
    out += writes(p.receive_lines([b"ok", b"ok", b"ok T:20.0 /0.0"], 1.1))
    for k in range(10):  # one ok a read until every line is acknowledged
        if p.last_acked == len(commands):
            break
        out += writes(p.receive_lines([b"ok"], 1.2 + k / 10))
    assert out == [frame(3, "M105")] + [frame(n, c) for n, c in enumerate(commands[2:], 4)]
