"""G-code reader: modes, markers and one-line errors naming the line."""

from __future__ import annotations

import numpy as np
import pytest

from slicer.gcode.reader import GcodeFormatError, parse_lines


def test_positions_are_modal_and_feed_is_mm_per_s():
    p = parse_lines(["G90", "M83", "G1 X1 Y2 Z3 A4 C5 F600", "G1 X2 E0.5", "G0 Z9"])
    assert np.allclose(p.end[1], [2, 2, 3, 4, 5])
    assert np.allclose(p.start[2], [2, 2, 3, 4, 5]) and p.end[2, 2] == 9
    assert np.isnan(p.start[0]).all()
    assert p.feed[1] == pytest.approx(10.0) and list(p.g) == [1, 1, 0]
    assert list(p.line) == [3, 4, 5]


def test_absolute_extrusion_is_made_relative():
    p = parse_lines(["M82", "G92 E0", "G1 X1 E1.0", "G1 X2 E1.5", "G92 E0", "G1 X3 E0.25"])
    assert np.allclose(p.e, [1.0, 0.5, 0.25])


def test_homing_makes_the_position_unknown():
    p = parse_lines(["G1 X1 Y1 Z1 A0 C0", "G28", "G1 X5"])
    assert np.isnan(p.start[1]).all() and p.end[1, 0] == 5 and np.isnan(p.end[1, 1])


def test_markers_tag_moves():
    p = parse_lines([';HOSTD_SUBPART {"index": 1, "parent": 0}',
                     ';HOSTD_TRANSITION {"from": 0, "to": 1, "a": 0, "c": 0}',
                     "G0 Z50", ";HOSTD_TRANSITION_END",
                     ';HOSTD_LAYER {"subpart": 1, "index": 0}',
                     ';HOSTD_INTERFACE {"parent": 1, "child": 2}', "G1 X1 E1"])
    assert list(p.subpart) == [1, 1] and list(p.layer) == [-1, 0]
    assert list(p.transition) == [True, False] and list(p.layer_seq) == [-1, 0]
    assert p.transitions[0]["first"] == 0 and p.transitions[0]["last"] == 0
    assert p.parents == {1: 0} and p.interfaces[0]["child"] == 2


@pytest.mark.parametrize(("lines", "where"), [
    (["G1 X1", "G1 Xabc"], "line 2: bad word"),
    (["G91"], "line 1: G91"),
    (["", ';HOSTD_LAYER {"subpart": 1'], "line 2: ;HOSTD_LAYER: bad JSON"),
    ([';HOSTD_LAYER {"index": 1}'], "line 1: ;HOSTD_LAYER: missing or bad key"),
    (["G92 X0"], "line 1: G92"),
])
def test_malformed_lines_name_the_line(lines, where):
    with pytest.raises(GcodeFormatError, match=where):
        parse_lines(lines)
