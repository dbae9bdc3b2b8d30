"""OctoPrint's virtual printer behind a pseudo-terminal, for the benches.

Run with the OctoPrint venv's interpreter (``make test-octoprint`` builds ``.venv-octoprint``):
``.venv-octoprint/bin/python bench/virtual_printer.py [--baud 115200]`` prints the pty path
on one line of stdout and serves until SIGTERM/SIGINT; point ``serial.port`` at that path. The
printer runs with its own defaults (a 64-byte receive buffer, plain ``ok``), no reset banner
and no injected errors. A pty carries bytes at once, so each way a line is passed on when its
last byte would have crossed a wire of ``--baud`` (10 bits a byte), as on a real port;
``--baud 0`` passes lines on at once (the virtual printer's own pace).
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import tempfile
import threading
import time
import tty
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


def _host_to_printer(fd: int, printer: Any, wire: Wire) -> None:
    buf = b""
    while data := os.read(fd, 4096):
        buf += data
        *lines, buf = buf.split(b"\n")
        for line in lines:
            wire.carry(line + b"\n")
            printer.write(line + b"\n")


def _printer_to_host(fd: int, printer: Any, wire: Wire) -> None:
    while True:
        line = printer.readline()  # without its newline, unlike a real port
        if line:
            out = line.rstrip(b"\r\n") + b"\n"
            wire.carry(out)
            os.write(fd, out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baud", type=int, default=115200, help="the wire's pace (0: none)")
    baud = ap.parse_args().baud
    virtual.plugin_manager = NoPlugins
    master, slave = os.openpty()
    tty.setraw(slave)
    printer = virtual.VirtualPrinter(Settings({"simulateReset": False}), Profiles(),
                                     tempfile.mkdtemp(prefix="octo-data-"), read_timeout=0.1)
    for target in (_host_to_printer, _printer_to_host):
        threading.Thread(target=target, args=(master, printer, Wire(baud)),
                         daemon=True).start()
    print(os.ttyname(slave), flush=True)
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    stop.wait()
    os._exit(0)  # the virtual printer's own threads would hold the interpreter


if __name__ == "__main__":
    sys.exit(main())
