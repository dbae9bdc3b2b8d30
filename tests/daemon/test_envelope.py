"""A G-code file fits the printer: its moves within the travel (machine coordinates, through
G90/G91, G92 and G28), and a sliced file's kinematics those of this printer's config."""

from __future__ import annotations

import json

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hostd.config.loader import defaults
from hostd.printer.envelope import _Travel, envelope_from_config, travel_extents
from hostd.printer.errors import ProgramError
from hostd.printer.program import parse_program

ENVELOPE = envelope_from_config(defaults().data)
number = st.floats(-1000, 1000, allow_nan=False).map(lambda v: round(v, 3))
axes = st.sets(st.sampled_from("XYZAC"), min_size=1)


@st.composite
def command(draw: st.DrawFn) -> str:
    kind = draw(st.sampled_from(["G1", "G1", "G1", "G0", "G90", "G91", "G92", "G28", "M104",
                                 "g1", "G01", "M206", "G92 E0", "G1 X", "G1 X1e2 Y-.5"]))
    if kind in ("G0", "G1", "G92", "g1", "G01", "M206"):
        words = [f"{a}{draw(number):g}" for a in sorted(draw(axes))]
        if kind in ("G0", "G1") and draw(st.booleans()):
            words.append("E0.05 F1800")
        if kind == "g1":
            words = [w.lower() for w in words]
        return " ".join([kind, *words])
    if kind == "G28":
        return " ".join(["G28", *sorted(draw(st.sets(st.sampled_from("XYZ"))))])
    return "M104 S200" if kind == "M104" else kind


def one_by_one(commands: list[str]) -> dict[str, tuple[float, float]]:
    travel = _Travel()
    for c in commands:
        travel.one(c)
    return {axis: (travel.low[axis], travel.high[axis]) for axis in travel.low}


@settings(max_examples=400, deadline=None)
@given(commands=st.lists(command(), max_size=60), block=st.integers(1, 8))
def test_blocks_read_at_once_reach_what_each_command_reaches(commands, block):
    assert travel_extents(commands, block) == one_by_one(commands)


@pytest.mark.parametrize(("lines", "x"), [
    (["G1 X10", "G92 X0", "G1 X5"], (10.0, 15.0)),  # a G92 offset: machine X 10 + 5
    (["G1 X10", "G91", "G1 X5", "G1 X5", "G90", "G1 X2"], (2.0, 20.0)),
    (["G28", "G91", "G1 X5", "G90", "G1 X3"], (3.0, 3.0)),  # relative from home: unknown
    (["G92 X50", "G1 X60"], None),  # a G92 before any known place: machine X unknown
    (["G1 X10", "G28 Y", "G91", "G1 X5"], (10.0, 15.0)),  # G28 Y leaves X known
])
def test_machine_coordinates_through_modes_offsets_and_homing(lines, x):
    assert travel_extents(lines).get("X") == x


def test_a_move_past_the_travel_names_its_line_axis_value_and_key():
    text = "G28\nG90\n; a comment\nG1 X10 Y10 Z5\nG91\nG1 Z400\nG1 Z400\n"
    with pytest.raises(ProgramError) as err:
        ENVELOPE.check(parse_program(text))
    assert str(err.value) == ("line 7: Z 805 is outside the machine's travel [0, 700] "
                              "(machine.z_range)")
    with pytest.raises(ProgramError, match=r"line 2: A -95 .* \[-90, 90\] \(machine.a_limits\)"):
        ENVELOPE.check(parse_program("G28\nG0 A-95\n"))
    ENVELOPE.check(parse_program("G28\nG0 C7200 A90\nG1 X500 Y0 Z700\n"))  # C continuous


def _header(**changes: object) -> str:
    kin = {**ENVELOPE.kinematics, "type": "xyzac-trt", **changes}
    return f";HOSTD_KINEMATICS {json.dumps(kin)}\nG28\nG1 X100 Y100 Z10\n"


def test_a_file_sliced_for_this_printer_fits():
    ENVELOPE.check(parse_program(_header()))


@pytest.mark.parametrize(("key", "value", "config_key"), [
    ("table_origin", [250.0, 250.0, 120.0], "machine.table_origin"),
    ("a_pivot", [250.0, 250.0, 80.5], "machine.a_pivot"),
    ("a_limits", [-60.0, 60.0], "machine.a_limits"),
    ("c_limits", [-180.0, 180.0], "machine.c_limits"),
    ("platform_radius", 100.0, "machine.platform_radius"),
    ("printhead", [[0.0, 12.0, 0.5, 7.43]], "printhead.segments"),
])
def test_a_file_sliced_for_another_machine_is_refused_naming_the_key(key, value, config_key):
    with pytest.raises(ProgramError) as err:
        ENVELOPE.check(parse_program(_header(**{key: value})))
    assert str(err.value).startswith(f"sliced for another machine: {key} ")
    assert f"({config_key})" in str(err.value)


@pytest.mark.parametrize(("text", "message"), [
    ("G28\nM104 S9999\n", "line 2: M104 S9999 is above the hotend's limit 285 °C "
                          "(machine.max_hotend_temp)"),
    ("G28\nM140 S60\nG1 X1\nM190 R121\n", "line 4: M190 R121 is above the bed's limit 120 °C "
                                          "(machine.max_bed_temp)"),
    ("; start\nM109 S286 ; too hot\n", "line 2: M109 S286 is above the hotend's limit"),
    ("G28\nM104 S-10\n", "line 2: M104 S-10: a negative temperature"),
])
def test_a_heater_target_above_the_printers_limit_is_refused(text: str, message: str):
    with pytest.raises(ProgramError) as err:
        ENVELOPE.check(parse_program(text))
    assert message in str(err.value)


def test_targets_at_the_limits_and_other_m_codes_pass():
    ENVELOPE.check(parse_program("M104 S285\nM109 R285\nM140 S120\nM190 S0\nM106 S255\n"
                                 "M1040 S9999\nM117 M104 S9999\n"))


def test_a_target_far_into_a_long_file_names_its_line():
    lines = ["G28", "G90"] + ["G1 X10 Y10 E0.1"] * 9000 + ["M104 S300"]
    with pytest.raises(ProgramError) as err:
        ENVELOPE.check(parse_program("\n".join(lines) + "\n"))
    assert str(err.value).startswith("line 9003: M104 S300")
