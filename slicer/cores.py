"""The slicer's share of the machine's cores: how many are free for its worker threads and
processes, how busy other processes kept them meanwhile, and worker processes that end
with it.

A worker waiting for work on a pool's queue would outlive a slicer killed for its memory, or
with its daemon. :func:`die_with_parent`, run as a pool's initializer, asks the kernel to kill
the worker when the process (on Linux: the thread) that started it ends.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import time
from concurrent.futures import Executor
from dataclasses import dataclass
from pathlib import Path

PR_SET_PDEATHSIG = 1  # prctl(2): a signal for this process when its parent dies
PROC_STAT = Path("/proc/stat")


def free_cores() -> int:
    """Cores not busy with other work, counting the one the caller runs on as free: the
    cores less the 1-min load average beyond this process's own, rounded (at least 1). On a
    busy machine two threads or processes only fight over one core."""
    cores = os.cpu_count() or 1
    busy = max(0.0, os.getloadavg()[0] - 1.0) if hasattr(os, "getloadavg") else 0.0
    return max(1, int(cores - busy + 0.5))


@dataclass(frozen=True)
class Reading:
    """The clock, the CPU seconds of this process (all its threads) and of the whole
    machine (every core's busy time, steal included; None where ``/proc/stat`` is not
    readable)."""

    wall: float
    own: float
    machine: float | None


def reading() -> Reading:
    """The CPU seconds now (:class:`Reading`)."""
    return Reading(time.monotonic(), time.process_time(), _machine_busy())


def others_busy(before: Reading, after: Reading) -> float | None:
    """Cores other processes kept busy on average between two readings: the machine's busy
    time less this process's, over the time between; None where the machine's is unknown
    or no time passed."""
    wall = after.wall - before.wall
    if before.machine is None or after.machine is None or wall <= 0.0:
        return None
    theirs = (after.machine - before.machine) - (after.own - before.own)
    return max(0.0, theirs / wall)


def _machine_busy() -> float | None:
    """Seconds every core has been busy since boot: ``/proc/stat``'s first line, all but
    idle and iowait (user, nice, system, irq, softirq, steal; guest is within user)."""
    try:
        fields = PROC_STAT.read_text().split("\n", 1)[0].split()
        ticks = [int(v) for v in fields[1:9]]
        return (sum(ticks) - ticks[3] - ticks[4]) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


def die_with_parent(parent: int) -> None:
    """Worker initializer: on Linux the kernel kills this worker when the process that
    started it dies (a slicer killed for memory, or with its daemon, leaves no orphans
    waiting for work forever). ``parent`` is that process's pid, from before the start."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != parent:  # it died before the request took effect
        os._exit(1)


def kill_workers(pool: Executor) -> None:
    """Kill ``pool``'s worker processes now (a call they run is abandoned); shut the pool
    down after. The executor's record of its workers is read: it offers no public way."""
    for proc in list((getattr(pool, "_processes", None) or {}).values()):
        proc.kill()
