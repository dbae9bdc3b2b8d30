"""hostd under systemd: sd_notify readiness/watchdog/status/stopping, and socket activation.

A datagram socket stands in for systemd's ``NOTIFY_SOCKET``; a pre-bound listening Unix socket
passed as fd 3 with ``LISTEN_PID``/``LISTEN_FDS`` stands in for ``hostd.socket``.
"""

from __future__ import annotations

import asyncio
import socket
import sys
from pathlib import Path

import pytest
from hostd_harness import make_gcode

pytestmark = pytest.mark.asyncio

# Moves the passed socket to fd 3 and sets LISTEN_PID to its own pid, which exec keeps.
ACTIVATE = ("import os, sys; os.dup2(int(sys.argv[1]), 3); "
            "os.environ.update(LISTEN_PID=str(os.getpid()), LISTEN_FDS='1'); "
            "os.execv(sys.argv[2], sys.argv[2:])")


class NotifySocket:
    """The receiving end of sd_notify: one datagram per message."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(path))
        self.sock.setblocking(False)
        self.seen: list[dict[str, str]] = []

    async def next(self) -> dict[str, str]:
        data = await asyncio.get_running_loop().sock_recv(self.sock, 4096)
        msg = dict(line.split("=", 1) for line in data.decode().splitlines())
        self.seen.append(msg)
        return msg

    async def until(self, key: str, value: str = "", prefix: bool = False) -> dict[str, str]:
        while True:
            msg = await self.next()
            got = msg.get(key)
            if got is not None and (got.startswith(value) if prefix else got == value):
                return msg


async def test_ready_watchdog_status_and_stopping(daemon_factory, tmp_path):
    note = NotifySocket(tmp_path / "notify.sock")
    d = daemon_factory()
    async with asyncio.timeout(30):
        await d.start(env={"NOTIFY_SOCKET": str(note.path), "WATCHDOG_USEC": "200000"})
        ready = await note.until("READY", "1")
        assert ready["STATUS"].startswith("idle, link ready")
        assert not any("WATCHDOG" in m for m in note.seen[:-1]), "pinged before ready"
        await note.until("WATCHDOG", "1")
        await note.until("WATCHDOG", "1")
        c = await d.rpc()
        job = await c.submit_text("w.gcode", make_gcode(subparts=1, layers=2, per_layer=20))
        await note.until("STATUS", f"printing job {job['id']} (w.gcode)", prefix=True)
        await note.until("STATUS", "idle, link ready, 0 queued")
        await c.close()
        d.proc.terminate()
        stopping = await note.until("STOPPING", "1")
        assert stopping["STATUS"] == "stopping"
        assert await d.stop() == 0
    note.sock.close()


async def test_socket_activation_serves_the_inherited_socket(daemon_factory, tmp_path):
    path = tmp_path / "activated.sock"
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(str(path))
    listener.listen()
    d = daemon_factory()
    fd = listener.fileno()
    async with asyncio.timeout(30):
        await d.start(pass_fds=(fd,), wrapper=(sys.executable, "-c", ACTIVATE, str(fd)))
        listener.close()  # the daemon holds its own copy, as systemd does
        assert not d.socket.exists(), "created the configured socket despite activation"
        d.socket = path
        c = await d.rpc()
        status = await c.call("printer.status")
        assert status["control"]["activated"] is True
        assert status["control"]["socket"] == str(path)
        await c.close()
        assert await d.stop() == 0
    assert path.exists(), "an activated socket's file belongs to systemd"
