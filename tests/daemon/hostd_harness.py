"""Harness of the end-to-end tests: a hostd subprocess on the emulator, an asyncio RPC client."""

from __future__ import annotations

import asyncio
import base64
import itertools
import json
import os
import resource
import signal
import socket
import sys
from pathlib import Path
from typing import Any

import yaml

ROOT = Path(__file__).resolve().parents[2]
READY = "ready (socket"
PART_BYTES = 3 << 16  # hostctl's parts


async def hostctl(sock: str | Path, *args: str) -> tuple[int, str, str]:
    """``hostctl --socket SOCK ARGS...`` in a child process: (exit code, stdout, stderr)."""
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "hostd.cli.main", "--socket", str(sock), *args,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE, cwd=str(ROOT))
    out, err = await proc.communicate()
    return proc.returncode or 0, out.decode(), err.decode()


def make_gcode(subparts: int = 3, layers: int = 3, per_layer: int = 40) -> str:
    """A synthetic sliced file: start script, sub-parts with layers, transitions between."""
    out = [';HOSTD_ESTIMATE {"filament_mm": 100.0, "time_s": 600.0}',
           "G28", "M140 S60", "M104 S210", "M190 S60", "M109 S210", "G90", "M83", "G92 E0"]
    for k in range(subparts):
        if k:
            a, c = 30.0 * k, 120.0 * k
            out.append(f';HOSTD_TRANSITION {{"from": 0, "to": {k}, "a": {a}, "c": {c}, '
                       f'"x": 100.0, "y": 100.0, "z": 80.0}}')
            out += ["G0 Z80 F3000", f"G0 A{a:g} C{c:g} F3000", "G0 X100 Y100 F6000"]
            out.append(";HOSTD_TRANSITION_END")
        out.append(f';HOSTD_SUBPART {{"index": {k}, "parent": {0 if k else "null"}}}')
        for layer in range(layers):
            out.append(f';HOSTD_LAYER {{"subpart": {k}, "index": {layer}}}')
            z = (80.0 if k else 0.0) + 0.2 * (layer + 1)
            for i in range(per_layer):
                out.append(f"G1 X{100 + (i % 10):g} Y{100 + (i % 7):g} Z{z:.1f} E0.05 F1800")
    out += ["M104 S0", "M140 S0", "G0 Z200 F3000", "G0 A0 C0 F3000"]
    return "\n".join(out) + "\n"


def file_commands(text: str) -> list[str]:
    from hostd.printer.program import parse_program

    return parse_program(text).commands


HOUSEKEEPING = {"M105", "M110", "M115", "M110 N0"}


def executed(log: list[list[Any]]) -> list[str]:
    """The emulator log without the link's own handshake and idle temperature queries."""
    return [c for _, c in log if c.split()[0] not in HOUSEKEEPING]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


async def scrape(port: int, accept: str = "text/plain") -> str:
    r, w = await asyncio.open_connection("127.0.0.1", port)
    w.write(f"GET /metrics HTTP/1.0\r\nHost: localhost\r\nAccept: {accept}\r\n\r\n".encode())
    await w.drain()
    raw = await r.read()
    w.close()
    head, _, body = raw.partition(b"\r\n\r\n")
    assert head.split(b"\r\n")[0].split()[1] == b"200", head
    return body.decode()


class Rpc:
    """An asyncio JSON-RPC client on the control socket."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.reader, self.writer = reader, writer
        self.ids = itertools.count(1)
        self.events: asyncio.Queue[dict[str, Any]] = asyncio.Queue()
        self.waiting: dict[int, asyncio.Future[dict[str, Any]]] = {}
        self.task = asyncio.create_task(self._read())

    @classmethod
    async def connect(cls, path: str | Path) -> Rpc:
        r, w = await asyncio.open_unix_connection(str(path), limit=2**26)
        return cls(r, w)

    async def _read(self) -> None:
        while line := await self.reader.readline():
            msg = json.loads(line)
            if "id" in msg and msg["id"] in self.waiting:
                self.waiting.pop(msg["id"]).set_result(msg)
            elif "method" in msg:
                self.events.put_nowait(msg["params"])
        for fut in self.waiting.values():
            fut.set_exception(ConnectionError("closed"))

    async def raw(self, method: str, **params: Any) -> dict[str, Any]:
        req_id = next(self.ids)
        fut = asyncio.get_running_loop().create_future()
        self.waiting[req_id] = fut
        self.writer.write(json.dumps({"jsonrpc": "2.0", "id": req_id, "method": method,
                                      "params": params}).encode() + b"\n")
        await self.writer.drain()
        return await fut

    async def call(self, method: str, **params: Any) -> Any:
        msg = await self.raw(method, **params)
        if "error" in msg:
            raise RpcCallError(msg["error"]["code"], msg["error"]["message"])
        return msg["result"]

    async def submit_text(self, name: str, text: str) -> dict[str, Any]:
        """Queue ``text``: in one request, or in parts when it is long, as hostctl does
        (a request is at most daemon.max_request_bytes)."""
        data = text.encode()
        if len(data) <= PART_BYTES:
            return await self.call("job.submit", name=name, data=text, encoding="text")
        for offset in range(0, len(data), PART_BYTES):
            part = base64.b64encode(data[offset:offset + PART_BYTES]).decode()
            await self.call("job.upload", data=part, offset=offset)
        return await self.call("job.submit", name=name)

    async def printing(self, text: str, progress: float = 0.1) -> dict[str, Any]:
        """Subscribe, submit ``text`` as ``long.gcode`` and wait until a ``progress`` share
        of it is acknowledged; the job."""
        await self.call("events.subscribe")
        job = await self.submit_text("long.gcode", text)
        await self.until(lambda e: e["event"] == "job.progress" and e["progress"] > progress)
        return job

    async def until(self, pred: Any) -> dict[str, Any]:
        """The first pushed event satisfying ``pred``."""
        while True:
            ev = await self.events.get()
            if pred(ev):
                return ev

    async def until_state(self, job_id: int, *states: str) -> dict[str, Any]:
        return await self.until(lambda e: e["event"] == "job.state" and e["job_id"] == job_id
                                and e["new"] in states)

    async def close(self) -> None:
        self.writer.close()
        self.task.cancel()
        await asyncio.gather(self.task, return_exceptions=True)


class RpcCallError(Exception):
    def __init__(self, code: int, message: str) -> None:
        super().__init__(f"{code}: {message}")
        self.code = code
        self.message = message


class DaemonProc:
    """``hostd --config`` as a subprocess; :meth:`start` returns once it logs ready."""

    def __init__(self, tmp: Path, **overrides: Any) -> None:
        self.tmp = tmp
        self.socket = tmp / "hostd.sock"
        cfg: dict[str, Any] = {
            # the tests queue jobs back to back; the queue hold after a print (the default,
            # daemon.next_job: after_clear) has tests of its own (test_queue_hold.py)
            "daemon": {"socket": str(self.socket), "state_dir": str(tmp / "state"),
                       "log_level": "info", "next_job": "at_once"},
            "metrics": {"enabled": False},
            "serial": {"port": "sim://"},
            "sim": {"throttle": False},
        }
        for dotted, value in overrides.items():
            section, key = dotted.split("__")
            cfg.setdefault(section, {})[key] = value
        self.config = tmp / "hostd.yaml"
        self.config.write_text(yaml.safe_dump(cfg))
        self.proc: asyncio.subprocess.Process | None = None
        self.stderr: list[str] = []
        self._drain: asyncio.Task[None] | None = None

    async def start(self, env: dict[str, str] | None = None, pass_fds: tuple[int, ...] = (),
                    wrapper: tuple[str, ...] = (), limit_files: int | None = None) -> None:
        """Spawn hostd (after ``wrapper`` argv, e.g. an fd-moving exec; with at most
        ``limit_files`` open files, as LimitNOFILE= sets) and wait for ready."""
        def limit() -> None:
            if limit_files is not None:
                resource.setrlimit(resource.RLIMIT_NOFILE, (limit_files, limit_files))

        self.proc = await asyncio.create_subprocess_exec(
            *wrapper, sys.executable, "-m", "hostd.main", "--config", str(self.config),
            stderr=asyncio.subprocess.PIPE, cwd=str(ROOT), pass_fds=pass_fds,
            env={**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}, preexec_fn=limit)
        assert self.proc.stderr is not None
        while True:
            line = (await self.proc.stderr.readline()).decode()
            if not line:
                raise RuntimeError("hostd exited:\n" + "".join(self.stderr))
            self.stderr.append(line)
            if READY in line:
                break
        self._drain = asyncio.create_task(self._keep_reading())

    async def _keep_reading(self) -> None:
        assert self.proc is not None and self.proc.stderr is not None
        while line := await self.proc.stderr.readline():
            self.stderr.append(line.decode())

    async def rpc(self) -> Rpc:
        return await Rpc.connect(self.socket)

    def loop_errors(self) -> list[str]:
        """What asyncio or a traceback put in the log: nothing, in a run that went well."""
        marks = ("Exception in callback", "never retrieved", "Traceback", "ERROR asyncio")
        return [line for line in self.stderr if any(m in line for m in marks)]

    async def stop(self, sig: int = signal.SIGTERM) -> int:
        assert self.proc is not None
        if self.proc.returncode is None:
            self.proc.send_signal(sig)
        rc = await self.proc.wait()
        if self._drain is not None:
            await self._drain
        return rc
