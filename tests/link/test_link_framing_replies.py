"""Framing and the reply parser (pure)."""

from __future__ import annotations

import random

import pytest

from hostd.link.framing import FOLD_BYTES, checksum, encode, frame, framed, strip_gcode
from hostd.link.replies import (
    Banner,
    Busy,
    Capability,
    Echo,
    ErrorReply,
    FirmwareInfo,
    Halted,
    Ok,
    Other,
    Position,
    Resend,
    Temperatures,
    Wait,
    parse_reply,
)


def test_frame_matches_the_well_known_m110_line() -> None:
    assert frame(0, "M110 N0") == "N0 M110 N0*125"
    assert encode(frame(0, "M110 N0")) == b"N0 M110 N0*125\n"


def test_checksum_is_the_xor_of_the_bytes() -> None:
    assert checksum("") == 0
    assert checksum("N1 G28") == ord("N") ^ ord("1") ^ ord(" ") ^ ord("G") ^ ord("2") ^ ord("8")


def _xor_each(text: str) -> int:
    cs = 0
    for b in text.encode("ascii", "replace"):
        cs ^= b
    return cs


@pytest.mark.parametrize("seed", range(4))
def test_folded_checksum_matches_a_byte_by_byte_xor(seed: int) -> None:
    """Random texts around and beyond the fold's 128 bytes, every length up to three folds;
    non-ASCII characters go out as ``?``."""
    rng = random.Random(seed)
    for length in range(3 * FOLD_BYTES + 2):
        text = "".join(chr(rng.choice((rng.randrange(32, 127), rng.randrange(1, 300))))
                       for _ in range(length))
        assert checksum(text) == _xor_each(text), (seed, length)
        number = rng.randrange(10 ** rng.randrange(1, 8))
        assert framed(number, text) == encode(frame(number, text))


@pytest.mark.parametrize(("raw", "expected"), [
    ("G1 X10 ; move", "G1 X10"),
    ("  ; only a comment", None),
    ("", None),
    ("g28 (home) X", "G28 X"),
    ("N12 G1 X1*97", "G1 X1"),
    ("M117 Hello world", "M117 Hello world"),
    # Marlin reads upper-case parameters only, and hostd's modal tracker takes x20 for X20:
    # the line sent is the one tracked. Text arguments stay as written; a tab is a blank.
    ("g1 x20 y5.5 e0.1", "G1 X20 Y5.5 E0.1"),
    ("G1 X10\tY7", "G1 X10 Y7"),
    ("G1\tX10 Y2", "G1 X10 Y2"),
    ("m118 e1 Hello", "M118 e1 Hello"),
    ("M117\tHello there", "M117 Hello there"),
    ("M23 part.gco", "M23 part.gco"),
])
def test_strip_gcode(raw: str, expected: str | None) -> None:
    assert strip_gcode(raw) == expected


@pytest.mark.parametrize(("line", "expected"), [
    ("ok", Ok()),
    ("ok N10 P15 B3", Ok(10, 15, 3)),
    ("Resend: 12", Resend(12)),
    ("Resend:12", Resend(12)),
    ("rs N12", Resend(12)),
    ("rs 12", Resend(12)),
    ("echo:busy: processing", Busy("processing")),
    ("busy: paused for user", Busy("paused for user")),
    ("wait", Wait()),
    ("start", Banner("start")),
    ("echo:Marlin bugfix-2.1.x", Banner("echo:Marlin bugfix-2.1.x")),
    ("Error:Printer halted. kill() called!", Halted("Error:Printer halted. kill() called!")),
    ("!! thermal runaway", Halted("!! thermal runaway")),
    ("Cap:AUTOREPORT_TEMP:1", Capability("AUTOREPORT_TEMP", True)),
    ("Cap:EMERGENCY_PARSER:0", Capability("EMERGENCY_PARSER", False)),
    ("echo:Unknown command: \"X\"", Echo("Unknown command: \"X\"")),
    ("something else", Other("something else")),
])
def test_simple_replies(line: str, expected: object) -> None:
    assert parse_reply(line) == expected


@pytest.mark.parametrize(("line", "kind", "last"), [
    ("Error:checksum mismatch, Last Line: 11", "checksum", 11),
    ("Error:Line Number is not Last Line Number+1, Last Line: 11", "line_number", 11),
    ("Error:No Checksum with line number, Last Line: 3", "no_checksum", 3),
    ("Error:No Line Number with checksum, Last Line: 3", "no_line_number", 3),
    ("Error:Something odd", "other", None),
])
def test_error_lines(line: str, kind: str, last: int | None) -> None:
    reply = parse_reply(line)
    assert isinstance(reply, ErrorReply)
    assert (reply.kind, reply.last_line) == (kind, last)


@pytest.mark.parametrize("line", [
    "ok T:210.0 /210.0 B:60.0 /60.0 @:0 B@:0",
    " T:210.00 /210.00 B:60.00 /60.00 @:0 B@:0",
    "T:210.0/210.0 B:60.0/60.0 @:64",
    "ok T0:210.0 /210.0 B:60.0 /60.0 T:210.0 /210.0",
])
def test_temperature_reports_with_and_without_blanks(line: str) -> None:
    reply = parse_reply(line)
    temps = reply.temperatures if isinstance(reply, Ok) else reply
    assert isinstance(temps, Temperatures)
    heater = temps.heaters.get("T") or temps.heaters["T0"]
    assert heater.actual == 210.0 and heater.target == 210.0
    assert temps.heaters["B"].target == 60.0


def test_m114_with_rotary_axes_ignores_the_step_counts() -> None:
    reply = parse_reply("X:1.00 Y:2.00 Z:3.00 A:10.00 C:-45.00 E:0.50 Count X:80 Y:160 Z:1200 "
                        "A:400 C:-1800")
    assert reply == Position({"X": 1.0, "Y": 2.0, "Z": 3.0, "A": 10.0, "C": -45.0, "E": 0.5})


def test_position_on_the_ok_line() -> None:
    reply = parse_reply("ok X:1.0 Y:2.0 Z:3.0 E:0.0 Count: A:0 B:0 C:0")
    assert isinstance(reply, Ok) and reply.position == Position(
        {"X": 1.0, "Y": 2.0, "Z": 3.0, "E": 0.0})


def test_m115_firmware_line() -> None:
    reply = parse_reply("FIRMWARE_NAME:Marlin 2.1.2 (Github) SOURCE_CODE_URL:github.com/x "
                        "PROTOCOL_VERSION:1.0 MACHINE_TYPE:5axis EXTRUDER_COUNT:1 UUID:abc")
    assert isinstance(reply, FirmwareInfo)
    assert reply.name == "Marlin 2.1.2 (Github)"
    assert reply.fields["EXTRUDER_COUNT"] == "1"
