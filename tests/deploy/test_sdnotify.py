from __future__ import annotations

import os
import socket
from pathlib import Path

from hostd.sdnotify import listen_fds, notify, watchdog_interval


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


def test_listen_fds_only_for_this_process_and_unset() -> None:
    env = {"LISTEN_PID": str(os.getpid()), "LISTEN_FDS": "2", "LISTEN_FDNAMES": "a:b"}
    assert listen_fds(env) == [3, 4]
    assert env == {}, "unset, so that child processes do not take the sockets"
    assert listen_fds({"LISTEN_PID": "1", "LISTEN_FDS": "1"}) == []
    assert listen_fds({}) == []


def test_notify_to_a_vanished_socket_is_reported_not_raised(tmp_path: Path) -> None:
    assert notify("WATCHDOG=1", environ={"NOTIFY_SOCKET": str(tmp_path / "gone")}) is False
