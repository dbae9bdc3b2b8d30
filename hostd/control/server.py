"""The control server: JSON-RPC 2.0 over a Unix socket, one message per line.

Connections are accepted under the API's limits (:mod:`hostd.control.limits`: a cap on
connections, a budget of buffered request bytes, idle timeouts, bounded event queues, requests
in turns) and served by :class:`~hostd.control.connection.Connection`: requests answered in
order, responses and pushed events whole and in order. A message over the size limit gets an
error and the connection is closed; a client that stops reading its events is dropped once
its queue is full. Neither affects the daemon or the other clients.
"""

from __future__ import annotations

import asyncio
import itertools
import logging
import os
import socket
import stat
from pathlib import Path
from typing import Any

from hostd.control.codes import CONNECTION_LIMIT
from hostd.control.connection import Client, Connection
from hostd.control.limits import ConnectionGate, Limits, LimitSettings, Listener, Ticket
from hostd.control.rpc import Registry, encode, notification, response
from hostd.events import EventBus

__all__ = ["Client", "ControlError", "ControlServer"]

log = logging.getLogger(__name__)

SOCKET_MODE = 0o660
BACKLOG = 128


class ControlError(Exception):
    """The control socket cannot be set up (path taken by a live daemon, not writable, ...)."""


def _why(exc: OSError, path: Path) -> str:
    """The reason of ``exc`` in a few words: the system's, the ancestor of ``path`` that is
    no directory, or the text of an error without an errno (a path too long to bind)."""
    if isinstance(exc, NotADirectoryError | FileExistsError):
        blocker = next((p for p in path.parents if p.exists() and not p.is_dir()), None)
        if blocker is not None:
            return f"{blocker} is not a directory"
    if exc.strerror:
        return exc.strerror
    return str(exc) or type(exc).__name__


class ControlServer:
    """Serve ``registry`` on the Unix socket ``path`` (mode 0660).

    Parameters
    ----------
    path
        Socket path; a stale socket file is replaced, a live one is an error.
    registry
        The endpoints; handlers get the :class:`Client` as ``ctx``.
    bus
        Events pushed to subscribed clients.
    limits
        The API's limits (shared with any other listener of the API).
    """

    def __init__(self, path: str | Path, registry: Registry, bus: EventBus,
                 limits: Limits | None = None) -> None:
        self.path = Path(path)
        self.registry = registry
        self.bus = bus
        self.limits = limits or Limits(LimitSettings())
        self.clients: dict[int, Client] = {}
        self.connections: set[Connection] = set()
        self.subscribers = 0
        self._ids = itertools.count(1)
        self._sock: socket.socket | None = None
        self._listener: Listener | None = None
        self.closing = False
        self._unsubscribe = bus.subscribe(self._broadcast)
        self.requests = 0
        self.oversized = 0
        self.inherited = False  # the listening socket came from systemd (socket activation)
        self._made: tuple[int, int] | None = None  # (st_dev, st_ino) of the socket we bound

    async def start(self, sock: socket.socket | None = None) -> None:
        """Listen on ``path``, or serve ``sock``, a listening socket passed by systemd."""
        if sock is not None:
            self._adopt(sock)
        else:
            await self._bind()
        assert self._sock is not None
        self._listener = Listener(self._sock, self.limits.gate, self._connection, _refusal)
        self._listener.start()

    async def _bind(self) -> None:
        try:
            await self._remove_stale()
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ControlError(f"{self.path}: cannot use: {_why(exc, self.path)}") from None
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        old = os.umask(0o117)  # the socket is born 0660: no window with wider permissions
        try:
            sock.bind(str(self.path))
            sock.listen(BACKLOG)
        except OSError as exc:
            sock.close()
            raise ControlError(f"{self.path}: cannot listen: {_why(exc, self.path)}") from None
        finally:
            os.umask(old)
        os.chmod(self.path, SOCKET_MODE)
        made = self.path.stat()
        self._made = (made.st_dev, made.st_ino)
        self._sock = sock
        log.info("control socket %s", self.path)

    def _connection(self, ticket: Ticket) -> Connection:
        return Connection(self, ticket, next(self._ids))

    def attach(self, conn: Connection) -> None:
        self.connections.add(conn)
        self.clients[conn.client.id] = conn.client

    def detach(self, conn: Connection) -> None:
        self.connections.discard(conn)
        self.clients.pop(conn.client.id, None)

    def _adopt(self, sock: socket.socket) -> None:
        if sock.family != socket.AF_UNIX or sock.type != socket.SOCK_STREAM:
            raise ControlError(f"inherited fd {sock.fileno()} is not a Unix stream socket")
        self._sock = sock
        self.inherited = True
        name = sock.getsockname()
        if isinstance(name, str) and name and Path(name) != self.path:
            log.warning("socket activation: serving %s, not the configured %s", name, self.path)
            self.path = Path(name)
        log.info("control socket %s (passed by systemd)", self.path)

    async def _remove_stale(self) -> None:
        try:
            mode = self.path.lstat().st_mode
        except FileNotFoundError:
            return
        if not stat.S_ISSOCK(mode):
            raise ControlError(f"{self.path}: exists and is not a socket")
        try:
            _, w = await asyncio.open_unix_connection(str(self.path))
        except OSError:
            self.path.unlink(missing_ok=True)  # stale: nobody listens
            return
        w.close()
        raise ControlError(f"{self.path}: another daemon is listening")

    async def close(self) -> None:
        self.closing = True
        self._unsubscribe()
        if self._listener is not None:
            self._listener.close()
        tasks = [c.task for c in self.connections if c.task is not None]
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)  # each closes its connection
        if self._sock is not None:
            self._sock.close()
        self._unlink_own()

    def _unlink_own(self) -> None:
        """Remove the socket file only if it is the one this server bound: not a live
        daemon's socket, an ordinary file at that path, or systemd's activated socket."""
        if self._made is None:
            return
        try:
            st = self.path.lstat()
        except FileNotFoundError:
            return
        if (st.st_dev, st.st_ino) == self._made:
            self.path.unlink(missing_ok=True)

    def _broadcast(self, name: str, data: dict[str, Any]) -> None:
        """One event to every subscriber that wants it, encoded once."""
        line: bytes | None = None
        for conn in list(self.connections):
            if conn.client.wants(name):
                if line is None:
                    line = encode(notification("notify_" + name.replace(".", "_"),
                                               {"event": name, **data})).encode()
                conn.push(line)

    def status(self) -> dict[str, Any]:
        return {"socket": str(self.path), "activated": self.inherited,
                "clients": len(self.connections), "subscribed": self.subscribers,
                "connections_total": self.limits.gate.accepted, "requests_total": self.requests,
                "oversized_total": self.oversized, "limits": self.limits.status()}


def _refusal(gate: ConnectionGate) -> bytes:
    """The line a connection refused at the cap gets."""
    return encode(response(None, error={"code": CONNECTION_LIMIT,
                                        "message": gate.refusal()})).encode()
