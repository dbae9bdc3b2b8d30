"""The slicer's share of the machine's cores: how many are free for its worker threads and
processes, and worker processes that end with it.

A worker waiting for work on a pool's queue would outlive a slicer killed for its memory, or
with its daemon. :func:`die_with_parent`, run as a pool's initializer, asks the kernel to kill
the worker when the process (on Linux: the thread) that started it ends.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal

PR_SET_PDEATHSIG = 1  # prctl(2): a signal for this process when its parent dies


def free_cores() -> int:
    """Cores not busy with other work, counting the one the caller runs on as free: the
    cores less the 1-min load average beyond this process's own, rounded (at least 1). On a
    busy machine two threads or processes only fight over one core."""
    cores = os.cpu_count() or 1
    busy = max(0.0, os.getloadavg()[0] - 1.0) if hasattr(os, "getloadavg") else 0.0
    return max(1, int(cores - busy + 0.5))


def die_with_parent(parent: int) -> None:
    """Worker initializer: on Linux the kernel kills this worker when the process that
    started it dies (a slicer killed for memory, or with its daemon, leaves no orphans
    waiting for work forever). ``parent`` is that process's pid, from before the start."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != parent:  # it died before the request took effect
        os._exit(1)
