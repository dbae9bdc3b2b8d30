"""A worker process of the daemon ends when the daemon is killed."""

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
