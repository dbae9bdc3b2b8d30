"""The ETA: the slicer's estimate, corrected by the rate measured since the job's first layer
began (the start script's heat-up is not slow printing)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hostd.events import EventBus
from hostd.jobs import progress as manager_module
from hostd.jobs.active import Active
from hostd.jobs.figures import eta
from hostd.jobs.manager import JobManager
from hostd.jobs.spool import Spool
from hostd.jobs.store import JobStore
from hostd.printer.program import parse_program
from hostd.printer.streamer import Streamer, StreamSettings

shares = st.floats(0.0, 0.9)
estimates = st.floats(10.0, 1e6)
slowness = st.floats(0.2, 5.0)  # measured time over the estimate's


@given(estimate=estimates, start=shares, done=st.floats(0.02, 1.0), k=slowness)
def test_a_steady_rate_predicts_the_rest_at_that_rate(estimate, start, done, k):
    ratio = start + (1 - start) * done
    if ratio >= 1.0 or ratio - start <= 0.01:
        return  # until 1 % more is done the estimate stands (below)
    elapsed = k * estimate * (ratio - start)  # k times as long as estimated so far
    assert eta(estimate, ratio, elapsed, start) == pytest.approx(k * estimate * (1 - ratio))


@given(estimate=estimates, start=shares, early=st.floats(0.0, 0.0099), elapsed=st.floats(0, 1e5))
def test_before_any_measure_the_estimate_stands(estimate, start, early, elapsed):
    ratio = start + early
    assert eta(estimate, ratio, elapsed, start) == pytest.approx(estimate * (1 - ratio))


@given(start=shares, done=st.floats(0.02, 1.0), elapsed=st.floats(1.0, 1e5))
def test_without_an_estimate_the_measured_rate_alone(start, done, elapsed):
    ratio = start + (1 - start) * done
    if ratio >= 1.0 or ratio - start <= 0.01:
        return
    rate = (ratio - start) / elapsed
    assert eta(None, ratio, elapsed, start) == pytest.approx((1 - ratio) / rate)
    assert eta(None, start + 0.005, elapsed, start) is None  # too little done to tell
    assert eta(0.0, ratio, elapsed, start) == pytest.approx((1 - ratio) / rate)


@given(estimate=st.one_of(st.none(), estimates), elapsed=st.floats(0, 1e5), start=shares)
def test_a_finished_job_has_nothing_left(estimate, elapsed, start):
    assert eta(estimate, 1.0, elapsed, start) == 0.0


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def monotonic(self) -> float:
        return self.now


HEATED = ('G28\nM190 S60\nM109 S210\n;HOSTD_ESTIMATE {"time_s": 100.0}\n'
          ';HOSTD_SUBPART {"index": 0, "parent": null}\n'
          ';HOSTD_LAYER {"subpart": 0, "index": 0}\n'
          + "".join(f"G1 X{i} Y1 Z0.2 E{i} F1200\n" for i in range(97)))


@pytest.mark.asyncio
@pytest.mark.timeout(30)
async def test_the_heat_up_before_the_first_layer_does_not_count_as_slow_printing(
        tmp_path, monkeypatch):
    clock = Clock()
    monkeypatch.setattr(manager_module, "time", clock)
    store = JobStore(tmp_path / "jobs.db")
    mgr = JobManager(store, Spool(tmp_path / "spool", 1 << 20), None, lambda: None,
                     EventBus(), StreamSettings())
    program = parse_program(HEATED)
    st = Streamer(None, program, StreamSettings())  # type: ignore[arg-type]
    mgr.active = act = Active(store.add("p.gcode", "gcode", "0" * 64), program, st, clock.now)
    first = program.layers[0].index

    def acked(n: int, at: float) -> float | None:
        clock.now = 1000.0 + at
        st.acked = n
        if n > first:
            st.subpart, st.layer = 0, 0
        mgr._on_progress(st)
        return mgr._progress(act, clock.now)["eta_s"]

    assert acked(1, 1.0) == pytest.approx(100.0 * (1 - 1 / program.total))  # the estimate
    acked(first, 240.0)  # four minutes of heat-up end as the first layer's first line goes
    acked(first + 1, 240.5)
    half = first + 1 + (program.total - first - 1) // 2
    left = acked(half, 240.5 + 0.5 * 97 / 100 * 100.0)  # printing exactly at the estimate
    assert left == pytest.approx(100.0 * (1 - half / program.total), rel=0.05)
    later = half + 25
    slow = acked(later, 240.5 + 48.5 + 2 * 25.0)  # the next quarter twice as slow
    rate = (later - first - 1) / (48.5 + 50.0)  # lines a second since the first layer began
    assert slow == pytest.approx((program.total - later) / rate, rel=0.01)
    assert slow > 1.3 * 100.0 * (1 - later / program.total)  # slower than the estimate says
    await mgr.stop()
    store.close()
