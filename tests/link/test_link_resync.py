"""Resend requests out of step with the lines sent (issue 38, item 6): the pure protocol against
a board that counts lines as OctoPrint's virtual printer does.

That emulator counts every line whose checksum passes (``current_line``), refused or not, and
answers a checksum error with ``Resend: current_line + 1``. After a window's lines in flight
were refused, its count runs ahead of the lines it took, so at its next checksum error it asks
for a line never sent. The link used to take that for a duplicate request and wait out the ok
timeout, again and again; now it drains the answers and sets the numbering back with ``M110``.
"""

from __future__ import annotations

import random

from test_link_protocol import acks, ready, wire, writes

from hostd.link.actions import Acked, Action, Write
from hostd.link.framing import checksum, encode, frame


class DriftingBoard:
    """OctoPrint's virtual printer's line checks (``_processIncoming``, ``_triggerResend``),
    answering each line at once; ``flips`` of the numbered lines arrive with a bit flipped."""

    def __init__(self, flips: float = 0.0, seed: int = 0) -> None:
        self.last_n = 0  # lastN: the last line taken
        self.current = 0  # current_line: every line whose checksum passed
        self.executed: list[str] = []
        self.rng = random.Random(seed)
        self.flips = flips
        self._buf = b""

    def feed(self, data: bytes) -> list[str]:
        """The replies to the complete lines in ``data``."""
        self._buf += data
        *lines, self._buf = self._buf.split(b"\n")
        out: list[str] = []
        for raw in lines:
            out += self._line(self._noise(raw.decode()))
        return out

    def _noise(self, line: str) -> str:
        star = line.rfind("*")
        if star < 2 or self.rng.random() >= self.flips:
            return line
        at = self.rng.randrange(1, star)  # never the N or the *: the checksum catches it
        flipped = chr(ord(line[at]) ^ (1 << self.rng.randrange(7)))
        return line if flipped in "*\r\n" else line[:at] + flipped + line[at + 1:]

    def _line(self, line: str) -> list[str]:
        body, _, cs = line.rpartition("*")
        if not cs.isdigit() or int(cs) != checksum(body):
            return self._resend(self.current + 1, "checksum mismatch")
        self.current += 1
        number_text, _, command = body.partition(" ")
        number = int(number_text[1:])
        if command.startswith("M110"):
            self.last_n = self.current = number
            return ["ok"]
        if number != self.last_n + 1:
            return self._resend(self.last_n + 1, "Line Number is not Last Line Number+1")
        self.last_n = number
        self.executed.append(command)
        return ["ok"]

    def _resend(self, expected: int, why: str) -> list[str]:
        self.last_n = expected - 1
        return [f"Error:{why}, Last Line: {self.last_n}", f"Resend:{expected}", "ok"]


def run(p: object, board: DriftingBoard, actions: list[Action], now: float) -> list[Action]:
    """Carry the host's writes to the board and its replies back until the wire is quiet."""
    seen: list[Action] = []
    while actions:
        seen += actions
        data = b"".join(a.data for a in actions if isinstance(a, Write))
        replies = board.feed(data)
        actions = p.receive_lines(replies, now) if replies else []  # type: ignore[attr-defined]
    return seen


def test_a_request_for_a_line_never_sent_resynchronises_at_once() -> None:
    p = ready()
    for i in (1, 2, 3):
        p.submit(f"G1 X{i}", 0.0)
    assert acks(p.receive("ok", 0.1)) == [1]
    # line 2 garbled, the count ahead by two: the board asks for line 5, never sent; line 3
    # is refused as out of turn, with the same request
    for error in ("checksum mismatch", "Line Number is not Last Line Number+1"):
        p.receive(f"Error:{error}, Last Line: 4", 0.2)
        p.receive("Resend: 5", 0.2)
        out = writes(p.receive("ok", 0.2))
    assert out == [frame(1, "M110 N1")]  # at once: no ok timeout waited out
    assert writes(p.receive("ok", 0.3)) == [frame(2, "G1 X2"), frame(3, "G1 X3")]
    assert acks(p.receive("ok", 0.4) + p.receive("ok", 0.4)) == [2, 3]
    assert p.counters.resyncs == 1 and p.counters.timeouts == 0


def test_an_m110_whose_ok_is_lost_is_sent_again_after_the_timeout() -> None:
    p = ready(ok_timeout=1.0)
    p.submit("G1 X1", 0.0)
    p.receive("ok", 0.1)  # everything sent is executed: nothing else holds the deadline
    p.receive("Resend: 3", 0.2)
    assert wire(p.receive("ok", 0.2)) == encode(frame(1, "M110 N1")).decode()
    deadline = p.deadline()
    assert deadline is not None
    assert wire(p.tick(deadline + 0.01)) == encode(frame(1, "M110 N1")).decode()
    p.receive("ok", 1.5)
    p.submit("G1 X2", 1.6)
    assert acks(p.receive("ok", 1.7)) == [2] and p.counters.resyncs == 1


def test_a_drifting_board_on_a_noisy_line_gets_every_line_once_without_a_timeout() -> None:
    board = DriftingBoard(flips=0.03, seed=7)
    p = ready(rx_buffer_bytes=127, ok_timeout=10.0)
    commands = [f"G1 X{i % 50} Y{i % 7} E{i}" for i in range(1, 1001)]
    _, actions = p.submit_many(commands, 0.0)  # the window holds several lines in flight
    acked = [a.line for a in run(p, board, actions, 0.1) if isinstance(a, Acked)]
    assert acked[-1] == len(commands) and board.executed == commands
    assert p.counters.checksum_errors > 10 and p.counters.resyncs > 0
    assert p.counters.timeouts == 0


def test_a_request_after_a_lost_ok_trusts_the_firmware_and_runs_nothing_twice() -> None:
    """Line 2's ok is lost; the timeout's nudge (line 3) arrives garbled. The request for
    line 3 is ahead of the oks counted, but line 2 was sent before the timeout and never
    answered: its answer was lost, and the firmware took it. Line 3 is resent, not line 2."""
    p = ready(ok_timeout=1.0)
    p.submit("G1 X1", 0.0)
    p.submit("G1 X2", 0.0)
    assert acks(p.receive("ok", 0.1)) == [1]
    assert writes(p.tick(1.2)) == [frame(3, "M105")]
    p.receive("Error:checksum mismatch, Last Line: 2", 1.3)
    p.receive("Resend: 3", 1.3)
    actions = p.receive("ok", 1.3)
    assert acks(actions) == [2] and writes(actions) == [frame(3, "M105")]
    assert p.counters.resyncs == 0
