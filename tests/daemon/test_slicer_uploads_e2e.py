"""Send to printer from slicers (issue 36, item 2): the requests those clients send, byte for
byte in what matters (method, path, headers, the form's fields in their order and their part
headers), against a hostd subprocess on sim://.

Read from the clients' sources (not copied):
- PrusaSlicer, src/slic3r/Utils/OctoPrint.cpp (prusa3d/PrusaSlicer): ``OctoPrint::test``
  asks ``GET api/version`` with ``X-Api-Key`` and wants an ``api`` key and a ``text`` that
  starts with "OctoPrint"; ``upload_inner_with_host`` posts ``api/files/local`` through
  libcurl with the form fields ``print`` ("true"/"false"), ``path`` (the folder, often empty)
  and ``file`` (the file part, application/octet-stream); libcurl adds ``Expect:
  100-continue`` and waits for the interim answer before the body.
- SuperSlicer (supermerill/SuperSlicer) and OrcaSlicer (SoftFever/OrcaSlicer), the same file:
  the same requests (their OctoPrint host types descend from PrusaSlicer's).
- Cura's OctoPrint plugin, OctoPrintOutputDevice.py ``_sendPrintJob``
  (fieldOfView/Cura-OctoPrintPlugin): a Qt multipart form to ``api/files/local`` with
  ``path`` (text/plain), ``file``, then ``select`` and ``print`` ("true") when it prints.
- Moonraker's clients: Fluidd's src/api/httpClientActions.ts ``serverFilesUploadPost``
  (fluidd-core/fluidd) posts ``/server/files/upload`` with ``file``, ``path``, ``root``
  ("gcodes") and ``print`` ("true") from a browser FormData; Moonraker's docs/web_api.md
  (Arksine/moonraker) adds the optional ``checksum`` (sha256), refused with 422 when wrong.
"""

from __future__ import annotations

import asyncio
import hashlib
import json
import secrets
from pathlib import Path
from typing import Any

import pytest
import trimesh
from hostd_harness import DaemonProc, free_port, make_gcode
from mesh_files import IDENTITY, three_mf

from slicer.mesh.samples import cylinder

pytestmark = pytest.mark.asyncio
CRLF = b"\r\n"


def part(name: str, data: bytes, filename: str | None = None,
         content_type: str | None = None) -> bytes:
    """One part of a multipart/form-data body (without its boundary line)."""
    disposition = f'Content-Disposition: form-data; name="{name}"'
    if filename is not None:
        disposition += f'; filename="{filename}"'
    head = [disposition] + ([f"Content-Type: {content_type}"] if content_type else [])
    return CRLF.join(h.encode() for h in head) + CRLF + CRLF + data


def form_body(boundary: str, parts: list[bytes]) -> bytes:
    b = boundary.encode()
    return b"".join(b"--" + b + CRLF + p + CRLF for p in parts) + b"--" + b + b"--" + CRLF


class Http:
    """Requests written by hand on a TCP connection, as a client library would write them."""

    def __init__(self, port: int) -> None:
        self.port = port

    async def request(self, head: list[str], body: bytes = b"", expect_continue: bool = False
                      ) -> tuple[int, dict[str, Any]]:
        reader, writer = await asyncio.open_connection("127.0.0.1", self.port)
        writer.write(("\r\n".join(head) + "\r\n\r\n").encode())
        if expect_continue:  # libcurl: the body only after the server's 100 Continue
            interim = await reader.readuntil(b"\r\n\r\n")
            assert interim.startswith(b"HTTP/1.1 100 Continue"), interim
        writer.write(body)
        await writer.drain()
        status_line = await reader.readuntil(CRLF)
        headers = (await reader.readuntil(CRLF + CRLF)).decode().lower()
        length = int(headers.split("content-length:")[1].split("\r\n")[0])
        payload = await reader.readexactly(length)
        writer.close()
        return int(status_line.split()[1]), json.loads(payload)


def prusaslicer_version(port: int, key: str) -> list[str]:
    return ["GET /api/version HTTP/1.1", f"Host: 127.0.0.1:{port}",
            "User-Agent: PrusaSlicer/2.8.1", "Accept: */*", f"X-Api-Key: {key}"]


def prusaslicer_upload(port: int, key: str, filename: str, data: bytes, print_: bool,
                       agent: str = "PrusaSlicer/2.8.1") -> tuple[list[str], bytes]:
    boundary = "------------------------" + secrets.token_hex(8)
    body = form_body(boundary, [part("print", b"true" if print_ else b"false"),
                                part("path", b""),
                                part("file", data, filename, "application/octet-stream")])
    return (["POST /api/files/local HTTP/1.1", f"Host: 127.0.0.1:{port}",
             f"User-Agent: {agent}", "Accept: */*", f"X-Api-Key: {key}",
             f"Content-Length: {len(body)}",
             f"Content-Type: multipart/form-data; boundary={boundary}",
             "Expect: 100-continue"], body)


def cura_upload(port: int, key: str, filename: str, data: bytes) -> tuple[list[str], bytes]:
    boundary = "boundary_.oOo._" + secrets.token_urlsafe(24)
    body = form_body(boundary, [part("path", b"", None, "text/plain"),
                                part("file", data, filename, "application/octet-stream"),
                                part("select", b"true", None, "text/plain"),
                                part("print", b"true", None, "text/plain")])
    return (["POST /api/files/local HTTP/1.1", f"Host: 127.0.0.1:{port}",
             f"X-Api-Key: {key}", "User-Agent: Cura/5.8.0 OctoPrintPlugin/3.8.0",
             "MIME-Version: 1.0", f"Content-Type: multipart/form-data; boundary={boundary}",
             f"Content-Length: {len(body)}", "Connection: Keep-Alive",
             "Accept-Encoding: gzip, deflate"], body)


def fluidd_upload(port: int, key: str, filename: str, data: bytes,
                  checksum: str | None = None) -> tuple[list[str], bytes]:
    boundary = "----WebKitFormBoundary" + secrets.token_urlsafe(12)
    fields = [part("file", data, filename, "application/octet-stream"), part("path", b""),
              part("root", b"gcodes"), part("print", b"true")]
    if checksum is not None:
        fields.append(part("checksum", checksum.encode()))
    body = form_body(boundary, fields)
    return (["POST /server/files/upload HTTP/1.1", f"Host: 127.0.0.1:{port}",
             "Accept: application/json, text/plain, */*", f"X-Api-Key: {key}",
             f"Content-Type: multipart/form-data; boundary={boundary}",
             f"Content-Length: {len(body)}", "Origin: http://127.0.0.1"], body)


def slicer_daemon(tmp: Path) -> tuple[DaemonProc, int, str]:
    from hostd import api_keys

    keys = tmp / "api-keys"
    key = api_keys.new(keys, "slicers").key
    port = free_port()
    return (DaemonProc(tmp, http__enabled=True, http__port=port,
                       http__api_key_file=str(keys)), port, key)


async def test_octoprint_clients_send_gcode_stl_and_3mf_that_become_jobs(tmp_path):
    d, port, key = slicer_daemon(tmp_path)
    http = Http(port)
    gcode = make_gcode(subparts=2, layers=2, per_layer=10).encode()
    box = trimesh.creation.box((20.0, 20.0, 10.0))
    stl = trimesh.exchange.stl.export_stl(box)
    peg = three_mf(cylinder(radius=6.0, height=12.0), None, [IDENTITY])
    async with asyncio.timeout(180):
        await d.start()
        try:
            c = await d.rpc()
            await c.call("events.subscribe", events=["job.state"])
            status, version = await http.request(prusaslicer_version(port, key))
            assert status == 200 and "api" in version
            assert version["text"].startswith("OctoPrint")
            status, sent = await http.request(
                *prusaslicer_upload(port, key, "part.gcode", gcode, True),
                expect_continue=True)
            assert status == 201, sent
            assert sent["done"] is True and sent["effectivePrint"] is True
            assert sent["files"]["local"]["name"] == "part.gcode"
            await c.until_state(sent["job"]["id"], "completed")
            status, orca = await http.request(
                *prusaslicer_upload(port, key, "peg.3mf", peg, True, "OrcaSlicer/2.2.0"),
                expect_continue=True)
            assert status == 201, orca
            await c.until_state(orca["job"]["id"], "completed")
            status, cura = await http.request(*cura_upload(port, key, "cura.gcode", gcode))
            assert status == 201 and cura["effectivePrint"] is True, cura
            await c.until_state(cura["job"]["id"], "completed")
            status, superslicer = await http.request(
                *prusaslicer_upload(port, key, "box.stl", stl, False, "SuperSlicer/2.5.59"),
                expect_continue=True)
            assert status == 201 and superslicer["effectivePrint"] is False, superslicer
            await c.until_state(superslicer["job"]["id"], "ready")
            queue = await c.call("queue.status")
            peg_job = await c.call("job.get", id=orca["job"]["id"])
            await c.close()
        finally:
            await d.stop()
    assert peg_job["info"]["format"] == "3mf" and peg_job["info"]["summary"]["filament_mm"] > 0
    # "Upload" without print: kept, and held until the operator starts it
    assert queue["held"] and queue["ready"] == 1
    assert queue["reason"].startswith(f"uploaded without print (job {superslicer['job']['id']}")


async def test_moonraker_clients_upload_with_and_without_a_checksum(tmp_path):
    d, port, key = slicer_daemon(tmp_path)
    http = Http(port)
    gcode = make_gcode(subparts=1, layers=2, per_layer=10).encode()
    async with asyncio.timeout(90):
        await d.start()
        try:
            c = await d.rpc()
            await c.call("events.subscribe", events=["job.state"])
            status, sent = await http.request(*fluidd_upload(port, key, "fluidd.gcode", gcode))
            assert status == 201, sent
            result = sent["result"]
            assert result["item"] == {"path": "fluidd.gcode", "root": "gcodes",
                                      "size": len(gcode)}
            assert result["action"] == "create_file" and result["print_queued"] is True
            await c.until_state(result["job"]["id"], "completed")
            good = hashlib.sha256(gcode).hexdigest()
            status, sent = await http.request(*fluidd_upload(port, key, "sum.gcode", gcode,
                                                             good))
            assert status == 201, sent
            status, wrong = await http.request(*fluidd_upload(port, key, "bad.gcode", gcode,
                                                              "0" * 64))
            assert status == 422 and "checksum mismatch" in wrong["error"]["message"]
            status, _ = await http.request(*fluidd_upload(port, "nope", "x.gcode", gcode))
            assert status == 401
            listed = await c.call("job.list")
            await c.close()
        finally:
            await d.stop()
    assert [j["name"] for j in listed["jobs"]] == ["fluidd.gcode", "sum.gcode"]
    assert not list((tmp_path / "state" / "spool").glob(".upload-*"))


async def test_a_file_hostd_cannot_read_gets_the_sockets_error_in_the_clients_form(tmp_path):
    d, port, key = slicer_daemon(tmp_path)
    http = Http(port)
    ply = b"ply\nformat ascii 1.0\nelement vertex 0\nend_header\n"
    async with asyncio.timeout(60):
        await d.start()
        try:
            status, octo = await http.request(
                *prusaslicer_upload(port, key, "part.stl", ply, True), expect_continue=True)
            status2, moon = await http.request(*fluidd_upload(port, key, "part.stl", ply))
        finally:
            await d.stop()
    message = "part.stl: unsupported format: PLY (hostd reads STL, 3MF and OBJ)"
    assert (status, octo["error"]) == (400, message)
    assert status2 == 400 and message in json.dumps(moon)
