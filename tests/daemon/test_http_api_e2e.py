"""The HTTP and WebSocket API (issue 36, item 1) against a hostd subprocess on sim://: the
control socket's methods and events over a WebSocket (one registry), uploads over HTTP with
the socket's checks and errors, API keys (401 without one, except GET /api/version), the
body cap, the key file read again when hostctl api-key changes it, and the limits."""

from __future__ import annotations

import asyncio
import json
import socket
from pathlib import Path
from typing import Any

import aiohttp
import pytest
from hostd_harness import DaemonProc, free_port, hostctl, make_gcode

pytestmark = pytest.mark.asyncio


def http_daemon(tmp: Path, **overrides: Any) -> tuple[DaemonProc, str, str]:
    """A daemon with the HTTP API on a free port, and a key made by hostctl's code."""
    from hostd import api_keys

    keys = tmp / "api-keys"
    key = api_keys.new(keys, "tests").key
    port = free_port()
    d = DaemonProc(tmp, http__enabled=True, http__port=port, http__api_key_file=str(keys),
                   **overrides)
    return d, f"http://127.0.0.1:{port}", key


def form(name: str, data: bytes, **fields: str) -> aiohttp.FormData:
    body = aiohttp.FormData()
    for key, value in fields.items():
        body.add_field(key, value)
    body.add_field("file", data, filename=name, content_type="application/octet-stream")
    return body


class WsRpc:
    """JSON-RPC 2.0 over the daemon's WebSocket."""

    def __init__(self, ws: aiohttp.ClientWebSocketResponse) -> None:
        self.ws = ws
        self.next_id = 0
        self.events: list[dict[str, Any]] = []

    async def call(self, method: str, **params: Any) -> dict[str, Any]:
        self.next_id += 1
        await self.ws.send_str(json.dumps({"jsonrpc": "2.0", "id": self.next_id,
                                           "method": method, "params": params}))
        while True:
            msg = json.loads((await self.ws.receive()).data)
            if msg.get("id") == self.next_id:
                return msg
            self.events.append(msg)

    async def until(self, pred: Any) -> dict[str, Any]:
        for ev in self.events:
            if pred(ev):
                return ev
        while True:
            msg = json.loads((await self.ws.receive()).data)
            if "method" in msg:
                self.events.append(msg)
                if pred(msg):
                    return msg


async def test_the_websocket_serves_the_sockets_methods_and_events_and_prints_a_job(tmp_path):
    d, url, key = http_daemon(tmp_path)
    async with asyncio.timeout(90):
        await d.start()
        try:
            async with aiohttp.ClientSession() as http:
                async with http.ws_connect(f"{url}/websocket?apikey={key}") as ws:
                    rpc = WsRpc(ws)
                    info = (await rpc.call("server.info"))["result"]
                    sock = await d.rpc()
                    assert info["methods"] == (await sock.call("server.info"))["methods"]
                    await sock.close()
                    assert (await rpc.call("events.subscribe"))["result"] == {
                        "subscribed": "all"}
                    job = (await rpc.call("job.submit", name="part.gcode", encoding="text",
                                          data=make_gcode(subparts=2, layers=2)))["result"]
                    done = await rpc.until(lambda m: m["method"] == "notify_job_state"
                                           and m["params"]["new"] == "completed")
                    assert done["params"]["job_id"] == job["id"]
                    assert any(m["method"] == "notify_job_progress" for m in rpc.events)
                    bad = await rpc.call("job.get", id=99)
                    assert bad["error"]["code"] == -32001
                    garbled = await ws.send_str("{not json") or json.loads(
                        (await ws.receive()).data)
                    assert garbled["error"]["code"] == -32700
        finally:
            await d.stop()
    assert not d.loop_errors()


async def test_a_websocket_message_over_the_request_limit_closes_it_as_too_big(tmp_path):
    d, url, key = http_daemon(tmp_path, daemon__max_request_bytes=393216)
    async with asyncio.timeout(60):
        await d.start()
        try:
            async with aiohttp.ClientSession() as http:
                async with http.ws_connect(f"{url}/websocket?apikey={key}") as ws:
                    await ws.send_str("[" + " " * 400_000 + "]")
                    closed = await ws.receive()
                    assert closed.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED)
                    assert ws.close_code == aiohttp.WSCloseCode.MESSAGE_TOO_BIG
        finally:
            await d.stop()
    assert any("dropped: a message over 393216 bytes" in line for line in d.stderr)


async def raw_websocket(port: int, key: str) -> tuple[asyncio.StreamReader,
                                                      asyncio.StreamWriter]:
    """A WebSocket opened by hand (its frames are written by the test)."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(f"GET /websocket?apikey={key} HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\n"
                 "Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
                 "Sec-WebSocket-Version: 13\r\n\r\n".encode())
    assert (await reader.readuntil(b"\r\n\r\n")).startswith(b"HTTP/1.1 101")
    return reader, writer


def text_frame_head(length: int) -> bytes:
    """A client's text frame of ``length`` bytes: 64-bit length, mask key 0 (the payload
    goes as it is)."""
    return bytes([0x81, 0x80 | 127]) + length.to_bytes(8, "big") + bytes(4)


async def test_unfinished_websocket_messages_count_against_the_byte_budget(tmp_path):
    """The connection holding the most unfinished bytes is dropped when the budget across
    connections runs out (as on the control socket), not the one that comes next."""
    d, url, key = http_daemon(tmp_path, daemon__max_request_bytes=393216,
                              daemon__max_buffered_bytes=393216)
    port = int(url.rsplit(":", 1)[1])
    async with asyncio.timeout(60):
        await d.start()
        try:
            big_r, big_w = await raw_websocket(port, key)
            big_w.write(text_frame_head(300_000) + b" " * 250_000)
            await big_w.drain()
            small_r, small_w = await raw_websocket(port, key)
            small_w.write(text_frame_head(300_000))
            for _ in range(4):  # past the budget, while it holds less than the other
                small_w.write(b" " * 50_000)
                await small_w.drain()
            assert await big_r.read() == b""  # dropped, holding the most
            small_w.write(b" " * 100_000)  # the rest of its message: blanks are no JSON
            reply = await small_r.read(200)
            big_w.close()
            small_w.close()
        finally:
            await d.stop()
    assert b"parse error" in reply
    assert any("HTTP client dropped: " in line and "bytes of unfinished requests, the most "
               "when the daemon.max_buffered_bytes (393216)" in line for line in d.stderr)


async def test_every_request_needs_a_key_but_the_version(tmp_path):
    d, url, key = http_daemon(tmp_path)
    async with asyncio.timeout(60):
        await d.start()
        try:
            async with aiohttp.ClientSession() as http:
                async with http.get(f"{url}/api/version") as r:
                    assert r.status == 200
                    version = await r.json()
                assert version["api"] == "0.1" and version["text"].startswith("OctoPrint")
                for headers, query in (({}, ""), ({"X-Api-Key": "nope"}, ""),
                                       ({}, "?apikey=nope")):
                    async with http.post(f"{url}/api/jobs{query}", headers=headers,
                                         data=form("p.gcode", b"G28\n")) as r:
                        assert r.status == 401, await r.text()
                    async with http.get(f"{url}/websocket{query}", headers=headers) as r:
                        assert r.status == 401
                async with http.post(f"{url}/api/jobs?apikey={key}",
                                     data=form("p.gcode", b"G28\n")) as r:
                    assert r.status == 201
                    assert (await r.json())["state"] in ("ready", "printing", "completed")
        finally:
            await d.stop()


async def test_uploads_take_the_sockets_checks_and_errors_and_the_body_cap(tmp_path):
    d, url, key = http_daemon(tmp_path, http__max_upload_mb=1)
    far = "G28\nG1 X9000 F600\n"  # beyond machine.x_range
    async with asyncio.timeout(60):
        await d.start()
        try:
            sock = await d.rpc()
            said = await sock.raw("job.submit", name="far.gcode", data=far, encoding="text")
            await sock.close()
            headers = {"X-Api-Key": key}
            async with aiohttp.ClientSession(headers=headers) as http:
                async with http.post(f"{url}/api/jobs", data=form("far.gcode",
                                                                  far.encode())) as r:
                    assert r.status == 400
                    assert await r.json() == {"error": said["error"]["message"],
                                              "code": said["error"]["code"]}
                async with http.post(f"{url}/api/jobs", data=form("e.gcode", b"")) as r:
                    assert r.status == 400 and (await r.json())["error"] == (
                        "e.gcode: empty upload")
                big = b"G1 X1\n" * 200_000  # 1.2 MB: over http.max_upload_mb 1
                async with http.post(f"{url}/api/jobs", data=form("big.gcode", big)) as r:
                    assert r.status == 413, await r.text()
                async with http.post(f"{url}/api/jobs", data=b"G28\n") as r:
                    assert r.status == 400 and "multipart" in (await r.json())["error"]
            spool = [p.name for p in (tmp_path / "state" / "spool").iterdir()]
        finally:
            await d.stop()
    assert spool == [] and not d.loop_errors()  # nothing staged is left behind


async def test_hostctl_api_key_new_list_and_revoke_take_effect_without_a_restart(tmp_path):
    d, url, _ = http_daemon(tmp_path)
    keys = str(tmp_path / "api-keys")
    async with asyncio.timeout(60):
        await d.start()
        try:
            rc, out, err = await hostctl(d.socket, "api-key", "new", "--label", "PrusaSlicer",
                                         "--file", keys, "--json")
            assert rc == 0, err
            made = json.loads(out)
            async with aiohttp.ClientSession(headers={"X-Api-Key": made["key"]}) as http:
                async with http.get(f"{url}/websocket") as r:
                    assert r.status != 401  # (400: not a WebSocket handshake)
                rc, out, _ = await hostctl(d.socket, "api-key", "list", "--file", keys)
                assert rc == 0 and f"{made['key'][:8]}…  PrusaSlicer" in out
                assert made["key"] not in out  # listed by its first digits only
                rc, out, _ = await hostctl(d.socket, "api-key", "revoke", made["key"][:8],
                                           "--file", keys)
                assert rc == 0 and out.startswith(f"revoked {made['key'][:8]}")
                async with http.get(f"{url}/websocket") as r:
                    assert r.status == 401
                rc, _, err = await hostctl(d.socket, "api-key", "revoke", "zzzz", "--file",
                                           keys)
                assert rc == 2 and err.startswith("hostctl: 'zzzz': no such key in ")
        finally:
            await d.stop()


async def test_a_silent_http_connection_is_closed_after_the_idle_timeout(tmp_path):
    d, url, _ = http_daemon(tmp_path, daemon__idle_timeout=1)
    port = int(url.rsplit(":", 1)[1])
    async with asyncio.timeout(30):
        await d.start()
        try:
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
            writer.write(b"GET /api/version HTTP/1.1\r\nHost: x\r\n")  # never finished
            assert await reader.read() == b""  # closed by the daemon
            writer.close()
        finally:
            await d.stop()
    assert any("HTTP client dropped: no whole request for 1 s" in line for line in d.stderr)


async def test_a_port_in_use_stops_hostd_naming_the_key(tmp_path):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        d = DaemonProc(tmp_path, http__enabled=True, http__port=port)
        async with asyncio.timeout(30):
            with pytest.raises(RuntimeError) as err:
                await d.start()
    assert f"http: cannot listen on 127.0.0.1:{port}: " in str(err.value)
    assert "(http.port)" in str(err.value)
