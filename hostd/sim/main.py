"""``hostd-sim``: serve the emulated board on a pseudo-terminal.

``hostd-sim --pty`` prints the pty path on one line of stdout and serves until killed; point
``serial.port`` (or any host) at that path. With ``--log FILE`` it writes, when it stops, the
numbered commands it executed (one per line, in order, the ``M110`` handshakes left out) so a
caller can check that a stream arrived whole.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import selectors
import signal
import sys
import tty
from dataclasses import fields
from pathlib import Path

from hostd.sim.pty_writer import PtyWriter
from hostd.sim.server import Emulator
from hostd.sim.settings import SimSettings


class SimError(Exception):
    """The emulator cannot be served."""


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """Command-line options: every :class:`SimSettings` field is a ``--flag``."""
    parser = argparse.ArgumentParser(prog="hostd-sim", description=__doc__)
    parser.add_argument("--pty", action="store_true", required=True,
                        help="serve on a new pseudo-terminal and print its path")
    parser.add_argument("--log", type=Path, default=None, metavar="FILE",
                        help="on exit, write the numbered commands executed to FILE")
    defaults = SimSettings()
    for f in fields(SimSettings):
        value = getattr(defaults, f.name)
        flag = "--" + f.name.replace("_", "-")
        if isinstance(value, bool):
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, default=value)
        else:
            parser.add_argument(flag, type=type(value), default=value)
    return parser.parse_args(argv)


def settings_from_args(args: argparse.Namespace) -> SimSettings:
    """The :class:`SimSettings` the options describe."""
    return SimSettings(**{f.name: getattr(args, f.name) for f in fields(SimSettings)})


async def serve_pty(settings: SimSettings, log: Path | None = None) -> None:
    """Open a pty, print its path, and serve the emulator on it until cancelled or signalled
    (then write the execution log to ``log``, when given)."""
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    print(os.ttyname(slave), flush=True)
    loop = asyncio.get_running_loop()
    writer = PtyWriter(loop, master)
    emulator = Emulator(settings, writer.write)
    stop = asyncio.Event()
    loop.add_reader(master, _on_readable, master, emulator)
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    try:
        await stop.wait()
    finally:
        loop.remove_reader(master)
        emulator.close()
        writer.close()
        os.close(master)
        os.close(slave)
        if log is not None:
            log.write_text("".join(f"{text}\n" for text in executed_lines(emulator)))


def executed_lines(emulator: Emulator) -> list[str]:
    """The numbered commands the board executed, without the ``M110`` handshakes."""
    return [text for number, text in emulator.firmware.log
            if number is not None and not text.startswith("M110")]


def _on_readable(fd: int, emulator: Emulator) -> None:
    with contextlib.suppress(BlockingIOError, InterruptedError):
        data = os.read(fd, 4096)
        emulator.feed(data)


def precise_loop() -> asyncio.AbstractEventLoop:
    """An event loop whose timers fire on time to the kernel's slack, not to the millisecond.

    The default selector (epoll) rounds every timeout up to a whole millisecond, so each wire
    timer of the emulator would fire up to 1 ms late, on top of the wire time itself.
    select(2) takes microseconds, and the emulator watches a single descriptor.
    """
    return asyncio.SelectorEventLoop(selectors.SelectSelector())


def main(argv: list[str] | None = None) -> int:
    """Console entry point of ``hostd-sim``."""
    args = parse_args(argv)
    try:
        with asyncio.Runner(loop_factory=precise_loop) as runner:
            runner.run(serve_pty(settings_from_args(args), args.log))
    except OSError as exc:
        print(f"hostd-sim: {SimError(exc)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
