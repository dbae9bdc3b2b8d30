"""systemd integration: readiness/watchdog notifications and socket activation.

``sd_notify``: one datagram of ``KEY=VALUE`` lines to the socket named by ``NOTIFY_SOCKET``
(an abstract socket when it starts with ``@``); a no-op outside systemd. Socket activation:
``LISTEN_PID``/``LISTEN_FDS`` name the listening sockets passed from fd 3 on.
"""

from __future__ import annotations

import logging
import os
import socket

log = logging.getLogger(__name__)

SD_LISTEN_FDS_START = 3


def _address(raw: str) -> str:
    return "\0" + raw[1:] if raw.startswith("@") else raw


def notify(message: str, environ: dict[str, str] | None = None) -> bool:
    """Send ``message`` (e.g. ``"READY=1"``); return whether it was delivered.

    Never blocks: a full or vanished notify socket loses the message (logged), it does not
    stall the event loop.
    """
    env = os.environ if environ is None else environ
    raw = env.get("NOTIFY_SOCKET")
    if not raw:
        return False
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
            sock.setblocking(False)
            sock.sendto(message.encode(), _address(raw))
    except OSError as exc:
        log.warning("sd_notify %s: %s", raw, exc)
        return False
    return True


def watchdog_interval(environ: dict[str, str] | None = None) -> float | None:
    """Half the watchdog period systemd asks for (``WATCHDOG_USEC``), in seconds, or None."""
    env = os.environ if environ is None else environ
    usec = env.get("WATCHDOG_USEC")
    pid = env.get("WATCHDOG_PID")
    if not usec or (pid and pid != str(os.getpid())):
        return None
    return int(usec) / 2e6


def listen_fds(environ: dict[str, str] | None = None, unset: bool = True) -> list[int]:
    """File descriptors passed by socket activation (fd 3 on), or ``[]``.

    Like ``sd_listen_fds(unset)``: the variables are removed so that child processes (the
    slicing worker) do not take the sockets for theirs.
    """
    env = os.environ if environ is None else environ
    pid, count = env.get("LISTEN_PID"), env.get("LISTEN_FDS")
    if unset:
        for key in ("LISTEN_PID", "LISTEN_FDS", "LISTEN_FDNAMES"):
            env.pop(key, None)
    if not pid or not count or pid != str(os.getpid()):
        return []
    try:
        n = int(count)
    except ValueError:
        return []
    return list(range(SD_LISTEN_FDS_START, SD_LISTEN_FDS_START + max(0, n)))
