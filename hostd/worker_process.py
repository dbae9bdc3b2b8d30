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

from slicer.cores import kill_workers

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
        pool = self._pool
        try:
            return await asyncio.get_running_loop().run_in_executor(pool, fn, *args)
        except BrokenProcessPool:
            if self._pool is pool:
                self._pool = None
            raise WorkerDied("the worker process died (out of memory?)") from None
        except asyncio.CancelledError:
            task = asyncio.current_task()
            if task is not None and task.cancelling():
                raise  # this task was cancelled, not the call
            raise WorkerDied("the worker was closed before the call ran") from None

    def kill(self) -> None:
        """End the worker now: a call running in it raises :class:`WorkerDied`, and the next
        call starts a fresh worker."""
        if self._pool is not None:
            kill_workers(self._pool)

    def close(self) -> None:
        """End the worker now; a call still running is abandoned (its future fails).

        The worker is killed before the pool is shut down and waited for. A pool shut down
        without waiting would leave its manager thread waiting on the running call, and the
        interpreter joins that thread at exit: the daemon would outlive its SIGTERM by the
        rest of a slice."""
        pool, self._pool = self._pool, None
        if pool is None:
            return
        kill_workers(pool)
        pool.shutdown(wait=True, cancel_futures=True)
