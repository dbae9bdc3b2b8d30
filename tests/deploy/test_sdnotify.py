from __future__ import annotations

import os
import socket
from pathlib import Path

from hostd.sdnotify import notify, watchdog_interval


def test_notify_is_a_no_op_outside_systemd() -> None:
    assert notify("READY=1", environ={}) is False


def test_notify_sends_one_datagram(tmp_path: Path) -> None:
    path = str(tmp_path / "notify.sock")
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as srv:
        srv.bind(path)
        srv.settimeout(5)
        assert notify("READY=1\nSTATUS=idle", environ={"NOTIFY_SOCKET": path}) is True
        assert srv.recv(1024) == b"READY=1\nSTATUS=idle"


def test_watchdog_interval_is_half_the_period_for_this_process() -> None:
    env = {"WATCHDOG_USEC": "30000000", "WATCHDOG_PID": str(os.getpid())}
    assert watchdog_interval(env) == 15.0
    assert watchdog_interval({"WATCHDOG_USEC": "30000000", "WATCHDOG_PID": "1"}) is None
    assert watchdog_interval({}) is None
