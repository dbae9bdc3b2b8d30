"""The control server: JSON-RPC 2.0 over a Unix socket, one message per line.

Each client has a reader task (requests are answered in order) and a writer task draining one
outgoing queue, so responses and pushed notifications never interleave mid-line. A message over
the size limit gets an error and the connection is closed; a client that stops reading its
events is dropped once its queue is full. Neither affects the daemon or the other clients.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import os
import socket
import stat
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hostd.control.codes import MESSAGE_TOO_LARGE
from hostd.control.rpc import Registry, encode, notification, response
from hostd.events import EventBus

log = logging.getLogger(__name__)

SOCKET_MODE = 0o660
CLIENT_QUEUE = 2000  # outgoing messages buffered per client before it counts as stuck


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


class Client:
    """One connection: its id, its event subscription and its outgoing queue."""

    def __init__(self, cid: int, server: ControlServer) -> None:
        self.id = cid
        self.server = server
        self.queue: asyncio.Queue[str | None] = asyncio.Queue()
        self.subscribed: frozenset[str] | None = None  # None: not subscribed
        self.all_events = False
        self.dropped = False
        self.on_close: dict[str, Callable[[], None]] = {}  # run once the connection has ended

    def send(self, line: str) -> None:
        if self.dropped:
            return
        if self.queue.qsize() >= CLIENT_QUEUE:
            log.warning("client %d is not reading; dropping it", self.id)
            self.dropped = True
            self.queue.put_nowait(None)
            return
        self.queue.put_nowait(line)

    def subscribe(self, names: list[str] | None) -> None:
        self.all_events = not names
        self.subscribed = frozenset(names or ())

    def on_event(self, name: str, data: dict[str, Any]) -> None:
        if self.subscribed is None:
            return
        if self.all_events or name in self.subscribed:
            self.send(encode(notification("notify_" + name.replace(".", "_"),
                                          {"event": name, **data})))


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
    max_message
        Largest request line, bytes.
    """

    def __init__(self, path: str | Path, registry: Registry, bus: EventBus,
                 max_message: int) -> None:
        self.path = Path(path)
        self.registry = registry
        self.bus = bus
        self.max_message = max_message
        self.clients: dict[int, Client] = {}
        self._ids = itertools.count(1)
        self._server: asyncio.AbstractServer | None = None
        self._tasks: set[asyncio.Task[None]] = set()
        self._closing = False
        self._unsubscribe = bus.subscribe(self._broadcast)
        self.requests = 0
        self.connections = 0
        self.oversized = 0
        self.inherited = False  # the listening socket came from systemd (socket activation)
        self._made: tuple[int, int] | None = None  # (st_dev, st_ino) of the socket we bound

    async def start(self, sock: socket.socket | None = None) -> None:
        """Listen on ``path``, or serve ``sock``, a listening socket passed by systemd."""
        if sock is not None:
            await self._adopt(sock)
            return
        try:
            await self._remove_stale()
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ControlError(f"{self.path}: cannot use: {_why(exc, self.path)}") from None
        old = os.umask(0o117)  # the socket is born 0660: no window with wider permissions
        try:
            self._server = await asyncio.start_unix_server(
                self._serve, path=str(self.path), limit=self.max_message)
        except OSError as exc:
            raise ControlError(f"{self.path}: cannot listen: {_why(exc, self.path)}") from None
        finally:
            os.umask(old)
        os.chmod(self.path, SOCKET_MODE)
        made = self.path.stat()
        self._made = (made.st_dev, made.st_ino)
        log.info("control socket %s", self.path)

    async def _adopt(self, sock: socket.socket) -> None:
        if sock.family != socket.AF_UNIX or sock.type != socket.SOCK_STREAM:
            raise ControlError(f"inherited fd {sock.fileno()} is not a Unix stream socket")
        try:
            self._server = await asyncio.start_unix_server(self._serve, sock=sock,
                                                           limit=self.max_message)
        except OSError as exc:
            raise ControlError(f"inherited socket: {exc.strerror or exc}") from None
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
        self._closing = True
        self._unsubscribe()
        if self._server is not None:
            self._server.close()
        for client in list(self.clients.values()):
            client.queue.put_nowait(None)
        for task in list(self._tasks):
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        if self._server is not None:
            with contextlib.suppress(Exception):
                await self._server.wait_closed()
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
        for client in list(self.clients.values()):
            client.on_event(name, data)

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._tasks.add(task)
        client = Client(next(self._ids), self)
        self.clients[client.id] = client
        self.connections += 1
        out = asyncio.create_task(self._write_loop(client, writer))
        try:
            await self._read_loop(client, reader)
        except (ConnectionError, asyncio.IncompleteReadError) as exc:
            log.debug("client %d: %s", client.id, exc)
        except asyncio.CancelledError:
            if not self._closing:
                raise
            # the server stops: the connection ends as a normal close would (a task ending
            # cancelled is reported as an error by asyncio's stream callback on Python 3.11)
        finally:
            self.clients.pop(client.id, None)
            client.queue.put_nowait(None)
            for name, hook in client.on_close.items():
                try:
                    hook()
                except Exception:  # one failing hook must not keep the others from running
                    log.exception("client %d: closing %s", client.id, name)
            with contextlib.suppress(Exception):
                await out
            writer.close()
            with contextlib.suppress(Exception):
                await writer.wait_closed()
            self._tasks.discard(task)

    async def _read_loop(self, client: Client, reader: asyncio.StreamReader) -> None:
        while not client.dropped:
            try:
                line = await reader.readline()
            except ValueError:  # over the limit: answer, then hang up (cannot resync)
                self.oversized += 1
                client.send(encode(response(None, error={
                    "code": MESSAGE_TOO_LARGE,
                    "message": f"message exceeds {self.max_message} bytes"})))
                return
            if not line:
                return
            if not line.strip():
                continue
            self.requests += 1
            reply = await self.registry.dispatch(line, client)
            if reply is not None:
                client.send(reply)

    async def _write_loop(self, client: Client, writer: asyncio.StreamWriter) -> None:
        try:
            while (line := await client.queue.get()) is not None:
                writer.write(line.encode())
                await writer.drain()
        except ConnectionError:
            client.dropped = True
        finally:
            writer.close()  # also ends the reader of a dropped client

    def status(self) -> dict[str, Any]:
        return {"socket": str(self.path), "activated": self.inherited,
                "clients": len(self.clients),
                "subscribed": sum(1 for c in self.clients.values() if c.subscribed is not None),
                "connections_total": self.connections, "requests_total": self.requests,
                "oversized_total": self.oversized}
