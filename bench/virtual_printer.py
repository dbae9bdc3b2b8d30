"""OctoPrint's virtual printer behind a pseudo-terminal, for the benches.

Run with the OctoPrint venv's interpreter (``make test-octoprint`` builds ``.venv-octoprint``):
``.venv-octoprint/bin/python bench/virtual_printer.py [--baud 115200]`` prints the pty path
on one line of stdout and serves until SIGTERM/SIGINT; point ``serial.port`` at that path. The
printer runs with its own defaults (a 64-byte receive buffer, plain ``ok``), no reset banner
and no injected errors. A pty carries bytes at once, so each way a line is passed on when its
last byte would have crossed a wire of ``--baud`` (10 bits a byte), as on a real port;
``--baud 0`` passes lines on at once (the virtual printer's own pace).

Also the printer for ``tests/link/test_link_octoprint.py`` (:func:`attach`, on a socket) and
``bench/link_noise.py`` (:func:`serve_pty`), with :class:`Noise` on the host's lines: a share
of them reach the printer with one bit flipped in their numbered, checksummed part (after the
``N``, before the ``*``, never making a ``*`` or a line break), as a noisy cable would:
Marlin's checksum catches every such line (``Error: Checksum mismatch`` and a ``Resend``). A
flip of the ``N`` or the ``*`` itself would make the line pass unchecked on this emulator (it
takes lines without a checksum), which no host can guard against, so none is made.
"""

from __future__ import annotations

import argparse
import os
import random
import re
import signal
import socket
import sys
import tempfile
import threading
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from octoprint.plugins import virtual_printer as plugin
from octoprint.plugins.virtual_printer import virtual


class Settings:
    """The slice of OctoPrint's plugin settings API the virtual printer reads (also the link's
    test against it, tests/link/test_link_octoprint.py)."""

    def __init__(self, overrides: dict[str, Any]) -> None:
        self.values = plugin.VirtualPrinterPlugin().get_settings_defaults()
        self.values.update(overrides)

    def get(self, path: list[str], merged: bool = False) -> Any:
        value: Any = self.values
        for key in path:
            value = value[key]
        return value

    def get_int(self, path: list[str]) -> int:
        return int(self.get(path))

    def get_float(self, path: list[str]) -> float:
        return float(self.get(path))

    def get_boolean(self, path: list[str]) -> bool:
        return bool(self.get(path))

    def global_get_basefolder(self, name: str) -> str:
        return tempfile.mkdtemp(prefix=f"octo-{name}-")


class NoPlugins:
    def get_hooks(self, name: str) -> dict[str, Any]:
        return {}


class Profiles:
    def get_current_or_default(self) -> dict[str, Any]:
        return {"volume": {"width": 500, "depth": 500, "height": 700}}


class Wire:
    """One direction of a serial wire: the time each line's last byte arrives."""

    def __init__(self, baud: int) -> None:
        self.byte_s = 10 / baud if baud else 0.0
        self.free = 0.0  # when the wire is idle again

    def carry(self, line: bytes) -> None:
        """Return once ``line`` has crossed the wire (queued behind the lines before it)."""
        if not self.byte_s:
            return
        now = time.monotonic()
        self.free = max(self.free, now) + len(line) * self.byte_s
        if self.free > now:
            time.sleep(self.free - now)  # the wire's time, not synchronisation


@dataclass
class Noise:
    """Bit flips on the host's lines: ``share`` of them, drawn from ``seed``."""

    share: float = 0.0
    seed: int = 0
    corrupted: int = 0  # lines flipped so far
    lines: int = 0  # lines seen
    rng: random.Random = field(init=False)

    def __post_init__(self) -> None:
        self.rng = random.Random(self.seed)

    def apply(self, line: bytes) -> bytes:
        self.lines += 1
        star = line.rfind(b"*")
        if not self.share or star < 2 or line[:1] != b"N" or self.rng.random() >= self.share:
            return line
        while True:
            at = self.rng.randrange(1, star)
            flipped = line[at] ^ (1 << self.rng.randrange(7))
            if flipped not in b"*\r\n":
                self.corrupted += 1
                return line[:at] + bytes([flipped]) + line[at + 1:]


def _host_to_printer(recv: Callable[[], bytes], printer: Any, wire: Wire,
                     noise: Noise) -> None:
    buf = b""
    while True:
        try:
            data = recv()
        except OSError:
            return
        if not data:
            return
        buf += data
        *lines, buf = buf.split(b"\n")
        for line in lines:
            wire.carry(line + b"\n")
            if _NEGATIVE_M110.match(line):
                _renumber(printer, -1)
                continue
            printer.write(noise.apply(line.rstrip(b"\r")) + b"\n")


_NEGATIVE_M110 = re.compile(rb"N-1 M110 N-1\*[0-9]+\r?$")
"""printcore's ``M110 N-1`` before a print: the virtual printer reads line numbers as
``N([0-9]+)`` and its reader thread dies on this one. Marlin sets its last line to -1 and
answers ``ok``; so does the harness, for it."""


def _renumber(printer: Any, last: int) -> None:
    with printer._incoming_lock:
        printer.lastN = printer.current_line = last
    printer._sendOk()


def _printer_to_host(send: Callable[[bytes], Any], printer: Any, wire: Wire,
                     stop: threading.Event) -> None:
    while not stop.is_set():
        line = printer.readline()  # without its newline, unlike a real port
        if line:
            out = line.rstrip(b"\r\n") + b"\n"
            wire.carry(out)
            try:
                send(out)
            except OSError:
                return


def _start(recv: Callable[[], bytes], send: Callable[[bytes], Any],
           overrides: dict[str, Any], noise: Noise, baud: int) -> threading.Event:
    virtual.plugin_manager = NoPlugins  # the printer asks it for hooks
    printer = virtual.VirtualPrinter(Settings(overrides), Profiles(),
                                     tempfile.mkdtemp(prefix="octo-data-"), read_timeout=0.1)
    stop = threading.Event()
    threading.Thread(target=_host_to_printer, args=(recv, printer, Wire(baud), noise),
                     daemon=True).start()
    threading.Thread(target=_printer_to_host, args=(send, printer, Wire(baud), stop),
                     daemon=True).start()
    return stop


def attach(board: socket.socket, overrides: dict[str, Any], noise: Noise | None = None,
           baud: int = 0) -> threading.Event:
    """A new virtual printer on ``board`` (one end of a connected stream socket); set the
    event it returns to stop its reader."""
    return _start(lambda: board.recv(4096), board.sendall, overrides, noise or Noise(), baud)


def serve_pty(overrides: dict[str, Any], noise: Noise | None = None,
              baud: int = 0) -> tuple[str, Callable[[], None]]:
    """A new virtual printer behind a pseudo-terminal, as a board behind a serial port: the
    path a host opens (with pyserial, as printcore and hostd do), and what stops it."""
    master, slave = os.openpty()
    tty.setraw(slave)  # no echo, no line discipline: bytes as on a serial line
    path = os.ttyname(slave)
    stop = _start(lambda: os.read(master, 4096), lambda data: os.write(master, data),
                  overrides, noise or Noise(), baud)

    def close() -> None:
        stop.set()
        os.close(slave)
        os.close(master)

    return path, close


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baud", type=int, default=115200, help="the wire's pace (0: none)")
    baud = ap.parse_args().baud
    path, _ = serve_pty({"simulateReset": False}, baud=baud)
    print(path, flush=True)
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    stop.wait()
    os._exit(0)  # the virtual printer's own threads would hold the interpreter


if __name__ == "__main__":
    sys.exit(main())
