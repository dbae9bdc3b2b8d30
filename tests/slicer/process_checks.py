"""Waiting for a process to end, for the tests of the slicer's worker processes."""

from __future__ import annotations

import os
import select


def gone_within(pid: int, seconds: float) -> bool:
    """True once process ``pid`` has exited (waited on through a pidfd, no polling)."""
    try:
        fd = os.pidfd_open(pid)
    except ProcessLookupError:
        return True
    try:
        return bool(select.select([fd], [], [], seconds)[0])
    finally:
        os.close(fd)
