"""Replies onto the pty master: never blocking the emulator, never losing what a host reads.

A pseudo-terminal holds about 20 KB between its master and a reader; a host that reads in
batches (hostd's held reads) can be that far behind for a moment, when the emulator sends a
burst. What the kernel cannot take yet waits here, in order, until the master is writable
again. With no host reading at all, the wait is bounded: beyond :data:`PENDING_LIMIT` bytes,
replies are dropped, as on a wire nobody listens to (and a host that opens the port later does
not find a backlog of stale replies).
"""

from __future__ import annotations

import asyncio
import os

PENDING_LIMIT = 64 * 1024  # bytes waiting for the kernel, beyond its own buffer


class PtyWriter:
    """Non-blocking, in-order writes to the pty master ``fd`` on ``loop``.

    Attributes
    ----------
    dropped
        Bytes dropped because :data:`PENDING_LIMIT` was reached (no host reading).
    """

    def __init__(self, loop: asyncio.AbstractEventLoop, fd: int) -> None:
        self._loop = loop
        self._fd = fd
        self._pending = bytearray()
        self.dropped = 0

    @property
    def pending(self) -> int:
        """Bytes waiting for the kernel to take them."""
        return len(self._pending)

    def write(self, data: bytes) -> None:
        """Write ``data`` now if the kernel takes it, else keep it until it does."""
        if self._pending:
            self._keep(data)
            return
        written = self._write_now(data)
        if written < len(data):
            self._keep(data[written:])
            self._loop.add_writer(self._fd, self._drain)

    def close(self) -> None:
        """Stop waiting for the master to become writable; what is pending is dropped."""
        self._loop.remove_writer(self._fd)
        self._pending.clear()

    def _keep(self, data: bytes) -> None:
        room = PENDING_LIMIT - len(self._pending)
        self._pending += data[:room]
        self.dropped += max(0, len(data) - room)

    def _write_now(self, data: bytes | bytearray) -> int:
        try:
            return os.write(self._fd, data)
        except (BlockingIOError, InterruptedError):
            return 0

    def _drain(self) -> None:
        del self._pending[:self._write_now(self._pending)]
        if not self._pending:
            self._loop.remove_writer(self._fd)
