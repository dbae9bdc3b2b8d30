"""The limits of the control socket (issues 37 and 38): cap, idle timeout, budget, turns,
and the listener's accept failures. Each test asserts what a client sees and what the
daemon counts, in-process, with limits small enough to reach."""

from __future__ import annotations

import asyncio
import errno
import json
import logging
import socket
from pathlib import Path

import pytest

from hostd.control.limits import Limits, LimitSettings, Listener, Turns
from hostd.control.rpc import Registry
from hostd.control.server import ControlServer
from hostd.events import EventBus

pytestmark = pytest.mark.asyncio


def registry() -> Registry:
    reg = Registry()

    async def echo(ctx, text: str) -> str:
        return text

    async def sub(ctx) -> str:
        ctx.subscribe(None)
        return "ok"

    reg.add("echo", echo, *_param("text"))
    reg.add("sub", sub)
    return reg


def _param(name: str):  # type: ignore[no-untyped-def]
    from hostd.control.rpc import Param

    return (Param(name, "str"),)


async def serve(tmp_path: Path, **settings: object) -> tuple[ControlServer, Limits]:
    limits = Limits(LimitSettings(**settings))  # type: ignore[arg-type]
    server = ControlServer(tmp_path / "s.sock", registry(), EventBus(), limits)
    await server.start()
    return server, limits


async def connect(server: ControlServer) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
    return await asyncio.open_unix_connection(str(server.path), limit=1 << 21)


async def ask(r: asyncio.StreamReader, w: asyncio.StreamWriter, method: str = "echo",
              params: dict | None = None) -> dict:
    w.write(json.dumps({"jsonrpc": "2.0", "id": 1, "method": method,
                        "params": {"text": "z"} if params is None else params}).encode()
            + b"\n")
    await w.drain()
    return json.loads(await r.readline())


async def test_at_the_cap_a_new_connection_gets_a_clear_error(tmp_path):
    server, limits = await serve(tmp_path, max_connections=3)
    async with asyncio.timeout(10):
        clients = [await connect(server) for _ in range(3)]
        for r, w in clients:  # each has asked something: none is closed to make room
            assert (await ask(r, w))["result"] == "z"
        r, w = await connect(server)
        refusal = json.loads(await r.readline())
        assert refusal["error"]["code"] == -32009
        assert "daemon.max_connections (3)" in refusal["error"]["message"]
        assert await r.read() == b""
        w.close()
        assert limits.status()["refused"] == 1 and limits.status()["open"] == 3
        for r, w in clients:  # the others carry on
            assert (await ask(r, w))["result"] == "z"
            w.close()
        await server.close()


async def test_a_silent_connection_makes_room_for_a_new_one(tmp_path):
    """A client that only connects (slow loris) cannot hold the last place."""
    server, limits = await serve(tmp_path, max_connections=2)
    async with asyncio.timeout(10):
        busy = await connect(server)
        assert (await ask(*busy))["result"] == "z"
        silent_r, silent_w = await connect(server)
        new = await connect(server)
        assert (await ask(*new))["result"] == "z"
        closed = json.loads(await silent_r.readline())
        assert closed["error"]["code"] == -32009 and "make room" in closed["error"]["message"]
        assert await silent_r.read() == b""
        assert limits.status()["dropped"]["room"] == 1 and limits.status()["refused"] == 0
        for _, w in (busy, new, (silent_r, silent_w)):
            w.close()
        await server.close()


async def test_an_idle_connection_is_closed_but_not_a_subscriber(tmp_path, caplog):
    """A byte now and then keeps no connection open; a subscriber waits for events as long
    as it likes."""
    server, limits = await serve(tmp_path, idle_timeout=0.3)
    async with asyncio.timeout(10):
        sub_r, sub_w = await connect(server)
        assert (await ask(sub_r, sub_w, "sub", {}))["result"] == "ok"
        loris_r, loris_w = await connect(server)
        ended = asyncio.ensure_future(loris_r.read())
        with caplog.at_level(logging.WARNING, logger="hostd.control.limits"):
            for byte in b'{"jsonrpc": "2.0", "id": 1, "method": "echo"':
                if ended.done():
                    break
                loris_w.write(bytes([byte]))
                await asyncio.wait({ended}, timeout=0.05)  # a byte each 50 ms
            closing = await ended
        assert b"daemon.idle_timeout" in closing
        assert limits.status()["dropped"]["idle"] == 1
        assert any("no whole request" in r.getMessage() for r in caplog.records)
        assert (await ask(sub_r, sub_w))["result"] == "z"  # subscribed all along
        sub_w.close()
        loris_w.close()
        await server.close()


async def test_the_budget_drops_the_connection_holding_the_most(tmp_path):
    """Issue 38: bytes of unfinished requests count against one total; over it, the
    connection holding the most is dropped, and the others' requests go on."""
    server, limits = await serve(tmp_path, max_request_bytes=600_000,
                                 max_buffered_bytes=1_000_000)
    async with asyncio.timeout(10):
        small = [await connect(server) for _ in range(2)]
        big_r, big_w = await connect(server)
        big_w.write(b'{"jsonrpc": "2.0", "id": 1, "method": "echo", "params": ["' +
                    b"x" * 500_000)
        await big_w.drain()
        for _, w in small:
            w.write(b'{"jsonrpc": "2.0", "id": 1, "method": "echo", "params": ["' +
                    b"y" * 300_000)
            await w.drain()
        assert await big_r.read() == b""  # dropped at once: nothing more is read of it
        for r, w in small:
            w.write(b'"]}\n')
            await w.drain()
            assert len(json.loads(await r.readline())["result"]) == 300_000
            w.close()
        status = limits.status()
        assert status["dropped"]["budget"] == 1 and status["buffered_bytes"] == 0
        big_w.close()
        await server.close()


async def test_requests_take_turns_one_a_pass_and_a_polite_one_goes_first():
    """Between two requests the loop makes a pass (the serial port's callbacks run), and a
    client that rested goes before clients that ask back to back."""
    turns = Turns(share=1.0)  # no rest: the order alone
    loop = asyncio.get_running_loop()
    passes = 0

    def count() -> None:  # one call a pass of the loop, as a port's reader runs
        nonlocal passes
        passes += 1
        if not done.done():
            loop.call_soon(count)

    done = loop.create_future()
    loop.call_soon(count)
    granted: list[tuple[str, int]] = []

    async def request(name: str, rested: float) -> None:
        await turns.take(rested)
        granted.append((name, passes))

    async with asyncio.timeout(5):
        flood = [asyncio.ensure_future(request(f"flood{i}", 0.0)) for i in range(20)]
        await asyncio.sleep(0)  # the flood has asked
        polite = asyncio.ensure_future(request("polite", 0.5))
        await asyncio.gather(*flood, polite)
        done.set_result(None)
    names = [n for n, _ in granted]
    assert names.index("polite") <= 2  # after the turns under way at most
    at = [p for _, p in granted]
    assert len(set(at)) == len(at)  # never two in one pass


async def test_requests_rest_for_their_share_of_the_loop():
    """While requests wait, each turn is followed by a rest three times as long (share 1/4):
    a flood gets about a quarter of the loop, the rest is idle for the port."""
    turns = Turns(share=0.25)
    loop = asyncio.get_running_loop()
    busy = 0.0

    async def request() -> None:
        nonlocal busy
        await turns.take(0.0)
        t0 = loop.time()
        while loop.time() - t0 < 0.002:  # a request's work: 2 ms
            pass
        busy += loop.time() - t0

    async with asyncio.timeout(10):
        t0 = loop.time()
        await asyncio.gather(*(request() for _ in range(40)))
        elapsed = loop.time() - t0
    assert busy / elapsed < 0.4, (busy, elapsed)


class FailingSocket:
    """A listening socket whose accept fails as with no open files left."""

    def __init__(self, real: socket.socket) -> None:
        self.real = real
        self.accepts = 0

    def fileno(self) -> int:
        return self.real.fileno()

    def setblocking(self, flag: bool) -> None:
        self.real.setblocking(flag)

    def accept(self) -> tuple[socket.socket, object]:
        self.accepts += 1
        raise OSError(errno.EMFILE, "Too many open files")


async def test_accept_out_of_files_pauses_and_logs_once(tmp_path, caplog):
    """Issue 38: asyncio's accept loop logged a traceback for each connection waiting and
    retried at once (109,000 tracebacks in a minute). The listener logs one line, pauses
    accepting, and logs again at most once a minute."""
    limits = Limits(LimitSettings())
    real = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    real.bind(str(tmp_path / "l.sock"))
    real.listen()
    sock = FailingSocket(real)
    listener = Listener(sock, limits.gate, lambda t: asyncio.Protocol(),  # type: ignore[arg-type]
                        lambda g: b"")
    clients = []
    async with asyncio.timeout(10):
        with caplog.at_level(logging.WARNING, logger="hostd.control.limits"):
            listener.start()
            for _ in range(20):
                c = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
                c.connect(str(tmp_path / "l.sock"))
                clients.append(c)
            await asyncio.sleep(1.5)  # a pause and its retry: the window measured
    listener.close()
    for c in clients:
        c.close()
    real.close()
    lines = [r for r in caplog.records if "accept failed" in r.getMessage()]
    assert len(lines) == 1 and not lines[0].exc_info
    assert "LimitNOFILE" in lines[0].getMessage()
    assert 2 <= sock.accepts <= 3 and listener.accept_failures == sock.accepts


async def test_hostctl_says_why_it_was_refused(tmp_path):
    """hostctl at the cap: the daemon's reason, exit 4, whether its request went out or not."""
    from hostd.cli.client import Client, RpcFailure
    from hostd.cli.errors import EXIT_REFUSED

    server, _ = await serve(tmp_path, max_connections=1)
    async with asyncio.timeout(10):
        r, w = await connect(server)
        assert (await ask(r, w))["result"] == "z"

        def call() -> RpcFailure:
            with Client(str(server.path)) as c, pytest.raises(RpcFailure) as caught:
                c.call("echo", text="z")
            return caught.value

        refused = await asyncio.to_thread(call)
        assert refused.rpc_code == -32009 and refused.code == EXIT_REFUSED
        assert "daemon.max_connections (1)" in str(refused)
        w.close()
        await server.close()
