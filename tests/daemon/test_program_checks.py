"""A G-code file is refused, line named, for what a firmware would misread or a marker the
daemon cannot use; what is merely unusual passes."""

from __future__ import annotations

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from hostd.link.framing import strip_gcode
from hostd.printer.errors import ProgramError
from hostd.printer.program import check_command, parse_program


@pytest.mark.parametrize(("text", "message"), [
    ("G28\nG1 X1e400 Y5\n", "line 2: X1E400 is not a finite number"),
    ("G1 Xnan\n", "line 1: XNAN is not a finite number"),
    ("G1 X10 E-inf\n", "line 1: E-INF is not a finite number"),
    ("G1 X1\x1a\n", "line 1: control character '\\x1a'"),
    ("M117 a\x07\n", "line 1: control character '\\x07'"),
    ("G28\nM110 N0\nG1 X100\n", "line 2: M110 is not allowed in a job or raw G-code "
                                 "(line numbers are hostd's to set)"),
    ("G28\nm0112\n", "line 2: M0112 is not allowed"),
    ("G28\nM110N0\n", "line 2: M110N0 is not allowed"),
    ("  M999\n", "line 1: M999 is not allowed in a job or raw G-code (use hostctl "
                "firmware-restart)"),
    ("N0 M110 N0*125\nN1 G28*18\n", "line 1: M110 is not allowed"),
    ("N1 G28*99\nN2 G1 X1*99\n", "line 1: checksum 99 does not match the line (18): the file "
                                 "is damaged"),
    ("G28\nhello world\n", "line 2: 'HELLO' is not a G-code command"),
    ("G28\n  X10 Y10\n", "line 2: 'X10' is not a G-code command"),
    ("G28\n%\n", "line 2: '%' is not a G-code command"),
    ("G28\nG X1\n", "line 2: 'G' is not a G-code command"),
    ("(setup) M104 S200\n(note) hello\n", "line 2: 'HELLO' is not a G-code command"),
    ("N10 G28*34\nN11 nope*122\n", "line 2: 'NOPE' is not a G-code command"),
    (';HOSTD_LAYER {"subpart": "a", "index": 0}\nG1 X1\n',
     "line 1: marker needs an integer 'subpart'"),
    (';HOSTD_LAYER {"subpart": [1], "index": 0}\nG1 X1\n',
     "line 1: marker needs an integer 'subpart'"),
    (';HOSTD_TRANSITION {"to": 1, "x": NaN}\nG0 X1\n;HOSTD_TRANSITION_END\n',
     "line 1: marker needs a finite number 'x'"),
    (';HOSTD_TRANSITION {"to": 1, "a": "30"}\nG0 A30\n;HOSTD_TRANSITION_END\n',
     "line 1: marker needs a finite number 'a'"),
])
def test_refused_with_the_line_named(text: str, message: str):
    with pytest.raises(ProgramError) as err:
        parse_program(text)
    assert message in str(err.value)


@pytest.mark.parametrize("text", [
    "G1 X1e3 Y2.5e-2 E0.04 F1800\n",  # exponents a firmware reads
    "M117 infill nan inf\n",  # a message is text
    "M23 inf.gco\n",  # so is a file name
    "(setup) M104 S200\nN1 G28*18\ng1 x1\nT0\n",  # a comment, a number, lowercase, T
    "M1100 S1\nM11\n",  # codes that only start like a reserved one
    "G1 X10\tY5\n",  # a tab separates words
])
def test_unusual_but_valid_lines_pass(text: str):
    assert parse_program(text).commands


def test_an_estimate_keeps_only_finite_figures():
    prog = parse_program(';HOSTD_ESTIMATE {"time_s": Infinity, "filament_mm": 3}\nG28\n')
    assert prog.estimate == {"filament_mm": 3.0}


def test_one_bad_line_among_many_is_found():
    lines = [f"G1 X{i % 50} Y{i % 7} E0.05 F1800" for i in range(2000)]
    lines[1499] = "G1 X5 Ynan"
    with pytest.raises(ProgramError, match="line 1500: YNAN is not a finite number"):
        parse_program("\n".join(lines) + "\n")


WORDS = ["G1", "G0", "M117", "M104", "T0", "G", "%", "(c)", "N7", "hello", "X1", "Y2.5",
         "E0.04", "F1800", "X1e3", "X1e400", "Xnan",
         "Yinf", "E-INF", "NaN", "info", "S210", "; note", "; infill", "(nan)", "a\x1ab",
         "\x07", "\t", "1.e5", "Z.5E-2", "\r", "\x0b", "\u2028", "\x85", "X\u0661e400", "X1_0e400"]
MARKERS = [';HOSTD_LAYER {"index": 1, "note": 1e-16}', ';HOSTD_ESTIMATE {"infill": 0.2}']


@settings(max_examples=600, deadline=None)
@example(["G1 X1 ; a comment, then a line break splitlines honours\rG1 Ynan"])
@example(["G1 X1 ; the same, beyond ASCII\u2028G1 Ynan"])
@example(["G1 X\u0661e400"])  # float() reads Arabic-Indic digits
@given(st.lists(st.lists(st.sampled_from(WORDS), min_size=1, max_size=5).map(" ".join)
                | st.sampled_from(MARKERS), min_size=1, max_size=12))
def test_the_screen_never_spares_a_file_a_closer_look_would_refuse(lines: list[str]):
    """The whole-file screen only skips the per-command check: a file is refused exactly
    when checking every one of its commands refuses it."""
    text = "\n".join(lines) + "\n"
    expected = None
    for lineno, raw in enumerate(text.splitlines(), 1):
        if raw.strip().startswith(";HOSTD_"):
            continue  # a marker, parsed as such
        cmd = strip_gcode(raw)
        if cmd is not None and expected is None:
            try:
                check_command(cmd, lineno)
            except ProgramError as exc:
                expected = str(exc)
    try:
        parse_program(text)
        got = None
    except ProgramError as exc:
        got = str(exc)
    assert got == expected


def test_a_command_longer_than_the_firmware_buffer_is_refused_with_its_line():
    """Marlin keeps MAX_CMD_SIZE - 1 characters of a line and drops the rest: a longer
    command fails its checksum on every resend and the print stalls."""
    from hostd.link.framing import COMMAND_MAX, MAX_CMD_SIZE, frame

    longest = "M117 " + "x" * (COMMAND_MAX - 5)
    assert len(frame(9_999_999, longest)) <= MAX_CMD_SIZE - 1  # fits, framed
    long_comment = "G1 X1 ; " + "c" * 200  # comments are not sent
    assert parse_program(f"G28\n{longest}\n{long_comment}\n").commands[1] == longest
    with pytest.raises(ProgramError) as err:
        parse_program(f"G28\n{longest}\n{longest}y\n")
    assert f"line 3: command of {COMMAND_MAX + 1} characters" in str(err.value)
    assert "MAX_CMD_SIZE 96" in str(err.value)
