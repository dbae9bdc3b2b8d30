"""The one module of the ``;HOSTD_`` markers and a command's words: what the writer makes,
both readers find, and the daemon imports without numpy."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from slicer.gcode.markers import (
    HEADERS,
    LAYER,
    PREFIX,
    TRANSITION,
    TRANSITION_END,
    LayerPayload,
    PayloadError,
    TransitionPayload,
    marker_line,
    parse_marker,
    parse_payload,
    split_words,
)

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("module", ["slicer.gcode.markers", "hostd.printer.program",
                                    "hostd.sim.machine"])
def test_the_markers_load_no_numpy(module: str) -> None:
    """The daemon's program reader and the emulator import the markers; the daemon never
    loads numpy, so neither may the package they come from."""
    code = f"import sys, {module}; print(sorted(m for m in sys.modules if m == 'numpy'))"
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                          text=True, check=True)
    assert done.stdout.strip() == "[]"


def test_a_marker_line_reads_back_as_written() -> None:
    line = marker_line(LAYER, LayerPayload(subpart=1, index=7))
    assert line == ';HOSTD_LAYER {"subpart": 1, "index": 7}'
    assert parse_marker(line) == (LAYER, '{"subpart": 1, "index": 7}')
    assert parse_payload(parse_marker(line)[1]) == {"subpart": 1, "index": 7}
    assert marker_line(TRANSITION_END) == ";HOSTD_TRANSITION_END"
    assert parse_marker(";HOSTD_TRANSITION_END") == (TRANSITION_END, "")
    record: TransitionPayload = {"from": None, "to": 1, "a": 30.0, "c": -90.0, "x": 1.0,
                                 "y": 2.0, "z": 3.0, "safe_z": 60.0}
    assert parse_payload(parse_marker(marker_line(TRANSITION, record))[1]) == record
    assert all(parse_marker(marker_line(name, {}))[0] == name for name in HEADERS)


@pytest.mark.parametrize("line", ["; a comment", "G1 X1", ";HOSTD_", ";HOSTD_layer {}",
                                  ";hostd_LAYER {}", ""])
def test_other_lines_are_no_markers(line: str) -> None:
    assert parse_marker(line) is None


@pytest.mark.parametrize(("text", "reason", "message"), [
    ('{"index": 1', "bad JSON", "bad JSON: Expecting ',' delimiter"),
    ("[1, 2]", "expected a JSON object", "expected a JSON object"),
])
def test_a_payload_that_is_no_json_object_is_refused(text: str, reason: str,
                                                     message: str) -> None:
    with pytest.raises(PayloadError) as err:
        parse_payload(text)
    assert err.value.reason == reason
    assert str(err.value) == message
    assert parse_payload("") == {}


def test_words_are_split_as_written() -> None:
    assert split_words("G1 X1 y-2.5\tE") == ("G1", [("X", "1"), ("y", "-2.5"), ("E", "")])
    assert split_words("  ") == ("", [])
    assert split_words("M117 hello") == ("M117", [("h", "ello")])
    assert PREFIX == ";HOSTD_"
