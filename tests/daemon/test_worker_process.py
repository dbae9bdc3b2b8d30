"""A worker process of the daemon ends when the daemon is killed, and when it is closed with
a call still running (the daemon stopped mid-slice)."""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys

import pytest

PARENT = """
import os, sys
from hostd.worker_process import spawn_pool
if __name__ == "__main__":
    pool = spawn_pool()
    print(pool.submit(os.getpid).result(), flush=True)
    sys.stdin.read()  # until killed
"""


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


@pytest.mark.timeout(60)
@pytest.mark.skipif(not hasattr(os, "pidfd_open"), reason="needs pidfd_open (Linux)")
def test_the_worker_ends_when_its_daemon_is_killed():
    parent = subprocess.Popen([sys.executable, "-c", PARENT], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True)
    try:
        assert parent.stdout is not None
        worker = int(parent.stdout.readline())
        assert worker != parent.pid and alive(worker)
        fd = os.pidfd_open(worker)
        try:
            parent.send_signal(signal.SIGKILL)
            parent.wait(timeout=30)
            ready, _, _ = select.select([fd], [], [], 30)  # readable once the worker has ended
        finally:
            os.close(fd)
        assert ready, "the worker outlived its killed parent by 30 s"
    finally:
        parent.kill()
        parent.wait()


CLOSER = """
import asyncio, os, sys, threading, time
from hostd.worker_process import WorkerProcess

async def main(running):
    w = WorkerProcess()
    print(await w.run(os.getpid), flush=True)
    call = asyncio.ensure_future(w.run(time.sleep, 600))  # a slice that takes long
    if running:  # (not a synchronisation: queued or running, the call must end the same way)
        await asyncio.wait({call}, timeout=1.0)
    else:
        await asyncio.sleep(0)  # handed to the pool, still queued
    w.close()
    try:
        await call
    except Exception as exc:
        print(type(exc).__name__, flush=True)

if __name__ == "__main__":
    asyncio.run(main(sys.argv[1] == "running"))
    print(",".join(sorted(t.name for t in threading.enumerate())), flush=True)
"""


@pytest.mark.timeout(120)
@pytest.mark.parametrize("call", ["queued", "running"])
def test_closing_with_a_call_running_ends_the_worker_and_lets_the_process_exit(call: str):
    # Before: the pool was shut down without waiting, its manager thread waited on the running
    # call, and the interpreter joined that thread at exit: 600 s here (the timeout below).
    done = subprocess.run([sys.executable, "-c", CLOSER, call], capture_output=True, text=True,
                          timeout=90)
    worker, error, threads = done.stdout.split()
    assert done.returncode == 0, done.stderr
    assert not alive(int(worker))
    assert error == "WorkerDied"  # the abandoned call fails, as a killed worker's does
    assert threads == "MainThread"
    assert "leaked" not in done.stderr and "Exception ignored" not in done.stderr, done.stderr
