"""A bounded HTTP/1.1 connection on the event loop, answering with a WSGI app.

Just enough HTTP for a scraper: a request head (no body) of at most :data:`MAX_HEAD` bytes,
answered in full with ``Content-Length``; keep-alive as HTTP/1.1 has it (HTTP/1.0 and
``Connection: close`` close after the answer); requests one at a time (pipelined bytes wait).
The connection holds a place under the metrics endpoint's
:class:`~hostd.control.limits.ConnectionGate` and is closed after ``idle_timeout`` seconds
without a whole request head; each answer is made in its turn
(:class:`~hostd.control.limits.Turns`), never between the serial port's callbacks.
"""

from __future__ import annotations

import asyncio
import io
import logging
import math
from collections.abc import Callable, Iterable
from typing import Any

from hostd.control.limits import IdleTimer, Ticket, Turns

log = logging.getLogger(__name__)

MAX_HEAD = 16 * 1024
"""Largest request head (request line and headers), bytes."""

WsgiApp = Callable[[dict[str, Any], Callable[..., Any]], Iterable[bytes]]


def simple_response(status: str, body: str, close: bool = True) -> bytes:
    data = body.encode()
    head = (f"HTTP/1.1 {status}\r\nContent-Type: text/plain; charset=utf-8\r\n"
            f"Content-Length: {len(data)}\r\n" + ("Connection: close\r\n" if close else "")
            + "\r\n")
    return head.encode("latin-1") + data


class Request:
    """A parsed request head."""

    def __init__(self, method: str, target: str, version: str,
                 headers: dict[str, str]) -> None:
        self.method = method
        self.path, _, self.query = target.partition("?")
        self.version = version
        self.headers = headers

    @property
    def keep_alive(self) -> bool:
        conn = self.headers.get("connection", "").lower()
        if self.version == "HTTP/1.0":
            return conn == "keep-alive"
        return conn != "close"

    def environ(self) -> dict[str, Any]:
        env = {"REQUEST_METHOD": self.method, "PATH_INFO": self.path,
               "QUERY_STRING": self.query, "SERVER_PROTOCOL": self.version,
               "wsgi.input": io.BytesIO(), "wsgi.url_scheme": "http"}
        for name, value in self.headers.items():
            env["HTTP_" + name.upper().replace("-", "_")] = value
        return env


def parse_head(head: bytes) -> Request | None:
    """The request in ``head`` (without its blank line), or ``None`` when it is no HTTP."""
    try:
        text = head.decode("latin-1")
        line, *fields = text.split("\r\n")
        method, target, version = line.split(" ")
    except ValueError:
        return None
    if not version.startswith("HTTP/1.") or not target.startswith("/"):
        return None
    headers: dict[str, str] = {}
    for field in fields:
        name, sep, value = field.partition(":")
        if not sep:
            return None
        headers[name.strip().lower()] = value.strip()
    return Request(method, target, version, headers)


class HttpConnection(asyncio.Protocol):
    """One metrics connection: request heads in, ``app``'s answers out."""

    def __init__(self, ticket: Ticket, app: WsgiApp, turns: Turns, idle_timeout: float,
                 on_request: Callable[[], None], live: set[HttpConnection]) -> None:
        self.ticket = ticket
        self.live = live  # the server's open connections: this one, while it is open
        self.app = app
        self.turns = turns
        self.idle_timeout = idle_timeout
        self.on_request = on_request
        self.transport: asyncio.Transport | None = None
        self.buffer = b""
        self.busy = False
        self.answered = -math.inf  # loop time of the last answer (none yet)
        self.writing = True  # the transport takes writes (the client reads its answers)
        self.idle: IdleTimer | None = None
        self.task: asyncio.Task[None] | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport
        self.live.add(self)
        self.ticket.evict = lambda why: self.close()
        self.idle = IdleTimer(self.idle_timeout, lambda: self.busy, self.close)

    def data_received(self, data: bytes) -> None:
        self.buffer += data
        self._next()

    def connection_lost(self, exc: Exception | None) -> None:
        self.live.discard(self)
        self.ticket.release()
        if self.idle is not None:
            self.idle.cancel()
        if self.task is not None:
            self.task.cancel()

    def pause_writing(self) -> None:
        self.writing = False

    def resume_writing(self) -> None:
        self.writing = True
        self._go_on()

    def close(self) -> None:
        if self.transport is not None:
            self.transport.abort()

    def _go_on(self) -> None:
        """Read the next request, once the answer before it is written and taken."""
        if self.transport is None or self.transport.is_closing() or self.busy:
            return
        if self.writing:
            self.transport.resume_reading()
            self._next()

    def _next(self) -> None:
        """Start answering the next whole request head, if there is one and none is under way."""
        if self.busy or self.transport is None or self.transport.is_closing():
            return
        head, sep, rest = self.buffer.partition(b"\r\n\r\n")
        if not sep:
            if len(self.buffer) > MAX_HEAD:
                self._refuse("431 Request Header Fields Too Large", "request head too large")
            return
        if len(head) > MAX_HEAD:
            self._refuse("431 Request Header Fields Too Large", "request head too large")
            return
        self.buffer = rest
        request = parse_head(head)
        if request is None:
            self._refuse("400 Bad Request", "not an HTTP/1.x request")
            return
        self.busy = True
        self.ticket.proven = True
        self.transport.pause_reading()
        self.task = asyncio.get_running_loop().create_task(self._answer(request))

    async def _answer(self, request: Request) -> None:
        loop = asyncio.get_running_loop()
        try:
            await self.turns.take(loop.time() - self.answered)
            self.on_request()
            self._write(request, *self._call(request))
        finally:
            self.busy = False
            self.task = None
            self.answered = loop.time()
        if self.idle is not None:
            self.idle.touch()
        if request.keep_alive:
            self._go_on()
        elif self.transport is not None:
            self.transport.close()

    def _call(self, request: Request) -> tuple[str, list[tuple[str, str]], bytes]:
        """The app's answer to ``request``: status, headers, body."""
        started: list[Any] = []

        def start_response(status: str, headers: list[tuple[str, str]]) -> None:
            started[:] = [status, headers]

        try:
            body = b"".join(self.app(request.environ(), start_response))
        except Exception:  # a failed scrape is the scraper's error, not the daemon's end
            log.exception("metrics: the scrape failed")
            return "500 Internal Server Error", [("Content-Type", "text/plain")], b"failed\n"
        return started[0], started[1], body

    def _write(self, request: Request, status: str, headers: list[tuple[str, str]],
               body: bytes) -> None:
        if self.transport is None or self.transport.is_closing():
            return
        lines = [f"HTTP/1.1 {status}", *(f"{k}: {v}" for k, v in headers),
                 f"Content-Length: {len(body)}"]
        if not request.keep_alive:
            lines.append("Connection: close")
        self.transport.write(("\r\n".join(lines) + "\r\n\r\n").encode("latin-1") + body)

    def _refuse(self, status: str, why: str) -> None:
        assert self.transport is not None
        self.transport.write(simple_response(status, why + "\n"))
        self.transport.close()
        self.buffer = b""
