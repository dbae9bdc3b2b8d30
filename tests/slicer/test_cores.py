"""How busy other processes kept the machine (:mod:`slicer.cores`): the machine's busy time
less this process's, per second between two readings."""

from __future__ import annotations

import os
import time

import pytest

from slicer import cores
from slicer.cores import Reading, others_busy, reading


@pytest.mark.parametrize(("before", "after", "expected"), [
    (Reading(10.0, 1.0, 100.0), Reading(12.0, 2.5, 103.0), 0.75),  # 3 s busy, 1.5 ours
    (Reading(10.0, 1.0, 100.0), Reading(12.0, 3.0, 101.9), 0.0),  # ours ahead of a tick
    (Reading(10.0, 1.0, None), Reading(12.0, 2.0, 103.0), None),
    (Reading(10.0, 1.0, 100.0), Reading(10.0, 1.0, 100.0), None),
])
def test_others_busy_is_the_machines_busy_time_less_ours_per_second(
        before: Reading, after: Reading, expected: float | None) -> None:
    got = others_busy(before, after)
    assert got == pytest.approx(expected) if expected is not None else got is None


def test_the_machines_busy_time_holds_this_process_own() -> None:
    """A busy loop of 0.3 s: the machine was busy at least as long, to a clock tick."""
    before = reading()
    if before.machine is None:
        pytest.skip("no /proc/stat here")
    end = time.process_time() + 0.3
    while time.process_time() < end:
        pass
    after = reading()
    assert after.machine is not None
    tick = 2.0 / os.sysconf("SC_CLK_TCK")
    assert after.machine - before.machine >= after.own - before.own - tick


def test_an_unreadable_proc_stat_gives_no_machine_figure(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(cores, "PROC_STAT", tmp_path / "missing")
    assert reading().machine is None
    (tmp_path / "garbled").write_text("cpu x y\n")
    monkeypatch.setattr(cores, "PROC_STAT", tmp_path / "garbled")
    assert reading().machine is None
