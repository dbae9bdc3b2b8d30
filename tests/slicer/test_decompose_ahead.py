"""A decomposition's attempts shared with a spawned worker (:mod:`slicer.decompose.ahead`):
the outcomes in order whoever computed them, the worker gone when the reader stops, a dead
worker's attempts computed here, no worker where it cannot pay; and a decomposition the
same with the worker as without it."""

from __future__ import annotations

import multiprocessing
import os
import pickle
import select
import signal
import subprocess
import sys
import textwrap
from collections.abc import Callable, Generator
from concurrent.futures import Executor, Future, ProcessPoolExecutor
from pathlib import Path

import pytest
import trimesh
from ahead_tasks import die, square, square_then_hang
from process_checks import gone_within

import slicer.decompose.ahead as ahead
import slicer.decompose.decomposition as decomposition
from kinematics.machine import MachineGeometry
from slicer.decompose import DecomposeSettings, RootRegionError, decompose
from slicer.mesh.hard_samples import hard_variant
from slicer.printhead import Printhead

HEAD, MACHINE = Printhead.default(), MachineGeometry()
Task = Callable[[int], tuple[int, int]]


class Pools:
    """Starts spawned pools of one worker for :func:`ahead.in_order` and keeps them."""

    def __init__(self) -> None:
        self.pools: list[ProcessPoolExecutor] = []
        self.workers: list[multiprocessing.process.BaseProcess] = []

    def start(self) -> Executor:
        pool = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"))
        self.pools.append(pool)
        return pool

    def there(self, task: Task) -> Callable[[Executor, int], Future[tuple[int, int]]]:
        def submit(pool: Executor, i: int) -> Future[tuple[int, int]]:
            fut = pool.submit(task, i)
            self.workers += list(pool._processes.values())  # type: ignore[attr-defined]
            return fut
        return submit


@pytest.fixture
def eager(monkeypatch: pytest.MonkeyPatch) -> None:
    """A worker for any attempt after the first, on any machine."""
    monkeypatch.setattr(ahead, "AHEAD_AFTER", 0.0)
    monkeypatch.setattr(ahead, "core_to_spare", lambda others: True)


def _run(count: int, pools: Pools, task: Task, here: Task = square
         ) -> Generator[tuple[int, int], None, None]:
    return ahead.in_order(count, here, pools.start, pools.there(task))


@pytest.mark.timeout(120)
def test_the_outcomes_come_in_order_the_later_ones_partly_from_the_worker(eager: None
                                                                            ) -> None:
    pools = Pools()
    got = list(_run(7, pools, square))
    assert [v for v, _ in got] == [i * i for i in range(7)]
    assert got[0][1] == os.getpid()  # the first attempt is always computed here
    assert got[1][1] != os.getpid()  # the worker is given the next two at once
    assert len(pools.pools) == 1
    assert pools.workers and not any(w.is_alive() for w in pools.workers)


@pytest.mark.timeout(120)
def test_a_reader_that_stops_early_has_the_worker_killed(eager: None) -> None:
    """The worker is busy with attempt 2 forever: the reader takes 0 and 1 and stops."""
    pools = Pools()
    outcomes = _run(6, pools, square_then_hang)
    assert [next(outcomes)[0], next(outcomes)[0]] == [0, 1]
    assert any(w.is_alive() for w in pools.workers)
    outcomes.close()
    assert pools.workers and not any(w.is_alive() for w in pools.workers)


@pytest.mark.timeout(120)
def test_an_error_here_ends_the_outcomes_and_the_worker(eager: None) -> None:
    def failing(i: int) -> tuple[int, int]:
        if i == 3:
            raise ValueError("attempt 3 failed")
        return square(i)

    pools = Pools()
    with pytest.raises(ValueError, match="attempt 3"):
        list(_run(6, pools, square_then_hang, failing))
    assert pools.workers and not any(w.is_alive() for w in pools.workers)


@pytest.mark.timeout(120)
def test_a_dead_workers_attempts_are_computed_here(eager: None) -> None:
    pools = Pools()
    got = list(_run(5, pools, die))
    assert got == [(i * i, os.getpid()) for i in range(5)]
    assert len(pools.pools) == 1  # no second worker after the first one died


@pytest.mark.parametrize("why", ["the first attempt was quick", "no core is free"])
def test_no_worker_is_started_where_it_cannot_pay(why: str,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    if why == "no core is free":
        monkeypatch.setattr(ahead, "AHEAD_AFTER", 0.0)
        monkeypatch.setattr(ahead, "core_to_spare", lambda others: False)
    else:
        monkeypatch.setattr(ahead, "AHEAD_AFTER", 3600.0)
        monkeypatch.setattr(ahead, "core_to_spare", lambda others: True)
    pools = Pools()
    assert list(_run(5, pools, square)) == [(i * i, os.getpid()) for i in range(5)]
    assert pools.pools == []


def test_a_bad_root_raised_in_a_worker_reaches_the_caller_whole() -> None:
    err = pickle.loads(pickle.dumps(RootRegionError(7, 4)))
    assert isinstance(err, RootRegionError) and (err.root, err.regions) == (7, 4)
    assert "0..3" in str(err)


@pytest.fixture(scope="module")
def ball() -> trimesh.Trimesh:
    """ball31 of the sweep: every usual attempt and its three-way cut, then the finer
    retry (:func:`~slicer.decompose.decomposition.attempt_plan`)."""
    return hard_variant(31).mesh()


def _decomposed(mesh: trimesh.Trimesh, monkeypatch: pytest.MonkeyPatch, after: float
                ) -> tuple[decomposition.Decomposition, int]:
    """``mesh`` decomposed with attempts shared after ``after`` s; and workers started."""
    started: list[ProcessPoolExecutor] = []
    spawn = decomposition._spawn

    def spawned(job: decomposition._Job) -> ProcessPoolExecutor:
        started.append(spawn(job))
        return started[-1]

    with monkeypatch.context() as patch:
        patch.setattr(ahead, "AHEAD_AFTER", after)
        patch.setattr(ahead, "core_to_spare", lambda others: True)
        patch.setattr(decomposition, "_spawn", spawned)
        dec = decompose(mesh, DecomposeSettings(), MACHINE, HEAD)
    return dec, len(started)


@pytest.mark.timeout(240)
def test_a_decomposition_is_the_same_with_a_worker_as_without(
        ball: trimesh.Trimesh, monkeypatch: pytest.MonkeyPatch) -> None:
    alone, none = _decomposed(ball, monkeypatch, 3600.0)
    shared, one = _decomposed(ball, monkeypatch, 0.0)
    assert (none, one) == (0, 1)
    assert len(alone.attempts) > 3  # attempts after the first were shared
    assert shared.attempts == alone.attempts
    assert (shared.seed, shared.k) == (alone.seed, alone.k)
    assert shared.signature() == alone.signature()
    assert [d.signature() for d in shared.runners_up] == \
        [d.signature() for d in alone.runners_up]
    assert [o.area for o in shared.overhang] == [o.area for o in alone.overhang]


@pytest.mark.parametrize(("cores", "others", "spare"),
                         [(2, 0.2, True), (2, 0.6, False), (4, 2.0, True), (4, 2.8, False),
                          (1, 0.0, False)])
def test_a_worker_is_started_only_where_other_processes_left_a_core(
        cores: int, others: float, spare: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(ahead.os, "cpu_count", lambda: cores)
    assert ahead.core_to_spare(others) is spare


@pytest.mark.parametrize("free", [1, 2])
def test_without_the_machines_figures_the_load_average_decides(
        free: int, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(ahead, "free_cores", lambda: free)
    assert ahead.core_to_spare(None) is (free >= 2)


def test_a_worker_that_cannot_be_started_leaves_every_attempt_here(eager: None) -> None:
    def start() -> Executor:
        raise OSError(11, "Resource temporarily unavailable")  # fork/spawn refused

    def there(pool: Executor, i: int) -> Future[tuple[int, int]]:
        raise AssertionError("no pool, nothing submitted")

    got = list(ahead.in_order(4, square, start, there))
    assert got == [(i * i, os.getpid()) for i in range(4)]


SLICER = textwrap.dedent("""
    import os, sys
    import trimesh
    from kinematics.machine import MachineGeometry
    from slicer.decompose import DecomposeSettings
    from slicer.decompose import decomposition as d
    from slicer.printhead import Printhead

    box = trimesh.creation.box((10.0, 10.0, 10.0))
    pool = d._spawn(d._Job(box, box, DecomposeSettings(), MachineGeometry(),
                           Printhead.default()))
    print(pool.submit(os.getpid).result(), flush=True)
    sys.stdin.read()  # until killed
""")


@pytest.mark.skipif(not hasattr(os, "pidfd_open"), reason="Linux pidfds")
@pytest.mark.timeout(120)
def test_the_worker_dies_with_a_killed_slicer() -> None:
    root = Path(__file__).resolve().parents[2]
    proc = subprocess.Popen([sys.executable, "-c", SLICER], cwd=root, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        assert select.select([proc.stdout], [], [], 90.0)[0], "the worker never answered"
        worker = int(proc.stdout.readline())
        assert worker != proc.pid
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    assert gone_within(worker, 20.0)
