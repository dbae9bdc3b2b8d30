"""Lines in parts (character counting): the credit is filled to the byte, and a line that went
out in part is always finished before anything else goes on the wire."""

from __future__ import annotations

import pytest
from test_link_protocol import acks, failures, ready, wire

from hostd.link.errors import FirmwareReset
from hostd.link.framing import encode, frame
from hostd.link.protocol import Protocol

CMD = "G1 X{0}.000 Y{0}.000 Z{0}.000 E0.0100"  # 37-39 bytes framed: one whole line in 63


def line(n: int) -> str:
    """Line ``n`` as framed on the wire (the n-th submission carries CMD with n)."""
    return encode(frame(n, CMD.format(n))).decode()


def started(**kw: object) -> tuple[Protocol, str]:
    """A 63-byte buffer after ten submissions: line 1 whole, line 2 up to the 63rd byte."""
    p = ready(rx_buffer_bytes=63, **kw)
    sent = "".join(wire(p.submit(CMD.format(i), 0.0)[1]) for i in range(1, 11))
    return p, sent


def numbers(text: str) -> list[str]:
    """The line numbers of the complete lines in ``text``."""
    return [ln.split()[0] for ln in text.splitlines(keepends=True) if ln.endswith("\n")]


def test_a_resend_replays_only_after_the_line_in_parts_is_finished() -> None:
    p, sent = started()
    assert numbers(sent) == ["N1"] and len(sent) == 63 and p.counters.lines_split == 1
    # line 1 arrived garbled: rejected at once
    out = wire(p.receive("Error:checksum mismatch, Last Line: 0", 0.1))
    out += wire(p.receive("Resend: 1", 0.1))
    assert out == ""  # the halved window has no room: nothing, not even the rest of line 2
    out += wire(p.receive("ok", 0.1))  # the error ok frees line 1: line 2 alone holds credit
    assert sent + out == line(1) + line(2)
    # the finished old line 2 is rejected too: a duplicate request. Every line in flight is
    # answered, two of them refused: the numbering is set back (M110), then the replay
    out += wire(p.receive("Error:Line Number is not Last Line Number+1, Last Line: 0", 0.1))
    out += wire(p.receive("Resend: 1", 0.1))
    out += wire(p.receive("ok", 0.1))
    assert numbers(sent + out) == ["N1", "N2", "N0"]
    assert out.endswith(encode(frame(0, "M110 N0")).decode())
    assert p.counters.duplicate_resends == 1 and p.counters.resyncs == 1
    done = []
    for _ in range(4):  # the M110's ok, then lines 1 to 3
        actions = p.receive("ok", 0.2)
        done += acks(actions)
        out += wire(actions)
    assert done == [1, 2, 3]
    assert numbers(sent + out)[:6] == ["N1", "N2", "N0", "N1", "N2", "N3"]


def test_a_timeout_finishes_the_line_then_nudges() -> None:
    p, sent = started(ok_timeout=1.0)
    out = wire(p.tick(1.5))
    assert (sent + out).startswith(line(1) + line(2) + encode(frame(3, "M105")).decode())


def test_a_firmware_reset_drops_the_rest_and_handshakes() -> None:
    p, _ = started()
    actions = p.receive("start", 0.1)
    assert isinstance(failures(actions)[0], FirmwareReset)
    assert wire(actions) == "N0 M110 N0*125\n"  # never the tail of line 2


def test_a_line_in_parts_cannot_be_acknowledged_or_counted_as_read() -> None:
    p, _ = started()
    p.receive("ok N1 P10 B3", 0.1)  # line 1 alone in the queue; line 3 starts in parts
    # a claim that the queue holds lines up to 5 frees nothing of line 3, still in parts
    actions = p.receive("ok N2 P10 B0", 0.1)
    assert acks(actions) == [2] and p.inflight_bytes == 63
    assert acks(p.receive("ok N3 P10 B3", 0.1)) == [3]  # once it is whole it may be


@pytest.mark.parametrize("kw", [{"partial_lines": False}, {"flow_control": "pingpong"}])
def test_whole_lines_only_when_switched_off_and_in_ping_pong(kw: dict[str, object]) -> None:
    p, sent = started(**kw)
    assert sent == line(1) and p.counters.lines_split == 0
