"""ModalState.apply_many: the batch reading gives the state of applying line by line, bit
for bit, whatever the batches and the commands."""

from __future__ import annotations

import dataclasses

import hypothesis.strategies as st
import pytest
from hypothesis import given, settings

from hostd.printer.modal import ModalState

_NUMBER = st.one_of(
    st.floats(-1e4, 1e4, allow_nan=False).map(lambda v: f"{v:.5f}"),
    st.integers(-999, 999).map(str),
    st.sampled_from(["1.", ".5", "-.25", "+3", "007", "1e3", "-", "1.2.3", "nan"]),
)
_WORD = st.tuples(st.sampled_from("XYZACEFxe"), _NUMBER).map("".join)
_MOVE = st.tuples(st.sampled_from(["G1", "G0", "G01", "g1"]),
                  st.lists(_WORD, max_size=5)).map(lambda m: " ".join([m[0], *m[1]]))
_OTHER = st.sampled_from(["G90", "G91", "M82", "M83", "G92 E0", "G92 X5 E1.5", "G28",
                          "G28 X", "M104 S200", "M140 S60", "M106 S128", "M107",
                          "G1  X1", "G1 X", "M117 hello E5", "G1 X1\nG1 E2"])
_COMMAND = st.one_of(_MOVE, _MOVE, _MOVE, _OTHER)


def _per_line(commands: list[str], start: ModalState) -> ModalState:
    state = start.copy()
    for command in commands:
        state.apply(command)
    return state


@settings(max_examples=300, deadline=None)
@given(st.lists(_COMMAND, max_size=40), st.lists(st.integers(1, 12), max_size=12),
       st.sampled_from([[], ["M83"], ["G91"], ["M83", "G1 E2.5 X3"]]))
def test_batches_give_the_state_of_line_by_line(commands: list[str], cuts: list[int],
                                                 prelude: list[str]) -> None:
    start = _per_line(prelude, ModalState())
    batched = start.copy()
    i = 0
    for size in [*cuts, len(commands)]:
        batched.apply_many(commands[i:i + size])
        i += size
    # repr: a bare axis letter leaves NaN, which == would call different
    assert repr(batched.snapshot()) == repr(_per_line(commands, start).snapshot())


def test_a_batch_of_plain_moves_takes_last_axes_and_sums_relative_e() -> None:
    state = ModalState()
    state.apply("M83")
    state.apply_many(["G1 X1 Y2 E0.5 F1200", "G0 Z3 A-4.5 C90", "G1 X7 E0.25 E0.125",
                      "G1 E-1"])
    assert state.position == {"X": 7.0, "Y": 2.0, "Z": 3.0, "A": -4.5, "C": 90.0,
                              "E": 0.5 + 0.125 - 1.0}
    assert state.feedrate == 1200.0
    assert state.extruded == 0.5 + 0.125 - 1.0


@pytest.mark.timeout(60)  # a regex that backtracks on the digits would never finish
def test_a_long_batch_that_is_not_all_moves_falls_back_at_once() -> None:
    moves = [f"G1 X{123456.78901 + i:.5f} Y-98765.43210 Z1234567 E0.0000123" for i in range(64)]
    batch = [*moves, "M104 S200"]
    state = ModalState()
    state.apply_many(batch)
    assert state.snapshot() == _per_line(batch, ModalState()).snapshot()
    assert state.hotend == 200.0


def test_a_long_file_is_joined_in_parts_with_the_same_state(monkeypatch) -> None:
    from hostd.printer import modal

    monkeypatch.setattr(modal, "JOIN_LINES", 3)
    commands = ["M83", "G1 X1 E0.5", "G1 Y2 E0.25", "G91", "G1 X1 E1", "G90", "M82",
                "G1 Z3 E4", "G1 E5 F900", "M106 S10", "G0 A1 C2"]
    state = ModalState()
    state.apply_many(commands)
    assert repr(state.snapshot()) == repr(_per_line(commands, ModalState()).snapshot())


@settings(max_examples=60, deadline=None)
@given(st.lists(_COMMAND, max_size=40))
def test_the_snapshot_is_a_plain_copy_of_every_field(commands: list[str]) -> None:
    """The snapshot the job's progress is written with is ``dataclasses.asdict``'s result,
    owns its position (a later move leaves it as it was) and rebuilds the same state."""
    state = _per_line(commands, ModalState())
    snap = state.snapshot()
    assert snap == dataclasses.asdict(state)
    assert ModalState.from_dict(snap) == state
    before = dict(snap["position"])
    state.apply("G1 X123.5 Y-4 Z7 A9 C11 E3")
    assert snap["position"] == before
