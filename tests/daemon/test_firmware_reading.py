"""The heater and travel checks read G-code as the firmware does (issue 38, item 1).

Marlin skips spaces between a parameter's letter and its value, reads ``S+400`` and
``S400.``, a code with no blank before its parameters, a code that wraps at 65536, and cuts
a comment and a checksum. The raw-G-code check, the upload check and the emulator read
words through one reader (:func:`slicer.gcode.markers.marlin_words`); the property test
says that whatever line the emulator would execute out of the machine's limits is refused.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from hostd.config.loader import defaults
from hostd.jobs.file_check import check_file
from hostd.jobs.spool import SpoolError
from hostd.link.framing import checksum, encode, frame
from hostd.printer.envelope import TRAVEL_TOL, envelope_from_config
from hostd.printer.errors import ScriptRefused
from hostd.printer.raw_gcode import check_script
from hostd.sim.firmware import Firmware
from hostd.sim.settings import SimSettings

ENVELOPE = envelope_from_config(defaults().data)
HOTEND, BED = 285.0, 120.0  # machine.max_hotend_temp, machine.max_bed_temp (defaults)


def _numbered(n: int, command: str) -> str:
    return f"N{n} {command}*{checksum(f'N{n} {command}')}"


BYPASSES = [  # each heated or moved the emulator past a limit, and passed both checks
    "M104 S 400", "M140 S 190", "M109 S 350", "G1 X 9999", "G1 A 170", "G0 A  -170",
    "M104 S+400", "M104 S400.", "M104S400", "M104 T0S400", "M65640 S400", "M104.0 S400",
    "M104 S400-5", "M104 S0x190", 'M104 S"400"', "M190 R 130", "G1X9999", "G1 Y9999-1",
    "M104 S400;glued comment", _numbered(1, "M104 S 400"), "m104 s 400",
    "G1 X1 X 9999",
]


@pytest.mark.parametrize("line", BYPASSES)
def test_a_target_or_move_out_of_limits_in_any_form_the_firmware_takes_is_refused(
        line: str, tmp_path: Path) -> None:
    assert _executes_out_of_limits([line]), "the emulator reads it as the firmware does"
    with pytest.raises(ScriptRefused, match=r"limit|travel"):
        check_script(line + "\n", ENVELOPE)  # hostctl send, printer.gcode
    upload = tmp_path / "part.gcode"
    upload.write_text(f"G28\n{line}\n")
    with pytest.raises(SpoolError, match=r"line 2: .*(limit|travel)"):
        check_file(str(upload), "gcode", "part.gcode", ENVELOPE)  # hostctl print


@pytest.mark.parametrize("line", [
    "M104 S 210", "M140 S60", "M109 R 200", "G1 X 250 Y250 Z10 A-45", "M104S200",
    "M117 M104 S400", "M1040 S999", "G1 X10 ; X9999 in a comment", "M106 S255",
])
def test_lines_within_the_limits_pass(line: str) -> None:
    assert check_script(line + "\n", ENVELOPE)
    assert not _executes_out_of_limits([line])


@pytest.mark.parametrize(("line", "code", "words"), [
    ("M104 S 400", "M104", [("S", 400.0)]),
    ("N12 m104 s+400.*77", "M104", [("S", 400.0)]),
    ("M65640 S400 ; wraps", "M104", [("S", 400.0)]),
    ("G1X5Y-.5E", "G1", [("X", 5.0), ("Y", -0.5), ("E", None)]),
    ("G1 X1E3", "G1", [("X", 1.0), ("E", 3.0)]),  # value_float cuts at E: no exponent
    ("G1 X0x10", "G1", [("X", 16.0), ("X", 10.0)]),  # strtof reads hex; then x10 (any case)
    ("G 28 X Y", "G28", [("X", None), ("Y", None)]),
    ("M117 G1 X9999", "M117", []),  # a message is text
    ("X10 Y10", "", []),  # no G, M or T: no command
    ("M104 \\;S400", "M104", [("S", 400.0)]),  # an escaped ';' starts no comment
])
def test_words_are_read_as_marlins_parser_reads_them(line: str, code: str,
                                                     words: list[tuple[str, float | None]]
                                                     ) -> None:
    from slicer.gcode.markers import marlin_words

    assert marlin_words(line) == (code, words)


# -- the property: whatever the emulator executes out of limits is refused -----------------

VALUES = ["0", "200", "285", "286", "400", "120", "121", "9999", "-5", "90", "91", "170",
          "500", "500.5", "65936", "1e3", "0x190", "0x1.9p8", ".5"]


@st.composite
def hostile_line(draw: st.DrawFn) -> str:
    """A heater or move command in the forms the firmware accepts."""
    letter = draw(st.sampled_from(["M", "m", "G", "g"]))
    number = draw(st.sampled_from(
        ["104", "109", "140", "190", "0", "1", "92", "0104", "65640", "65537", "104.0"]))
    head = letter + draw(st.sampled_from(["", " "])) + number
    words = draw(st.lists(_word(), max_size=3))
    glue = draw(st.sampled_from([" ", "", "  "]))
    line = glue.join([head, *words]) if words else head
    tail = draw(st.sampled_from(["", " ; comment", ";c", "*12", " *", "\t"]))
    prefix = draw(st.sampled_from(["", "N5 ", "  "]))
    return prefix + line + tail


@st.composite
def _word(draw: st.DrawFn) -> str:
    key = draw(st.sampled_from("SRBTXYZACEsxa"))
    space = draw(st.sampled_from(["", " ", "  "]))
    sign = draw(st.sampled_from(["", "+", "-"]))
    value = draw(st.sampled_from(VALUES))
    end = draw(st.sampled_from(["", ".", "-1", '"']))
    quote = '"' if end == '"' else ""
    return f"{key}{space}{quote}{sign}{value}{end}"


def _refused(line: str) -> bool:
    try:
        check_script(line + "\n", ENVELOPE)
    except ScriptRefused:
        return True
    return False


def _board() -> Firmware:
    fw = Firmware(SimSettings())
    fw.receive(encode(frame(0, "M110 N0")))
    fw.settle()
    return fw


def _out_of_limits(fw: Firmware) -> bool:
    m = fw.machine
    if m.hotend.target > HOTEND or m.bed.target > BED:
        return True
    position = m.machine_position()
    for axis, (lo, hi) in ENVELOPE.ranges.items():
        if not lo - TRAVEL_TOL <= position[axis] <= hi + TRAVEL_TOL:
            return True
    return any(math.isnan(v) for v in position.values())


def _executes_out_of_limits(lines: list[str], framed: bool = False) -> bool:
    """Whether the emulator, sent ``lines`` (as hostd frames them, or as they are), ends
    out of the machine's limits."""
    fw = _board()
    for n, line in enumerate(lines, 1):
        fw.receive(encode(frame(n, line)) if framed else (line + "\n").encode("latin-1"))
        fw.settle()
    return _out_of_limits(fw)


@settings(max_examples=800, deadline=None)
@example("M104 S 400")
@example("G1 A 170")
@example("m 0104s+400.;x")
@given(hostile_line())
def test_any_line_the_emulator_would_execute_out_of_limits_is_refused(line: str) -> None:
    """Sent as it is (from another host) or as hostd sends it after its checks (framed, the
    comment and checksum cut), a line that takes the emulator out of the limits is refused
    by the check of raw G-code and uploads."""
    if _refused(line):
        return
    assert not _executes_out_of_limits([line]), line
    assert not _executes_out_of_limits(check_script(line + "\n", ENVELOPE), framed=True), line
