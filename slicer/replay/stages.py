"""The replay check's stages: run in order, or on a small thread pool as their inputs allow.

The model's queries (mesh index, wall distance, inside test) and the deposits' (support,
collisions) need nothing of each other, and their heavy parts (numpy array loops, scipy's
KD-tree searches) release the GIL, so two threads keep both cores busy.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from types import TracebackType
from typing import Any, TypeVar

T = TypeVar("T")


class Stages:
    """Runs named stages and records their wall and CPU seconds.

    With ``threads`` ≥ 2, :meth:`submit` queues a stage on a pool of that many threads;
    queued stages start in the order they were submitted, so a stage that waits for the
    result of one submitted before it never waits for one that has not started. A stage's
    CPU is then its own thread's (scipy's query workers not included). With one thread
    every stage runs at once where it is submitted, and its CPU is the process's. Use as a
    context manager: leaving it waits for every stage.
    """

    def __init__(self, threads: int = 2) -> None:
        self.wall: dict[str, float] = {}
        self.cpu: dict[str, float] = {}
        self._pool = ThreadPoolExecutor(threads, "replay") if threads > 1 else None
        self._cpu_clock = time.thread_time if threads > 1 else time.process_time

    def _run(self, name: str, fn: Callable[[], T], after: tuple[Future[Any], ...]) -> T:
        for f in after:
            f.result()
        wall, cpu = time.perf_counter(), self._cpu_clock()
        try:
            return fn()
        finally:
            self.wall[name] = time.perf_counter() - wall
            self.cpu[name] = self._cpu_clock() - cpu

    def submit(self, name: str, fn: Callable[[], T], *after: Future[Any]) -> Future[T]:
        """Queue ``fn`` (or run it now with one thread), timed as ``name`` from when the
        stages ``after`` (whose results it reads) are done."""
        if self._pool is not None:
            return self._pool.submit(self._run, name, fn, after)
        done: Future[T] = Future()
        try:
            done.set_result(self._run(name, fn, after))
        except Exception as exc:  # handed over as a thread's would be, by result()
            done.set_exception(exc)
        return done

    def __enter__(self) -> Stages:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
