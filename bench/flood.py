"""The control socket flooded while a job streams: the link's line rate unloaded and flooded.

Run: ``.venv/bin/python bench/flood.py`` (``--printer sim`` or ``--printer virtual`` for one
of the two; ``--repeat N``). Issue 37's load, as a demanding user makes it, on loopback and
Unix sockets only, bounded in count and time: while hostd streams a job, a process of its own
runs, for ``--seconds`` (30),

- ``--clients`` (50) connections calling ``printer.status`` back to back,
- one connection sending malformed frames (bad JSON, an empty batch, a wrong version, an
  unknown method, a bad parameter), each reply checked for its JSON-RPC code,
- ``--slowloris`` (200) connections that send a request a byte a second and never finish it
  (one that is dropped connects again after a second),
- ``--big`` (2) connections sending frames of ``--big-mb`` (10) MB, again and again.

Meanwhile a well-behaved client polls ``printer.status`` at 20 Hz: its round trips (p50,
p99) and the link's acknowledged lines (``lines_acked``, the rate over the phase). The same
client measures ``--quiet`` (10) seconds before the flood and after it, so the ratio
flooded / unloaded compares figures of one run (the mean of the two quiet phases is the
unloaded rate). hostd's RSS: idle before the job, the largest during each phase, and after
the flood (``--settle`` seconds after it ended).

The printers: ``sim`` is ``serial.port: sim://`` (the emulator inside hostd, its wire
throttled to ``--baud``/10 bytes/s); ``virtual`` is OctoPrint's virtual printer in a process
of its own behind a pty, its wire paced to ``--baud`` too (``bench/virtual_printer.py``, run
with ``.venv-octoprint``'s interpreter: ``make test-octoprint`` builds it; skipped with a note
when it is missing).

Targets: flooded line rate >= 95 % of unloaded, status p99 < 10 ms flooded, RSS < 100 MB
during the flood and within 10 MB of the streaming RSS before it afterwards.
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import contextlib
import json
import os
import resource
import statistics
import sys
import tempfile
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from daemon import cpu_seconds, rss_mb

ROOT = Path(__file__).resolve().parents[1]
OCTO_PYTHON = ROOT / ".venv-octoprint" / "bin" / "python"
READY = "ready (socket"
PART_BYTES = 3 << 16  # hostctl's
POLL_S = 0.05  # the well-behaved client's period
SETTLE_S = 2.0
TARGETS = {"rate_ratio": 0.95, "status_p99_ms": 10.0, "flood_rss_mb": 100.0,
           "rss_regain_mb": 10.0}
MALFORMED: list[tuple[bytes, int]] = [
    (b"{not json\n", -32700),
    (b"[]\n", -32600),
    (b'{"jsonrpc": "1.0", "id": 1, "method": "printer.status"}\n', -32600),
    (b'{"jsonrpc": "2.0", "id": 2, "method": "no.such"}\n', -32601),
    (b'{"jsonrpc": "2.0", "id": 3, "method": "job.get", "params": {"id": "x"}}\n', -32602),
]
PARTIAL = b'{"jsonrpc": "2.0", "id": 1, "method": "printer.status"'


def job_text(lines: int) -> str:
    """A job of plain moves: no heat-up, no sub-part transition (the virtual printer reports
    no A/C), lines of about the same length all along."""
    moves = [f"G1 X{200 + (i % 50) * 0.5:.1f} Y{200 + (i % 40) * 0.5:.1f} E0.02 F6000"
             for i in range(lines)]
    return "\n".join([";HOSTD_SUBPART {\"index\": 0, \"parent\": null}",
                      ";HOSTD_LAYER {\"subpart\": 0, \"index\": 0}", "G90", "M83",
                      *moves]) + "\n"


# -- the flood, in a process of its own ---------------------------------------------------------


@dataclass
class Tally:
    status_calls: int = 0
    refused: int = 0
    malformed_right: int = 0
    malformed_wrong: int = 0
    big_answers: dict[str, int] = field(default_factory=dict)
    slowloris_dropped: int = 0
    errors: dict[str, int] = field(default_factory=dict)

    def error(self, what: str) -> None:
        self.errors[what] = self.errors.get(what, 0) + 1


async def _connect(sock: str, tally: Tally
                   ) -> tuple[asyncio.StreamReader, asyncio.StreamWriter] | None:
    try:
        return await asyncio.open_unix_connection(sock, limit=1 << 22)
    except OSError as exc:
        tally.error(f"connect: {exc.strerror or exc}")
        return None


async def _reply(r: asyncio.StreamReader, tally: Tally) -> dict[str, Any] | None:
    """The next message, or None when the connection ended (a refusal counted)."""
    line = await r.readline()
    if not line:
        return None
    msg = json.loads(line)
    if msg.get("id") is None and "error" in msg and "connection" in msg["error"]["message"]:
        tally.refused += 1
        return None
    return msg


STATUS = b'{"jsonrpc": "2.0", "id": 1, "method": "printer.status"}\n'


Conn = tuple[asyncio.StreamReader, asyncio.StreamWriter]


async def connections(sock: str, deadline: float, tally: Tally, pause: float
                      ) -> AsyncIterator[Conn]:
    """One connection after another until ``deadline``, ``pause`` seconds between them (a
    client that was refused or dropped connects again), each closed after its use."""
    while time.monotonic() < deadline:
        conn = await _connect(sock, tally)
        if conn is not None:
            try:
                yield conn
            finally:
                conn[1].close()
        if time.monotonic() < deadline:
            await asyncio.sleep(pause)  # pacing a reconnect, not a wait for something


STATUS = b'{"jsonrpc": "2.0", "id": 1, "method": "printer.status"}\n'


async def status_client(sock: str, deadline: float, tally: Tally, pipeline: int = 1) -> None:
    """``printer.status`` back to back, ``pipeline`` requests written at once."""
    async for r, w in connections(sock, deadline, tally, 0.5):
        with contextlib.suppress(ConnectionError):
            while time.monotonic() < deadline and await _statuses(r, w, pipeline, tally):
                pass


async def _statuses(r: asyncio.StreamReader, w: asyncio.StreamWriter, n: int,
                    tally: Tally) -> bool:
    w.write(STATUS * n)
    for _ in range(n):
        if await _reply(r, tally) is None:
            return False
        tally.status_calls += 1
    return True


async def malformed_client(sock: str, deadline: float, tally: Tally) -> None:
    async for r, w in connections(sock, deadline, tally, 0.5):
        with contextlib.suppress(ConnectionError):
            while time.monotonic() < deadline and await _malformed(r, w, tally):
                pass


async def _malformed(r: asyncio.StreamReader, w: asyncio.StreamWriter, tally: Tally) -> bool:
    for frame, code in MALFORMED:
        w.write(frame)
        msg = await _reply(r, tally)
        if msg is None:
            return False
        if msg.get("error", {}).get("code") == code:
            tally.malformed_right += 1
        else:
            tally.malformed_wrong += 1
    return True


async def big_client(sock: str, deadline: float, size: int, tally: Tally) -> None:
    """Frames of ``size`` bytes, the answer read while the frame is still being sent."""
    async for r, w in connections(sock, deadline, tally, 0.0):
        answer = asyncio.ensure_future(r.readline())
        await _send_big(w, size, answer)
        code = "none"
        with contextlib.suppress(ConnectionError, ValueError, KeyError, TimeoutError):
            async with asyncio.timeout(10):
                line = await answer
            code = str(json.loads(line)["error"]["code"]) if line else "closed"
        tally.big_answers[code] = tally.big_answers.get(code, 0) + 1
        answer.cancel()


async def _send_big(w: asyncio.StreamWriter, size: int, answer: asyncio.Future[bytes]) -> None:
    chunk = b"x" * (1 << 20)
    with contextlib.suppress(ConnectionError):
        for _ in range(size // len(chunk)):
            if answer.done():
                return
            w.write(chunk)
            await w.drain()
        w.write(b"\n")
        await w.drain()


async def slowloris_client(sock: str, deadline: float, tally: Tally) -> None:
    """A request a byte a second, never finished; connects again once dropped."""
    async for r, w in connections(sock, deadline, tally, 1.0):
        ended = asyncio.ensure_future(r.read())
        for i in range(len(PARTIAL)):
            await asyncio.wait({ended}, timeout=min(1.0, max(0.0, deadline - time.monotonic())))
            if ended.done() or time.monotonic() >= deadline:
                break
            with contextlib.suppress(ConnectionError):
                w.write(PARTIAL[i:i + 1])
        if ended.done():
            tally.slowloris_dropped += 1
            with contextlib.suppress(ConnectionError, ValueError):
                if b"connection" in ended.result():
                    tally.refused += 1
        ended.cancel()


async def flood(sock: str, args: argparse.Namespace) -> Tally:
    tally = Tally()
    deadline = time.monotonic() + args.seconds
    tasks = [status_client(sock, deadline, tally, args.pipeline) for _ in range(args.clients)]
    tasks += [malformed_client(sock, deadline, tally)]
    tasks += [big_client(sock, deadline, int(args.big_mb * (1 << 20)), tally)
              for _ in range(args.big)]
    tasks += [slowloris_client(sock, deadline, tally) for _ in range(args.slowloris)]
    running = [asyncio.ensure_future(t) for t in tasks]
    _, late = await asyncio.wait(running, timeout=args.seconds + 30)
    for task in late:  # a connection still waiting for the daemon: counted, not awaited
        task.cancel()
        tally.error("still waiting at the end")
    await asyncio.gather(*running, return_exceptions=True)
    return tally


def burn(seconds: float) -> Tally:
    """The control: a process as busy as the flood's, connecting to nothing."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        sum(range(10000))
    return Tally()


def worker_main(args: argparse.Namespace) -> int:
    print("flooding", flush=True)  # for a caller that waits for the flood to begin
    tally = burn(args.seconds) if args.burn else asyncio.run(flood(args.worker, args))
    print(json.dumps(tally.__dict__))
    return 0


# -- the measuring side --------------------------------------------------------------------------


class Probe:
    """The well-behaved client: one connection, ``printer.status`` at 20 Hz."""

    def __init__(self, r: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
        self.r, self.w = r, w
        self.ids = 0

    async def call(self, method: str, **params: Any) -> Any:
        self.ids += 1
        self.w.write(json.dumps({"jsonrpc": "2.0", "id": self.ids, "method": method,
                                 "params": params}).encode() + b"\n")
        while True:
            msg = json.loads(await self.r.readline())
            if msg.get("id") == self.ids:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                return msg["result"]

    async def submit(self, name: str, data: bytes) -> Any:
        """Queue a file sent in parts, as hostctl sends one over 192 KiB."""
        for offset in range(0, len(data), PART_BYTES):
            part = base64.b64encode(data[offset:offset + PART_BYTES]).decode()
            await self.call("job.upload", data=part, offset=offset)
        return await self.call("job.submit", name=name)

    async def phase(self, seconds: float, pid: int) -> dict[str, float]:
        """Poll for ``seconds``: the line rate, status round trips and the largest RSS."""
        lat: list[float] = []
        marks: list[tuple[float, int]] = []
        rss = 0.0
        cpu0, start = cpu_seconds(pid), time.monotonic()
        end = start + seconds
        while time.monotonic() < end:
            t0 = time.perf_counter()
            status = await self.call("printer.status")
            lat.append(1000 * (time.perf_counter() - t0))
            marks.append((time.monotonic(), status["link"]["lines_acked"]))
            rss = max(rss, rss_mb(pid))
            await asyncio.sleep(POLL_S)  # a client polling at 20 Hz
        lat.sort()
        (t0, a0), (t1, a1) = marks[0], marks[-1]
        cpu = 100 * (cpu_seconds(pid) - cpu0) / (time.monotonic() - start)
        return {"lines_per_s": (a1 - a0) / (t1 - t0), "cpu_pct": cpu,
                "status_p50_ms": statistics.median(lat),
                "status_p99_ms": lat[int(0.99 * (len(lat) - 1))], "rss_mb": rss,
                "polls": len(lat)}


async def spawn_virtual(baud: int) -> tuple[asyncio.subprocess.Process, str]:
    proc = await asyncio.create_subprocess_exec(
        str(OCTO_PYTHON), str(ROOT / "bench" / "virtual_printer.py"), "--baud", str(baud),
        stdout=asyncio.subprocess.PIPE, cwd=str(ROOT))
    assert proc.stdout is not None
    path = (await proc.stdout.readline()).decode().strip()
    if not path:
        raise RuntimeError("the virtual printer did not start")
    return proc, path


async def spawn_daemon(tmp: Path, port: str, baud: int, rx: int, profile: str | None,
                       checkout: Path, metrics: int | None = None,
                       limit_files: int | None = None
                       ) -> tuple[asyncio.subprocess.Process, asyncio.Task[list[str]]]:
    """hostd on ``port`` (metrics on port ``metrics``; at most ``limit_files`` open files),
    once it logs ready; the task gathering what it logs after."""
    cfg = tmp / "hostd.yaml"
    cfg.write_text(json.dumps({
        "daemon": {"socket": str(tmp / "hostd.sock"), "state_dir": str(tmp / "state"),
                   "log_level": "info"},
        "metrics": {"enabled": metrics is not None, "port": metrics or 9464},
        "serial": {"port": port, "baud": baud, "rx_buffer_bytes": rx},
        "sim": {"throttle": True, "rx_buffer_bytes": rx}}))
    prof = ["-m", "cProfile", "-o", profile] if profile else []
    def limit() -> None:
        if limit_files is not None:
            resource.setrlimit(resource.RLIMIT_NOFILE, (limit_files, limit_files))

    proc = await asyncio.create_subprocess_exec(
        sys.executable, *prof, "-m", "hostd.main", "--config", str(cfg),
        stderr=asyncio.subprocess.PIPE, cwd=str(checkout), preexec_fn=limit)
    assert proc.stderr is not None
    seen: list[str] = []
    async with asyncio.timeout(60):
        while READY not in (line := (await proc.stderr.readline()).decode()):
            if not line:
                raise RuntimeError("hostd exited:\n" + "".join(seen))
            seen.append(line)
    return proc, asyncio.create_task(_logged(proc.stderr))


async def _logged(stream: asyncio.StreamReader) -> list[str]:
    """What hostd logs until it exits."""
    out: list[str] = []
    while line := (await stream.readline()).decode():
        out.append(line)
    return out


async def run_flood(sock: Path, args: argparse.Namespace) -> asyncio.subprocess.Process:
    return await asyncio.create_subprocess_exec(
        sys.executable, str(Path(__file__)), "--worker", str(sock),
        "--seconds", str(args.seconds), "--clients", str(args.clients),
        "--slowloris", str(args.slowloris), "--big", str(args.big),
        "--big-mb", str(args.big_mb), "--pipeline", str(args.pipeline),
        *(["--burn"] if args.burn else []),
        stdout=asyncio.subprocess.PIPE, cwd=str(ROOT))


async def bench_printer(kind: str, args: argparse.Namespace, tmp: Path) -> dict[str, Any]:
    emu = None
    port, rx = "sim://", 127
    if kind == "virtual":
        emu, port = await spawn_virtual(args.baud)
        rx = 63
    daemon, logged = await spawn_daemon(tmp, port, args.baud, rx, args.profile,
                                         args.checkout)
    for proc in (daemon, emu):
        if proc is not None and args.nice:
            os.setpriority(os.PRIO_PROCESS, proc.pid, args.nice)
    out: dict[str, Any] = {"printer": kind}
    try:
        probe = await _probe(tmp / "hostd.sock")
        await asyncio.sleep(SETTLE_S)  # settle before the idle figure
        out["idle_rss_mb"] = rss_mb(daemon.pid)
        await probe.submit("flood.gcode", job_text(args.lines).encode())
        await _until_streaming(probe)
        out["before"] = await probe.phase(args.quiet, daemon.pid)
        worker = await run_flood(tmp / "hostd.sock", args)
        out["flood"] = await probe.phase(args.seconds, daemon.pid)
        report, _ = await worker.communicate()
        report = report.split(b"\n", 1)[1]
        out["tally"] = json.loads(report)
        await asyncio.sleep(args.settle)  # the time the RSS is given to come back
        out["after"] = await probe.phase(args.quiet, daemon.pid)
        out["after_rss_mb"] = rss_mb(daemon.pid)
        out["state"] = (await probe.call("printer.status"))["jobs"]["current"]
    finally:
        daemon.terminate()
        await daemon.wait()
        out["logged"] = await logged
        if emu is not None:
            emu.terminate()
            await emu.wait()
    return out


async def _probe(sock: Path) -> Probe:
    r, w = await asyncio.open_unix_connection(str(sock), limit=1 << 22)
    probe = Probe(r, w)
    await probe.call("server.info")
    return probe


async def _until_streaming(probe: Probe) -> None:
    async with asyncio.timeout(60):
        while True:
            cur = (await probe.call("printer.status"))["jobs"]["current"]
            if cur is not None and cur["acked"] > 200:
                return
            await asyncio.sleep(0.2)  # a client polling until the job runs


def figures(res: dict[str, Any]) -> dict[str, float]:
    unloaded = (res["before"]["lines_per_s"] + res["after"]["lines_per_s"]) / 2
    return {"rate_ratio": res["flood"]["lines_per_s"] / unloaded,
            "status_p99_ms": res["flood"]["status_p99_ms"],
            "flood_rss_mb": res["flood"]["rss_mb"],
            "rss_regain_mb": res["after_rss_mb"] - res["before"]["rss_mb"]}


def report(res: dict[str, Any]) -> None:
    print(f"\n== {res['printer']}: idle RSS {res['idle_rss_mb']:.1f} MB")
    print(f"{'phase':10} {'lines/s':>9} {'status p50':>11} {'p99 ms':>8} {'RSS max MB':>11}"
          f" {'polls':>6} {'hostd CPU %':>12}")
    for phase in ("before", "flood", "after"):
        p = res[phase]
        print(f"{phase:10} {p['lines_per_s']:9.1f} {p['status_p50_ms']:11.2f} "
              f"{p['status_p99_ms']:8.2f} {p['rss_mb']:11.1f} {p['polls']:6d} "
              f"{p['cpu_pct']:12.1f}")
    print(f"RSS at the end, after the quiet phase that follows the flood: "
          f"{res['after_rss_mb']:.1f} MB")
    print("flood:", json.dumps(res["tally"]))
    logged = [x for x in res.get("logged", []) if x.startswith(("WARNING", "ERROR"))]
    print(f"hostd logged {len(logged)} warnings and errors, "
          f"{sum(len(x) for x in logged)} bytes" + (f"; first: {logged[0].strip()}"
                                                   if logged else ""))
    for key, value in figures(res).items():
        target = TARGETS[key]
        ok = value >= target if key == "rate_ratio" else value < target
        print(f"{key:16} {value:8.3f}  (target {'>=' if key == 'rate_ratio' else '<'} "
              f"{target:g}) {'ok' if ok else 'MISSED'}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--printer", choices=("sim", "virtual", "both"), default="both")
    ap.add_argument("--baud", type=int, default=115200)
    ap.add_argument("--seconds", type=float, default=30.0, help="the flood's length")
    ap.add_argument("--quiet", type=float, default=10.0, help="each unloaded phase's length")
    ap.add_argument("--settle", type=float, default=3.0,
                    help="seconds after the flood before the phase after it")
    ap.add_argument("--clients", type=int, default=50)
    ap.add_argument("--slowloris", type=int, default=200)
    ap.add_argument("--big", type=int, default=2)
    ap.add_argument("--big-mb", type=float, default=10.0)
    ap.add_argument("--pipeline", type=int, default=1,
                    help="requests each status client writes at once (then reads the answers)")
    ap.add_argument("--lines", type=int, default=60000, help="the job's length")
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--burn", action="store_true",
                    help="the control experiment: instead of the flood, a process as busy "
                         "connects to nothing (what the machine's load alone does)")
    ap.add_argument("--nice", type=int, default=0,
                    help="run hostd (and the virtual printer: the board) at this nice value, "
                         "as the unit's Nice= does")
    ap.add_argument("--profile", metavar="FILE", help="run hostd under cProfile, stats to FILE")
    ap.add_argument("--checkout", type=Path, default=ROOT, metavar="DIR",
                    help="run the hostd of another checkout (a git worktree of another "
                         "version), to compare")
    ap.add_argument("--worker", metavar="SOCKET", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        return worker_main(args)
    kinds = ["sim", "virtual"] if args.printer == "both" else [args.printer]
    if "virtual" in kinds and not OCTO_PYTHON.exists():
        print(f"note: {OCTO_PYTHON} missing (make test-octoprint builds it): "
              "virtual printer skipped")
        kinds.remove("virtual")
    ok = True
    for _ in range(max(1, args.repeat)):
        for kind in kinds:
            with tempfile.TemporaryDirectory(prefix="hostd-flood-") as name:
                res = asyncio.run(bench_printer(kind, args, Path(name)))
            report(res)
            fig = figures(res)
            ok &= fig["rate_ratio"] >= TARGETS["rate_ratio"] and all(
                fig[k] < v for k, v in TARGETS.items() if k != "rate_ratio")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
