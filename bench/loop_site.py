"""Installed as ``sitecustomize`` by :mod:`loop_cpu` in every process of a bench run.

With ``HOSTD_LOOP_CPU`` set to a path prefix, it times (thread CPU) every event-loop callback,
every ``epoll`` wait, ``os.read`` and ``os.write``, and a few methods of the serial link once
they are imported; at exit it writes the totals to ``<prefix>.<pid>``, the first line being
the program's path (marked when the process is a multiprocessing child, whose ``argv`` is
its parent's). Without the variable it does nothing.
"""

from __future__ import annotations

import asyncio.events
import atexit
import os
import selectors
import sys
import time
from collections import defaultdict
from collections.abc import Callable
from typing import Any

PREFIX = os.environ.get("HOSTD_LOOP_CPU")
WRAPPED = {  # module: (class, method) pairs timed as "Class.method" (plain methods only)
    "hostd.link.protocol": [("Protocol", "receive_lines"), ("Protocol", "_pump"),
                            ("Protocol", "submit_many"), ("Protocol", "snapshot")],
    "hostd.link.link": [("SerialLink", "_on_lines"), ("SerialLink", "_apply"),
                        ("SerialLink", "status")],
    "hostd.link.transport": [("DirectSerialTransport", "_hold_or_watch")],
    "hostd.daemon": [("Daemon", "snapshot")],
    "hostd.jobs.manager": [("JobManager", "status")],
    "hostd.jobs.progress": [("ProgressRecorder", "on_progress"), ("ProgressRecorder", "persist")],
    "hostd.printer.streamer": [("Streamer", "_ack_head"), ("Streamer", "_catch_up")],
    "hostd.control.server": [("Client", "send")],
}
totals: defaultdict[str, list[int]] = defaultdict(lambda: [0, 0])  # name: [calls, ns]
clock = time.thread_time_ns


def timed(name: str, func: Callable[..., Any]) -> Callable[..., Any]:
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        start = clock()
        try:
            return func(*args, **kwargs)
        finally:
            entry = totals[name]
            entry[0] += 1
            entry[1] += clock() - start
    return wrapper


def callback_name(handle: asyncio.events.Handle) -> str:
    callback = handle._callback  # the bench looks inside asyncio on purpose
    owner = getattr(callback, "__self__", None)
    if isinstance(owner, asyncio.Task):
        return "task " + getattr(owner.get_coro(), "__qualname__", "?")
    return getattr(callback, "__qualname__", type(callback).__name__)


def install() -> None:
    run = asyncio.events.Handle._run
    pending = dict(WRAPPED)

    def handle_run(self: asyncio.events.Handle) -> None:
        for module in [m for m in pending if m in sys.modules]:
            for cls, method in pending.pop(module):
                owner = getattr(sys.modules[module], cls)
                setattr(owner, method, timed(f"{cls}.{method}", getattr(owner, method)))
        name = callback_name(self)  # before: a handle cancelled as it runs loses its callback
        start = clock()
        run(self)
        entry = totals[name]
        entry[0] += 1
        entry[1] += clock() - start

    asyncio.events.Handle._run = handle_run  # type: ignore[method-assign]
    selectors.EpollSelector.select = timed(  # type: ignore[method-assign]
        "(epoll wait)", selectors.EpollSelector.select)
    os.read = timed("(os.read)", os.read)
    os.write = timed("(os.write)", os.write)
    atexit.register(dump, time.process_time_ns())


def program() -> str:
    """The program's path; a multiprocessing child (which inherits its parent's ``argv``)
    is marked as such."""
    mp = sys.modules.get("multiprocessing")
    child = mp is not None and mp.parent_process() is not None
    return f"{sys.argv[0]} (multiprocessing child)" if child else sys.argv[0]


def dump(cpu_at_start: int) -> None:
    assert PREFIX is not None
    with open(f"{PREFIX}.{os.getpid()}", "w") as out:
        out.write(f"{program()}\n{time.process_time_ns() - cpu_at_start}\n")
        for name, (calls, ns) in totals.items():
            out.write(f"{calls}\t{ns}\t{name}\n")


if PREFIX:
    install()
