"""One daemon per state directory: an exclusive ``flock`` on ``<state_dir>/hostd.lock``.

Two daemons on one state directory would both take the queued jobs, write one database and
send one job to two printers (or the same printer twice). The second daemon's socket may be
configured elsewhere, so the socket check alone does not catch it. The kernel drops the lock
when its process dies, SIGKILL included: a restart after a crash never finds a stale lock.
"""

from __future__ import annotations

import fcntl
import os
from pathlib import Path

LOCK_NAME = "hostd.lock"


class StateLockError(Exception):
    """The state directory is in use by another hostd (one line, naming it and its pid)."""


class StateLock:
    """Held from :meth:`acquire` until :meth:`release` (or the process ends)."""

    def __init__(self, state_dir: str | Path) -> None:
        self.path = Path(state_dir) / LOCK_NAME
        self._fd: int | None = None

    def acquire(self) -> None:
        """Take the lock and write our pid in the file; :class:`StateLockError` if another
        process holds it (``OSError`` if the file cannot be opened)."""
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o640)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode("ascii", "replace").strip() or "unknown"
            os.close(fd)
            raise StateLockError(f"daemon.state_dir: {self.path.parent} is in use by another "
                                 f"hostd (pid {holder})") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        self._fd = fd

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing the descriptor drops the flock
            self._fd = None

    @property
    def held(self) -> bool:
        return self._fd is not None
