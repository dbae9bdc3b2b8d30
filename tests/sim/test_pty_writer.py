"""The emulator's pty writes: in order and whole while a host reads, bounded when none does."""

from __future__ import annotations

import asyncio
import contextlib
import os
import tty
from collections.abc import Iterator

import pytest

from hostd.sim.pty_writer import PENDING_LIMIT, PtyWriter


@pytest.fixture
def pty() -> Iterator[tuple[int, int]]:
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    os.set_blocking(slave, False)  # a pty can report readable before a read finds bytes
    yield master, slave
    os.close(master)
    os.close(slave)


def payload(n: int) -> bytes:
    """``n`` bytes of numbered lines, so a loss or a reordering shows."""
    lines = b"".join(b"%07d ok T:210.00 /210.00 B:60.00 /60.00\n" % i for i in range(n // 40 + 1))
    return lines[:n]


async def read_until(fd: int, size: int, chunk: int) -> bytes:
    """Read ``size`` bytes from ``fd`` as they come, ``chunk`` at a time."""
    loop = asyncio.get_running_loop()
    got = bytearray()
    ready = asyncio.Event()
    loop.add_reader(fd, ready.set)
    try:
        while len(got) < size:
            await ready.wait()
            ready.clear()
            with contextlib.suppress(BlockingIOError):
                got += os.read(fd, chunk)
    finally:
        loop.remove_reader(fd)
    return bytes(got)


@pytest.mark.asyncio
async def test_a_burst_larger_than_the_pty_arrives_whole_and_in_order(
        pty: tuple[int, int]) -> None:
    master, slave = pty
    writer = PtyWriter(asyncio.get_running_loop(), master)
    data = payload(PENDING_LIMIT)  # far beyond what the kernel holds (about 20 KB)
    for start in range(0, len(data), 5000):  # a few writes, as the emulator's replies
        writer.write(data[start:start + 5000])
    assert writer.pending > 0  # the kernel took only part of it
    async with asyncio.timeout(10):
        got = await read_until(slave, len(data), 512)
    assert got == data and writer.dropped == 0 and writer.pending == 0
    writer.close()


@pytest.mark.asyncio
async def test_with_no_reader_the_backlog_is_bounded_and_the_rest_dropped(
        pty: tuple[int, int]) -> None:
    master, slave = pty
    writer = PtyWriter(asyncio.get_running_loop(), master)
    data = payload(3 * PENDING_LIMIT)
    writer.write(data)
    taken = len(data) - writer.pending - writer.dropped  # by the kernel's own buffer
    assert writer.pending == PENDING_LIMIT and taken > 0
    writer.write(b"late\n")
    assert writer.pending == PENDING_LIMIT
    assert writer.dropped == len(data) + 5 - taken - PENDING_LIMIT
    async with asyncio.timeout(10):  # what a host reads later is the start, in order
        got = await read_until(slave, taken + PENDING_LIMIT, 4096)
    assert got == data[:taken + PENDING_LIMIT] and writer.pending == 0
    writer.close()
