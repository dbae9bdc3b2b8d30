"""The daemon's worker processes (the slicer's, the G-code checker's): spawned, one each, and
gone with the daemon.

A :class:`~concurrent.futures.ProcessPoolExecutor` worker outlives a daemon killed with
SIGKILL: it waits for work on a queue it holds both ends of. Under systemd the unit's control
group is killed with it; anywhere else it would linger, holding the daemon's stderr open. So
each worker starts a thread that waits on its parent's sentinel (a pipe the parent holds
open: no polling) and ends the worker when the parent is gone.
"""

from __future__ import annotations

import asyncio
import multiprocessing
import os
import threading
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any, TypeVar

T = TypeVar("T")


def _exit_with_parent() -> None:
    """Runs in the worker as it starts: end it when the process that spawned it ends."""
    parent = multiprocessing.parent_process()
    if parent is None:  # not a spawned child (never the case in a pool)
        return

    def watch() -> None:
        parent.join()
        os._exit(1)  # nothing to flush: results go back to a parent that is gone

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


def spawn_pool() -> ProcessPoolExecutor:
    """A pool of one spawned worker (sharing nothing with the daemon's threads) that ends with
    the daemon."""
    ctx = multiprocessing.get_context("spawn")
    return ProcessPoolExecutor(max_workers=1, mp_context=ctx, initializer=_exit_with_parent)


class WorkerDied(Exception):
    """The worker process ended while it ran a call (killed, out of memory)."""


class WorkerProcess:
    """One spawned worker, started by the first call and started afresh after it dies."""

    def __init__(self) -> None:
        self._pool: ProcessPoolExecutor | None = None

    @property
    def started(self) -> bool:
        return self._pool is not None

    async def run(self, fn: Callable[..., T], *args: Any) -> T:
        """``fn(*args)`` in the worker (``fn`` importable by name, arguments picklable); its
        exceptions are raised here, :class:`WorkerDied` if the process ended meanwhile."""
        if self._pool is None:
            self._pool = spawn_pool()
        try:
            return await asyncio.get_running_loop().run_in_executor(self._pool, fn, *args)
        except BrokenProcessPool:
            self._pool = None
            raise WorkerDied("the worker process died (out of memory?)") from None

    def kill(self) -> None:
        """End the worker now: a call running in it raises :class:`WorkerDied`, and the next
        call starts a fresh worker."""
        pool = self._pool
        if pool is None:
            return
        procs = getattr(pool, "_processes", None) or {}  # the executor's record of its workers
        for proc in list(procs.values()):
            proc.kill()

    def close(self) -> None:
        """Stop the worker; a call still running is abandoned."""
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None
