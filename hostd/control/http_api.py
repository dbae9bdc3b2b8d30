"""The HTTP and WebSocket API (``http:``), on the daemon's event loop, by aiohttp.

- ``GET /websocket``: JSON-RPC 2.0, a request or batch a text message, with the control
  socket's methods and pushed events: the same :class:`~hostd.control.rpc.Registry`, so every
  method is declared once (:mod:`hostd.control.endpoints`).
- ``POST /api/jobs``: an upload (``multipart/form-data``: ``file``, optional ``kind``) queued
  as ``job.submit`` queues one: staged in the spool as it arrives, checked whole, the same
  errors.
- ``GET /api/version``: the one request that needs no key (OctoPrint's answer, for slicers).
- the slicers' upload endpoints (:mod:`hostd.control.slicer_uploads`).

Every other request needs a key of ``http.api_key_file`` (``X-Api-Key`` or ``?apikey=``):
401 without one. The connections are the control socket's under its limits
(:mod:`hostd.control.limits`): they count against ``daemon.max_connections`` (a silent one
makes room; past the cap, 503), one idle for ``daemon.idle_timeout`` is closed (a WebSocket
with a subscription is never idle), each request and WebSocket message waits its turn,
a WebSocket message is at most ``daemon.max_request_bytes`` and its events go through a
bounded :class:`~hostd.control.limits.Outbox` (a subscriber that does not read them is
dropped). A request body is at most ``http.max_upload_mb``.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import logging
import math
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

from aiohttp import BodyPartReader, WSCloseCode, WSMsgType, web

from hostd import __version__
from hostd.api_keys import KeyRing
from hostd.control.codes import (
    INVALID_PARAMS,
    JOB_NOT_FOUND,
    JOB_STATE,
    PRINTER_BUSY,
    SHUTTING_DOWN,
    UPLOAD_REJECTED,
)
from hostd.control.connection import Client
from hostd.control.host import Host
from hostd.control.limits import ConnectionGate, IdleTimer, Limits, Listener, Ticket, listen_tcp
from hostd.control.rpc import Registry, error_for, notification
from hostd.events import EventBus
from hostd.jobs.spool import Staged

log = logging.getLogger(__name__)

BACKLOG = 128
CHUNK = 256 * 1024
"""Bytes of an upload read and written to the spool at a time."""
FIELD_BYTES = 4096
"""Longest form field beside the file (a name, a flag)."""
CLIENT_IDS = 1 << 40
"""WebSocket clients are numbered from here (the control socket's from 1): an upload in
parts is kept by its connection's number."""
OPEN = frozenset({"/api/version"})
"""Paths served without a key."""
STATUS = {INVALID_PARAMS: 400, UPLOAD_REJECTED: 400, JOB_NOT_FOUND: 404, JOB_STATE: 409,
          PRINTER_BUSY: 409, SHUTTING_DOWN: 503}
"""HTTP status of a refusal, by its JSON-RPC code (any other: 500)."""
Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]


class HttpError(Exception):
    """The HTTP API cannot be served (address in use, ...)."""


def json_response(data: Any, status: int = 200) -> web.Response:
    return web.json_response(data, status=status, dumps=lambda d: json.dumps(d, default=str))


def refusal(exc: BaseException) -> web.Response:
    """An exception from the domain as JSON ``{"error": message, "code": rpc code}``, the
    status from :data:`STATUS` (413 for an upload over a limit)."""
    err = error_for(exc)
    status = STATUS.get(err["code"], 500)
    if err["code"] == UPLOAD_REJECTED and "exceeds the limit" in err["message"]:
        status = 413
    return json_response({"error": err["message"], "code": err["code"]}, status)


# -- uploads ----------------------------------------------------------------------------------


@dataclass
class Upload:
    """A multipart upload: the file staged in the spool, its name, and the other fields."""

    name: str
    staged: Staged
    fields: dict[str, str]


class UploadError(Exception):
    """A request that is no upload hostd takes (with its HTTP status)."""

    def __init__(self, message: str, status: int = 400) -> None:
        super().__init__(message)
        self.status = status


async def read_upload(request: web.Request, stage: Callable[[], Staged], limit: int,
                      file_field: str = "file") -> Upload:
    """The multipart form of ``request``: its ``file_field`` written to a staging file of
    the spool as it arrives (at most ``limit`` bytes: 413 past it), the other fields kept
    (short text)."""
    if request.content_length is not None and request.content_length > limit + CHUNK:
        raise UploadError(f"request body of {request.content_length} bytes exceeds the "
                          f"limit of {limit} bytes (http.max_upload_mb)", 413)
    try:
        reader = await request.multipart()
    except (ValueError, AssertionError, KeyError):
        raise UploadError("expected a multipart/form-data body with a "
                          f"{file_field!r} field") from None
    fields: dict[str, str] = {}
    upload: Upload | None = None
    try:
        async for part in reader:
            if not isinstance(part, BodyPartReader):
                continue
            if part.name == file_field and upload is None:
                upload = Upload(part.filename or "upload", stage(), fields)
                await _write_part(part, upload.staged, limit)
            else:
                fields[str(part.name)] = await _field_text(part)
    except (ValueError, AssertionError) as exc:  # a malformed body
        if upload is not None:
            upload.staged.discard()
        raise UploadError(f"malformed multipart body: {exc}") from None
    except BaseException:
        if upload is not None:
            upload.staged.discard()
        raise
    if upload is None:
        raise UploadError(f"no {file_field!r} field in the form")
    return upload


async def _write_part(part: Any, staged: Staged, limit: int) -> None:
    while chunk := await part.read_chunk(CHUNK):
        if staged.size + len(chunk) > limit:
            raise UploadError(f"upload exceeds the limit of {limit} bytes "
                              "(http.max_upload_mb)", 413)
        await asyncio.to_thread(staged.write, chunk)


async def _field_text(part: Any) -> str:
    data = b""
    while chunk := await part.read_chunk(FIELD_BYTES):
        data += chunk
        if len(data) > FIELD_BYTES:
            raise UploadError(f"form field {part.name!r} is longer than {FIELD_BYTES} bytes")
    return data.decode("utf-8", "replace")


# -- connections ------------------------------------------------------------------------------


class _Conn(asyncio.Protocol):
    """One HTTP connection: aiohttp's own protocol within the control socket's limits
    (its place under the gate, the idle timer)."""

    def __init__(self, api: HttpApi, ticket: Ticket, inner: asyncio.Protocol) -> None:
        self.api = api
        self.ticket = ticket
        self.inner = inner
        self.transport: asyncio.Transport | None = None
        self.idle: IdleTimer | None = None
        self.requests = 0
        self.socket: WsClient | None = None
        self.rested_since = -math.inf

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport
        self.ticket.evict = self._evict
        self.api.conns[transport] = self
        self.idle = IdleTimer(self.api.limits.settings.idle_timeout, self._busy, self._idle)
        self.inner.connection_made(transport)

    def data_received(self, data: bytes) -> None:
        """A WebSocket's bytes count against the byte budget until their message is taken
        up (an upload's go to the spool as they come, and count against nothing)."""
        budget = self.api.limits.budget
        if self.socket is not None and not budget.take(self, len(data)):
            self.over_budget(f"{budget.held.get(self, 0) + len(data)} bytes of unfinished "
                             f"messages, the most when daemon.max_buffered_bytes "
                             f"({budget.cap}) ran out")
            return
        self.inner.data_received(data)

    def over_budget(self, reason: str) -> None:
        self.api.limits.budget.give(self)
        self._close("budget", reason)

    def eof_received(self) -> bool | None:
        return self.inner.eof_received()

    def connection_lost(self, exc: Exception | None) -> None:
        self.inner.connection_lost(exc)
        self.api.limits.budget.give(self)
        self.ticket.release()
        if self.idle is not None:
            self.idle.cancel()
        if self.transport is not None:
            self.api.conns.pop(self.transport, None)

    def pause_writing(self) -> None:
        self.inner.pause_writing()

    def resume_writing(self) -> None:
        self.inner.resume_writing()

    def _busy(self) -> bool:
        return bool(self.requests) or (self.socket is not None
                                       and self.socket.client.subscribed is not None)

    def _idle(self) -> None:
        timeout = self.api.limits.settings.idle_timeout
        self._close("idle", f"no whole request for {timeout:g} s (daemon.idle_timeout)")

    def _evict(self, why: str) -> None:
        self._close("room", why)
        self.ticket.release()

    def _close(self, reason: str, why: str) -> None:
        self.api.limits.drop(reason, "HTTP client", why)
        if self.transport is not None:
            self.transport.abort()

    def began(self) -> float:
        """A request starts: how long the connection rested before it (its bytes are no
        longer held for it)."""
        self.api.limits.budget.give(self)
        self.ticket.proven = True
        self.requests += 1
        assert self.idle is not None
        self.idle.touch()
        loop = asyncio.get_running_loop()
        return loop.time() - self.rested_since

    def ended(self) -> None:
        self.requests -= 1
        assert self.idle is not None
        self.idle.touch()
        self.rested_since = asyncio.get_running_loop().time()


class WsClient:
    """A WebSocket's JSON-RPC client: its replies and events through one bounded
    :class:`~hostd.control.limits.Outbox`, sent in order by one task."""

    def __init__(self, api: HttpApi, ws: web.WebSocketResponse, cid: int) -> None:
        self.api = api
        self.ws = ws
        self.client = Client(cid, api)
        self.outbox = api.limits.outbox(self._hand)
        self._ready: asyncio.Queue[bytes] = asyncio.Queue()
        self.dropped = False
        self.closing: asyncio.Task[bool] | None = None
        self.task = asyncio.get_running_loop().create_task(self._send())

    def _hand(self, data: bytes) -> None:
        """The outbox gives one message at a time (it holds the rest until it is sent)."""
        self.outbox.pause()
        self._ready.put_nowait(data)

    async def _send(self) -> None:
        with contextlib.suppress(ConnectionError, RuntimeError):
            while True:
                data = await self._ready.get()
                await self.ws.send_str(data.decode())
                self.outbox.resume()

    def reply(self, text: str) -> None:
        self.outbox.reply(text.rstrip("\n").encode())

    def push(self, data: bytes) -> None:
        if self.dropped:
            return
        if not self.outbox.event(data):
            self.api.limits.events_dropped += 1 + self.outbox.discard()
            self.dropped = self.client.dropped = True
            self.api.limits.drop("slow_reader", f"WebSocket client {self.client.id}",
                                 "not reading its events")
            self.closing = asyncio.get_running_loop().create_task(
                self.ws.close(code=WSCloseCode.POLICY_VIOLATION, message=b"events not read"))

    async def close(self) -> None:
        self.task.cancel()
        await asyncio.gather(self.task, return_exceptions=True)
        for name, hook in self.client.on_close.items():
            try:
                hook()
            except Exception:  # one failing hook must not keep the others from running
                log.exception("WebSocket client %d: closing %s", self.client.id, name)
        self.client.subscribed = None


# -- the server --------------------------------------------------------------------------------


class HttpApi:
    """Serve ``registry`` and the upload endpoints of ``host`` on ``address:port``.

    Parameters
    ----------
    keys
        The API keys.
    max_body
        Largest request body (``http.max_upload_mb``), bytes.
    routes
        More routes (``add(app, api)`` each): the slicers' endpoints, the web page.
    """

    def __init__(self, host: Host, registry: Registry, bus: EventBus, limits: Limits,
                 keys: KeyRing, address: str, port: int, max_body: int,
                 routes: tuple[Callable[[web.Application, HttpApi], None], ...] = ()) -> None:
        self.host = host
        self.registry = registry
        self.limits = limits
        self.keys = keys
        self.address = address
        self.port = port
        self.max_body = max_body
        self.subscribers = 0
        self.conns: dict[asyncio.BaseTransport, _Conn] = {}
        self.sockets: set[WsClient] = set()
        self.requests = 0
        self.refused_keys = 0
        self._ids = itertools.count(CLIENT_IDS)
        self._unsubscribe = bus.subscribe(self._broadcast)
        self._runner: web.AppRunner | None = None
        self._listener: Listener | None = None
        self._sock: Any = None
        self.app = web.Application(middlewares=[self._limited, self._keyed],
                                   client_max_size=max_body)
        self.app.router.add_get("/api/version", self.version)
        self.app.router.add_get("/websocket", self.websocket)
        self.app.router.add_post("/api/jobs", self.upload)
        for add in routes:
            add(self.app, self)

    async def start(self) -> None:
        try:
            self._sock = listen_tcp(self.address, self.port, BACKLOG)
        except OSError as exc:
            self._unsubscribe()
            raise HttpError(f"http: cannot listen on {self.address}:{self.port}: "
                            f"{exc.strerror or exc}") from None
        self._runner = web.AppRunner(self.app, access_log=None, handle_signals=False,
                                     keepalive_timeout=self.limits.settings.idle_timeout)
        await self._runner.setup()
        server = self._runner.server
        assert server is not None
        self._listener = Listener(self._sock, self.limits.gate,
                                  lambda ticket: _Conn(self, ticket, server()), _refusal)
        self._listener.start()
        log.info("HTTP API on %s:%d", self.address, self.bound_port)

    @property
    def bound_port(self) -> int:
        return int(self._sock.getsockname()[1]) if self._sock is not None else self.port

    async def close(self) -> None:
        self._unsubscribe()
        if self._listener is not None:
            self._listener.close()
        for ws in list(self.sockets):
            await ws.ws.close(code=1001, message=b"hostd stops")
        if self._runner is not None:
            await self._runner.cleanup()
        if self._sock is not None:
            self._sock.close()

    # -- middlewares -------------------------------------------------------------------------

    @web.middleware
    async def _limited(self, request: web.Request, handler: Handler) -> web.StreamResponse:
        """Every request in its turn, and counted as busy for its connection's idle timer."""
        conn = self.conns.get(request.transport) if request.transport else None
        rested = conn.began() if conn is not None else math.inf
        try:
            await self.limits.turns.take(rested)
            self.requests += 1
            return await handler(request)
        finally:
            if conn is not None:
                conn.ended()

    @web.middleware
    async def _keyed(self, request: web.Request, handler: Handler) -> web.StreamResponse:
        if request.path in OPEN and request.method in ("GET", "HEAD"):
            return await handler(request)
        given = request.headers.get("X-Api-Key") or request.query.get("apikey")
        if not self.keys.valid(given):
            self.refused_keys += 1
            why = ("no API key (X-Api-Key header or ?apikey=)" if not given
                   else "wrong API key")
            if self.keys.error is not None:
                why += f"; {self.keys.error}"
            return json_response({"error": why}, 401)
        return await handler(request)

    # -- routes ------------------------------------------------------------------------------

    async def version(self, request: web.Request) -> web.Response:
        """OctoPrint's ``/api/version`` (slicers ask it before an upload)."""
        return json_response({"api": "0.1", "server": "1.10.0",
                              "text": f"OctoPrint (hostd {__version__})"})

    async def upload(self, request: web.Request) -> web.Response:
        """``POST /api/jobs``: the file of a form queued as a job (201, the job)."""
        try:
            up = await self.read_upload(request)
        except UploadError as exc:
            return json_response({"error": str(exc)}, exc.status)
        kind = up.fields.get("kind") or None
        job = await self.submit(up, up.name, kind)
        return job if isinstance(job, web.Response) else json_response(job, 201)

    async def read_upload(self, request: web.Request, file_field: str = "file") -> Upload:
        limit = min(self.max_body, self.host.max_upload_bytes)
        return await read_upload(request, self.host.jobs.stage, limit, file_field)

    async def submit(self, up: Upload, name: str, kind: str | None
                     ) -> dict[str, Any] | web.Response:
        """Queue a staged upload as ``job.submit`` does: the job as JSON, or the refusal."""
        jobs = self.host.jobs
        try:
            return jobs.job_dict(await jobs.submit_staged(name, up.staged, kind))
        except Exception as exc:  # the domain's refusals, mapped as the socket's are
            return refusal(exc)

    async def websocket(self, request: web.Request) -> web.StreamResponse:
        ws = web.WebSocketResponse(max_msg_size=self.limits.settings.max_request_bytes)
        await ws.prepare(request)
        conn = self.conns.get(request.transport) if request.transport else None
        sock = WsClient(self, ws, next(self._ids))
        self.sockets.add(sock)
        if conn is not None:
            conn.socket = sock
        try:
            async for msg in ws:
                if msg.type is WSMsgType.TEXT:
                    await self._rpc(sock, conn, msg.data)
                elif msg.type is WSMsgType.BINARY:
                    await self._rpc(sock, conn, msg.data)
                elif msg.type is WSMsgType.ERROR:
                    self._ws_error(sock, ws.exception())
        finally:
            self.sockets.discard(sock)
            await sock.close()
        return ws

    async def _rpc(self, sock: WsClient, conn: _Conn | None, data: str | bytes) -> None:
        rested = conn.began() if conn is not None else math.inf
        try:
            await self.limits.turns.take(rested)
            self.requests += 1
            reply = await self.registry.dispatch(data, sock.client)
        finally:
            if conn is not None:
                conn.ended()
        if reply is not None:
            sock.reply(reply)

    def _ws_error(self, sock: WsClient, exc: BaseException | None) -> None:
        limit = self.limits.settings.max_request_bytes
        if getattr(exc, "code", None) == WSCloseCode.MESSAGE_TOO_BIG:
            self.limits.drop("too_large", f"WebSocket client {sock.client.id}",
                             f"a message over {limit} bytes (daemon.max_request_bytes)")

    def _broadcast(self, name: str, data: dict[str, Any]) -> None:
        line: bytes | None = None
        for sock in list(self.sockets):
            if sock.client.wants(name):
                if line is None:
                    line = json.dumps(notification("notify_" + name.replace(".", "_"),
                                                   {"event": name, **data}),
                                      separators=(",", ":")).encode()
                sock.push(line)

    def status(self) -> dict[str, Any]:
        return {"address": self.address, "port": self.bound_port, "clients": len(self.conns),
                "websockets": len(self.sockets), "subscribed": self.subscribers,
                "requests_total": self.requests, "refused_keys_total": self.refused_keys,
                "api_keys": self.keys.count(), "key_file_error": self.keys.error}


def _refusal(gate: ConnectionGate) -> bytes:
    """What a connection refused at the cap gets: 503, the reason as JSON."""
    body = json.dumps({"error": gate.refusal()}).encode()
    return (b"HTTP/1.1 503 Service Unavailable\r\nContent-Type: application/json\r\n"
            b"Connection: close\r\nContent-Length: " + str(len(body)).encode() + b"\r\n\r\n"
            + body)
