"""A decomposition's attempts shared with a spawned worker process, read in their order.

:func:`~slicer.decompose.decompose` tries (seed, K) attempts one after the other until one
is good enough, up to a dozen on a part with shallow branches (pipe3_15 of the hard set at
50 000 faces: eleven, 1.5 s each). Each is independent of the others, so :func:`in_order`
has a worker process compute the next one while this process computes the current one, and
hands the outcomes back strictly in order: the caller sees what a plain loop would, and stops
where it would (the work done past that point is dropped, the worker killed).

The worker is *spawned*, not forked: manifold3d runs on TBB threads, and a forked child of
a process that has used them can hang on a lock a thread it does not have held. A spawned
worker imports the slicer afresh (about a second of one core), so it is started only once
the first attempt has taken :data:`AHEAD_AFTER` seconds and failed to satisfy: a part the
first attempt decomposes never pays for it. Nor does a machine whose other processes kept
its cores busy during that first attempt (:func:`core_to_spare`, by ``/proc/stat``: the load
average would still count the slice run just before). A worker that dies (out of memory)
leaves its attempt to this process, and no attempt goes to it after.
"""

from __future__ import annotations

import logging
import os
from collections import deque
from collections.abc import Callable, Generator
from concurrent.futures import Executor, Future
from concurrent.futures.process import BrokenProcessPool
from typing import Generic, TypeVar

from slicer.cores import free_cores, kill_workers, others_busy, reading

R = TypeVar("R")
log = logging.getLogger(__name__)

AHEAD_AFTER = 0.5
"""Seconds the first attempt must take before the later ones are shared with a worker
(a spawned worker costs about a second of the other core to start)."""

SPARE = 1.5
"""Cores the machine must have beyond what other processes kept busy during the first
attempt for a worker to be started: this process's one and half of another (a slice's
attempt keeps about 1.3 cores busy itself, manifold3d's threads included)."""

QUEUED = 2
"""Attempts the worker holds at a time: one it computes, one it starts on next while this
process is busy with its own."""


def core_to_spare(others: float | None) -> bool:
    """Whether a worker would have a core: the machine's cores less ``others`` (the cores
    other processes kept busy during the first attempt, :func:`~slicer.cores.others_busy`)
    reach :data:`SPARE`; where ``others`` is unknown, two cores free by the load average
    (:func:`~slicer.cores.free_cores`). A machine busy with other work (a test suite on
    both cores) gains nothing from a worker but its start-up."""
    if others is None:
        return free_cores() >= 2
    return (os.cpu_count() or 1) - others >= SPARE


def in_order(count: int, here: Callable[[int], R], start: Callable[[], Executor],
             there: Callable[[Executor, int], Future[R]]) -> Generator[R, None, None]:
    """``here(i)`` for ``i`` = 0 .. ``count`` - 1, in order; after the first, each attempt
    not yet claimed may go to a worker instead (``there(pool, i)``, the same outcome).

    Parameters
    ----------
    count : int
        Number of attempts.
    here : callable
        ``here(i)``: attempt ``i`` in this process; outcomes are values (an error the
        caller handles is returned, not raised: a raised one ends the iteration).
    start : callable
        A pool of one worker process, started when the first attempt took
        :data:`AHEAD_AFTER` seconds and a core was free meanwhile (:func:`core_to_spare`);
        shut down (its worker killed) when the iteration ends or is dropped.
    there : callable
        ``there(pool, i)``: attempt ``i`` submitted to the pool.
    """
    ahead = _Ahead(count, here, start, there)
    try:
        for i in range(count):
            yield ahead.outcome(i)
    finally:
        ahead.close()


class _Ahead(Generic[R]):
    """The state of :func:`in_order`: every attempt below ``claimed`` is either ``done``
    (its outcome kept until read) or ``queued`` in the worker, which holds up to
    :data:`QUEUED` (one to compute while this process computes, one to start on next)."""

    def __init__(self, count: int, here: Callable[[int], R], start: Callable[[], Executor],
                 there: Callable[[Executor, int], Future[R]]) -> None:
        self.count, self.here, self.start, self.there = count, here, start, there
        self.claimed = 0
        self.done: dict[int, R] = {}
        self.queued: deque[tuple[int, Future[R]]] = deque()
        self.pool: Executor | None = None
        self.first = 0.0  # seconds of attempt 0
        self.others: float | None = None  # cores other processes kept busy meanwhile
        self.broken = False

    def outcome(self, i: int) -> R:
        """Attempt ``i``'s outcome, computing later ones here while the worker has it."""
        while i not in self.done:
            self._feed()
            self._collect(block=False)
            if i in self.done:
                break
            if i == self.claimed or self.claimed < self.count:
                self._here_next()  # i itself, or one after it while the worker has i
            else:
                self._collect(block=True)
        return self.done.pop(i)

    def _feed(self) -> None:
        """Give the worker the next attempts not claimed yet, up to :data:`QUEUED`."""
        while len(self.queued) < QUEUED and 0 < self.claimed < self.count:
            pool = self._pool()
            if pool is None:
                return
            try:
                self.queued.append((self.claimed, self.there(pool, self.claimed)))
            except (OSError, BrokenProcessPool):
                self.broken = True
                return
            self.claimed += 1

    def _pool(self) -> Executor | None:
        if self.pool is None and not self.broken and self.first >= AHEAD_AFTER \
                and core_to_spare(self.others):
            try:
                self.pool = self.start()
            except (OSError, BrokenProcessPool) as exc:  # no process: all done here
                self.broken = True
                log.debug("no worker process for the attempts: %s", exc)
            else:
                log.debug("attempts %d to %d shared with a worker process (first took "
                          "%.2f s)", self.claimed, self.count - 1, self.first)
        return None if self.broken else self.pool

    def _collect(self, block: bool) -> None:
        """The worker's finished outcomes into ``done``, in its order (with ``block``, at
        least one); a dead worker's attempts are computed here."""
        while self.queued and (block or self.queued[0][1].done()):
            block = False
            j, fut = self.queued.popleft()
            try:
                self.done[j] = fut.result()
            except BrokenProcessPool:
                self.broken = True
                self.done[j] = self.here(j)

    def _here_next(self) -> None:
        j = self.claimed
        self.claimed += 1
        if j > 0:
            self.done[j] = self.here(j)
            return
        before = reading()
        self.done[j] = self.here(j)
        after = reading()
        self.first, self.others = after.wall - before.wall, others_busy(before, after)

    def close(self) -> None:
        """Kill the worker (an attempt it runs is not needed) and shut its pool down."""
        if self.pool is None:
            return
        kill_workers(self.pool)
        self.pool.shutdown(wait=True, cancel_futures=True)
