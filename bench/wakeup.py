"""The floor under the daemon's streaming CPU: one asyncio wake-up per ``ok`` on a pty.

A child process plays the board: it writes ``ok\\n`` every ``--period`` seconds (1.68 ms is
one 38-byte line at 250000 baud) and drains what it reads. This process reads the pty with a
bare ``loop.add_reader`` callback and, with ``--write``, answers each wake-up with one
38-byte line, as the link does. Printed: CPU microseconds per wake-up and that rate as a
share of a core; nothing of hostd runs, so whatever the link and the streamer cost comes on
top. Run: ``.venv/bin/python bench/wakeup.py [--count N] [--period S] [--write]``.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import time
import tty

LINE = b"N12345 G1 X248.768 Y241.096 E0.00197*99\n"


def board(fd: int, count: int, period: float) -> None:
    """The child: ``count`` oks, one per ``period`` s, reading whatever arrives."""
    os.set_blocking(fd, False)
    due = time.perf_counter()
    for _ in range(count):
        due += period
        while (left := due - time.perf_counter()) > 0:
            time.sleep(min(left, 0.0002))
        try:
            os.read(fd, 4096)
        except BlockingIOError:
            pass
        os.write(fd, b"ok\n")


async def host(fd: int, count: int, write: bool) -> tuple[float, float]:
    """Read ``count`` oks; (CPU s, wall s)."""
    loop = asyncio.get_running_loop()
    os.set_blocking(fd, False)
    done = asyncio.Event()
    seen = 0

    def readable() -> None:
        nonlocal seen
        seen += os.read(fd, 4096).count(b"\n")
        if write:
            os.write(fd, LINE)
        if seen >= count:
            done.set()

    loop.add_reader(fd, readable)
    cpu, wall = time.process_time(), time.perf_counter()
    await done.wait()
    loop.remove_reader(fd)
    return time.process_time() - cpu, time.perf_counter() - wall


def measure(count: int, period: float, write: bool) -> tuple[float, float]:
    """``count`` wake-ups against a child board: (CPU s per wake-up, wall s)."""
    master, slave = os.openpty()
    tty.setraw(slave)
    pid = os.fork()
    if pid == 0:
        board(master, count, period)
        os._exit(0)
    try:
        cpu, wall = asyncio.run(host(slave, count, write))
    finally:
        os.waitpid(pid, 0)
        os.close(master)
        os.close(slave)
    return cpu / count, wall


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--count", type=int, default=5000)
    ap.add_argument("--period", type=float, default=0.00168)
    ap.add_argument("--write", action="store_true", help="answer each wake-up with a line")
    args = ap.parse_args()
    per, wall = measure(args.count, args.period, args.write)
    print(f"{args.count} wake-ups{' with a write each' if args.write else ''}: "
          f"{per * 1e6:.1f} us CPU each, {100 * per / args.period:.1f} % of a core at one per "
          f"{args.period * 1e3:.2f} ms ({wall:.1f} s)")


if __name__ == "__main__":
    main()
