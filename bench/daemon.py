"""Daemon performance: idle RSS, CPU while streaming at 250000 baud, printer.status latency.

Run: ``.venv/bin/python bench/daemon.py`` (``make bench``). By default the emulator runs in a
process of its own behind a pseudo-terminal (``hostd-sim --pty --throttle --baud 250000``: the
wire carries 25000 bytes/s each way), so the daemon's CPU share is its own: link, streamer,
job manager, control server. The line rate is printed beside the wire limit for this job's
lines (25000 bytes/s over the mean framed line), and the CPU both as a share of a core at that
rate and as CPU milliseconds per 1000 lines. ``--in-process`` uses ``sim://`` instead
(emulator inside the daemon: the old, upper-bound figure). ``--profile FILE`` runs the daemon
under cProfile and writes its stats.

It measures RSS when idle, then streams a G-code job in two phases. Up to 45 % of it, the
only client follows the job by its pushed events, as ``hostctl print --wait`` does
(``watch_cpu_pct``: the streaming itself, with the progress events at 5 Hz). From there to
90 %, a client polls ``printer.status`` at ~20 Hz (``stream_cpu_pct`` and the status round
trips: every poll builds and encodes the whole snapshot, a heavier client than hostctl).
Targets: RSS < 80 MB idle, daemon streaming CPU < 10 % of a core (both phases), status p99
< 10 ms.

``acked_lines_per_read`` is the lines acknowledged per read of the port in the second phase
(``serial.read_hold`` batches the ``ok`` while the wire is the bottleneck; ``--read-hold 0``
reads each at once). ``link_timeouts`` and ``link_resends`` count the link's ``ok`` timeouts
and resend requests over the job: a timeout is a stall of ``serial.ok_timeout`` (10 s) that
the averages hide, so each should be 0; the daemon's warnings go to stderr. The firmware's
receive buffer sets how many a read can take in:
``--rx-buffer BYTES`` gives the emulator and hostd another size than hostd's default.
``--advanced-ok`` has the emulator answer ``ok N<n> P<p> B<b>``, as a Marlin built with
ADVANCED_OK does (the README's recommended build; stock Marlin answers a plain ``ok``).
``--upload LINES`` has another client submit a G-code job of about that many lines as the
first phase begins: an operator's ``hostctl print`` queueing the next part (``upload_s``: its
run, the CLI's start included), and ``watch_wire_share_pct`` shows whether the stream kept
the wire full meanwhile.

Last, ``floor_us_per_wakeup`` is :mod:`wakeup`'s bare asyncio wake-up and write per ``ok``
(no hostd code) on this machine right after: a shared VM's speed drifts, and this tells a
slow spell from a slower daemon. ``--repeat N`` runs it N times and prints a line a run (its
end, floor and targeted figures), their median and largest, and how many runs kept each target.
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import json
import math
import os
import signal
import statistics
import sys
import tempfile
import time
from collections import deque
from pathlib import Path

import wakeup

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hostd.link.settings import LinkSettings  # noqa: E402

TARGETS = {"idle_rss_mb": 80.0, "watch_cpu_pct": 10.0, "stream_cpu_pct": 10.0,
           "status_p99_ms": 10.0}
BAUD = 250000
RX_BUFFER = LinkSettings().rx_buffer_bytes  # hostd's default (Marlin's 128-byte ring)
READY = "ready (socket"
PART_BYTES = 3 << 16  # hostctl's parts
SETTLE_S = 2.0  # idle time before the RSS figure



def synthetic_gcode(subparts: int = 3, layers: int = 6, per_layer: int = 120) -> str:
    """A sliced-looking file: start script, sub-parts, layers, HOSTD transitions."""
    out = [';HOSTD_ESTIMATE {"filament_mm": 250.0, "time_s": 900.0}',
           "G28", "M140 S60", "M104 S210", "M190 S60", "M109 S210", "G90", "M83", "G92 E0"]
    for k in range(subparts):
        if k:
            a, c = 35.0, 120.0 * k
            out += [f';HOSTD_TRANSITION {{"from": 0, "to": {k}, "a": {a}, "c": {c}, '
                    '"x": 250.0, "y": 250.0, "z": 140.0}',
                    "G0 Z140 F3000", f"G0 A{a:g} C{c:g} F3000", "G0 X250 Y250 F6000",
                    ";HOSTD_TRANSITION_END"]
        out.append(f';HOSTD_SUBPART {{"index": {k}, "parent": {0 if k else "null"}}}')
        for layer in range(layers):
            out.append(f';HOSTD_LAYER {{"subpart": {k}, "index": {layer}}}')
            z = (140.0 if k else 100.0) + 0.2 * (layer + 1)
            for i in range(per_layer):
                out.append(f"G1 X{245 + (i % 10):g} Y{245 + (i % 9):g} Z{z:.1f} E0.04 F1800")
    out += ["M104 S0", "M140 S0", "M107", "G0 Z300 F3000", "G0 A0 C0 F3000", "M84"]
    return "\n".join(out) + "\n"

def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


# -- the benchmark ----------------------------------------------------------------------------


class Client:
    def __init__(self, r: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
        self.r, self.w = r, w

    async def submit(self, name: str, data: bytes) -> dict:
        """Queue a file sent in parts, as hostctl sends one over 192 KiB (a request is at
        most daemon.max_request_bytes)."""
        for offset in range(0, len(data), PART_BYTES):
            part = base64.b64encode(data[offset:offset + PART_BYTES]).decode()
            await self.call("job.upload", data=part, offset=offset)
        return await self.call("job.submit", name=name)

    async def call(self, method: str, **params: object) -> dict:
        self.w.write(json.dumps({"jsonrpc": "2.0", "id": 1, "method": method,
                                 "params": params}).encode() + b"\n")
        await self.w.drain()
        while True:
            msg = json.loads(await self.r.readline())
            if msg.get("id") == 1:
                return msg["result"]


async def spawn_emulator(rx_buffer: int, advanced_ok: bool
                         ) -> tuple[asyncio.subprocess.Process, str]:
    """``hostd-sim --pty`` in its own process, the wire throttled to ``BAUD``."""
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "hostd.sim.main", "--pty", "--throttle", "--baud", str(BAUD),
        "--rx-buffer-bytes", str(rx_buffer), *(["--advanced-ok"] if advanced_ok else []),
        stdout=asyncio.subprocess.PIPE, cwd=str(ROOT))
    assert proc.stdout is not None
    path = (await proc.stdout.readline()).decode().strip()
    if not path:
        raise RuntimeError("the emulator did not start")
    return proc, path


async def spawn_daemon(tmp: Path, port: str, profile: str | None, partial: bool,
                       read_hold: float, rx_buffer: int, advanced_ok: bool
                       ) -> tuple[asyncio.subprocess.Process, asyncio.Task[None], list[str]]:
    """Start hostd on ``port``; its process, the task draining its stderr, and the warnings
    and errors it logs (filled as they come)."""
    cfg = tmp / "hostd.yaml"
    cfg.write_text(json.dumps({
        "daemon": {"socket": str(tmp / "hostd.sock"), "state_dir": str(tmp / "state"),
                   "log_level": "info"},
        "metrics": {"enabled": False},
        "serial": {"port": port, "baud": BAUD, "partial_lines": partial,
                   "read_hold": read_hold, "rx_buffer_bytes": rx_buffer},
        "sim": {"throttle": True, "rx_buffer_bytes": rx_buffer, "advanced_ok": advanced_ok}}))
    prof = ["-m", "cProfile", "-o", profile] if profile else []
    proc = await asyncio.create_subprocess_exec(
        sys.executable, *prof, "-m", "hostd.main", "--config", str(cfg),
        stderr=asyncio.subprocess.PIPE, cwd=str(ROOT))
    assert proc.stderr is not None
    log: deque[str] = deque(maxlen=50)
    warned: list[str] = []
    while READY not in (line := (await proc.stderr.readline()).decode()):
        if not line:
            raise RuntimeError("hostd exited:\n" + "".join(log))
        log.append(line)
    return proc, asyncio.create_task(_drain(proc.stderr, log, warned)), warned


async def _drain(stream: asyncio.StreamReader, log: deque[str], warned: list[str]) -> None:
    while line := (await stream.readline()).decode():
        log.append(line)
        # the bench stops the daemon before the job ends: that job's interruption is its own
        if line.startswith(("WARNING", "ERROR")) and "daemon stopped (SIGTERM)" not in line:
            warned.append(line)


WATCHED = ["job.state", "job.progress", "job.subpart", "subpart_started", "transition_failed"]
WATCH_FROM, WATCH_UNTIL = 0.05, 0.45  # the first phase follows the job by its events
POLL_UNTIL = 0.9


async def stream_and_measure(c: Client, sock: Path, pids: dict[str, int],
                             upload: int) -> dict[str, float]:
    """Submit a job; measure while a client follows its events, then while one polls."""
    text = synthetic_gcode(subparts=3, layers=40, per_layer=200)
    watcher = Client(*await asyncio.open_unix_connection(str(sock)))
    await watcher.call("events.subscribe", events=WATCHED)
    job = await c.submit("bench.gcode", text.encode())
    started = asyncio.Event()
    uploading = asyncio.create_task(submit_when(started, sock, upload)) if upload else None
    async with asyncio.timeout(300):  # the job streams in ~40 s: no events means a fault
        out, watched = await watch(watcher, pids, started)
        if uploading is not None:
            out["upload_s"] = await uploading
    watcher.w.close()
    polled, polled_span = await poll(c, pids)
    out |= polled
    out["lines"] = job["total_lines"]
    # of the lines each phase streamed (line numbers grow a digit as the job goes on); each
    # phase holds a sub-part transition, where M400 waits and the wire idles for a moment
    out["watch_wire_share_pct"] = 100 * out["watch_lines_per_s"] / wire_limit(text, *watched)
    out["wire_limit_lines_per_s"] = wire_limit(text, *polled_span)
    out["wire_share_pct"] = 100 * out["lines_per_s"] / out["wire_limit_lines_per_s"]
    return out


async def submit_when(started: asyncio.Event, sock: Path, lines: int) -> float:
    """Once ``started`` is set, ``hostctl print`` a job of about ``lines`` lines (the checkout's
    own hostctl, in a process of its own); the seconds it took."""
    text = synthetic_gcode(subparts=1, layers=max(1, lines // 200), per_layer=200)
    path = sock.parent / "next.gcode"
    path.write_text(text)
    await started.wait()
    t0 = time.monotonic()
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "hostd.cli.main", "--socket", str(sock), "print", str(path),
        cwd=str(ROOT), stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.PIPE)
    _, err = await proc.communicate()
    if proc.returncode:
        raise SystemExit(f"hostctl print failed: {err.decode().strip()}")
    return time.monotonic() - t0


async def watch(c: Client, pids: dict[str, int], started: asyncio.Event
                ) -> tuple[dict[str, float], tuple[int, int]]:
    """CPU while the only client following the job does so by its pushed events (``hostctl
    print --wait``), from ``WATCH_FROM`` to ``WATCH_UNTIL`` of the job; ``started`` is set
    as it begins."""
    start: tuple[dict[str, float], float, int] | None = None
    while True:
        msg = json.loads(await c.r.readline())
        if msg.get("method") != "notify_job_progress":
            continue
        params = msg["params"]
        if params["progress"] < WATCH_FROM:  # events queued while the job was submitted
            continue
        if start is None:
            start = ({k: cpu_seconds(p) for k, p in pids.items()}, time.monotonic(),
                     params["acked"])
            started.set()
        elif params["progress"] >= WATCH_UNTIL:
            break
    c0, t0, acked0 = start
    seconds, lines = time.monotonic() - t0, params["acked"] - acked0
    cpu = cpu_seconds(pids["stream"]) - c0["stream"]
    return {"watch_cpu_pct": 100 * cpu / seconds,
            "watch_cpu_ms_per_1000_lines": 1e6 * cpu / lines,
            "watch_lines_per_s": lines / seconds}, (acked0, params["acked"])


async def poll(c: Client, pids: dict[str, int]
               ) -> tuple[dict[str, float], tuple[int, int]]:
    """CPU and ``printer.status`` round trips while a client polls at ~20 Hz, up to
    ``POLL_UNTIL``."""
    c0 = {k: cpu_seconds(p) for k, p in pids.items()}
    t0 = time.monotonic()
    lat: list[float] = []
    acked: list[tuple[float, int]] = []  # (time of the answer, acknowledged lines)
    link0: dict[str, int] | None = None  # the link's counters at the first poll
    while True:
        s = time.perf_counter()
        status = await c.call("printer.status")
        lat.append((time.perf_counter() - s) * 1000)
        link0, link1 = link0 or status["link"], status["link"]
        cur = status["jobs"]["current"]
        if cur is None or cur["progress"] > POLL_UNTIL or len(lat) >= 2000:
            break
        acked.append((time.monotonic(), cur["acked"]))
        await asyncio.sleep(0.05)  # a client polling status at ~20 Hz
    t1 = time.monotonic()
    lat.sort()
    cpu = {k: cpu_seconds(p) - c0[k] for k, p in pids.items()}
    lines = acked[-1][1] - acked[0][1] if acked else 0
    rate = lines / (acked[-1][0] - acked[0][0]) if lines else math.nan
    out = {f"{k}_cpu_pct": 100 * v / (t1 - t0) for k, v in cpu.items()}
    out["stream_cpu_ms_per_1000_lines"] = 1e6 * cpu["stream"] / (rate * (t1 - t0))
    out.update(status_p50_ms=statistics.median(lat),
               status_p99_ms=lat[int(0.99 * (len(lat) - 1))], streamed_s=t1 - t0,
               lines_per_s=rate, status_calls=len(lat))
    assert link0 is not None
    out["acked_lines_per_read"] = ((link1["lines_acked"] - link0["lines_acked"])
                                   / max(1, link1["reads"] - link0["reads"]))
    # since the job began: a timeout is a 10 s stall that the CPU and rate figures hide
    out["link_timeouts"] = link1["timeouts"]
    out["link_resends"] = link1["resend_requests"]
    return out, (acked[0][1], acked[-1][1])


def wire_limit(text: str, first: int, last: int) -> float:
    """Lines per second the wire carries for commands ``first`` to ``last`` of this job:
    BAUD/10 over their mean framed line."""
    from hostd.link import frame, strip_gcode

    cmds = [c for c in map(strip_gcode, text.splitlines()) if c]
    wire = sum(len(frame(i + 1, c)) + 1 for i, c in enumerate(cmds) if first <= i < last)
    return BAUD / 10 / (wire / max(1, last - first))


async def bench(tmp: Path, in_process: bool, profile: str | None,
                partial: bool, read_hold: float, rx_buffer: int, advanced_ok: bool,
                upload: int) -> dict[str, float]:
    emu = None
    port = "sim://"
    if not in_process:
        emu, port = await spawn_emulator(rx_buffer, advanced_ok)
    try:
        proc, drain, warned = await spawn_daemon(tmp, port, profile, partial, read_hold, rx_buffer,
                                         advanced_ok)
        try:
            r, w = await asyncio.open_unix_connection(str(tmp / "hostd.sock"))
            c = Client(r, w)
            await c.call("server.info")
            await asyncio.sleep(SETTLE_S)  # let the daemon settle before the idle figure
            out = {"idle_rss_mb": rss_mb(proc.pid)}
            pids = {"stream": proc.pid} | ({"emulator": emu.pid} if emu else {})
            out |= await stream_and_measure(c, tmp / "hostd.sock", pids, upload)
            w.close()
        finally:
            proc.send_signal(signal.SIGINT if profile else signal.SIGTERM)
            await proc.wait()
            await drain
            sys.stderr.write("".join(f"hostd logged: {line}" for line in warned))
    finally:  # also when the daemon fails to start: no emulator left behind
        if emu is not None:
            emu.terminate()
            await emu.wait()
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--in-process", action="store_true",
                    help="emulator inside the daemon (sim://): CPU includes the emulator")
    ap.add_argument("--profile", metavar="FILE", help="run hostd under cProfile, stats to FILE")
    ap.add_argument("--partial-lines", action=argparse.BooleanOptionalAction, default=True,
                    help="serial.partial_lines (the first part of a line goes out when the "
                         "credit is short)")
    ap.add_argument("--read-hold", type=float, default=0.7,
                    help="serial.read_hold (share of the wire time still queued that a "
                         "real port is left unread while oks arrive quickly; 0: each at once)")
    ap.add_argument("--rx-buffer", type=int, default=RX_BUFFER, metavar="BYTES",
                    help="the firmware's receive buffer, for the emulator and "
                         f"serial.rx_buffer_bytes (default {RX_BUFFER}, as hostd's)")
    ap.add_argument("--advanced-ok", action="store_true",
                    help="the emulator answers ok N<n> P<p> B<b> (Marlin's ADVANCED_OK)")
    ap.add_argument("--upload", type=int, default=0, metavar="LINES",
                    help="another client submits a job of about LINES lines as the first "
                         "phase begins")
    ap.add_argument("--repeat", type=int, default=1, metavar="N",
                    help="run N times; prints each run's CPU figures with its floor, then "
                         "the median and largest of every figure")
    args = ap.parse_args()
    runs = [one_run(args) for _ in range(max(1, args.repeat))]
    mode = "in-process sim:// (CPU includes the emulator)" if args.in_process else \
        "emulator in its own process on a pty"
    print(f"hostd daemon bench, {BAUD} baud, {mode}, "
          f"partial lines {'on' if args.partial_lines else 'off'}, "
          f"read hold {args.read_hold:g}, receive buffer {args.rx_buffer} bytes, "
          f"{'ADVANCED_OK' if args.advanced_ok else 'plain'} oks")
    if len(runs) == 1:
        print_figures(runs[0])
        return 0 if within_targets(runs[0]) else 1
    print_runs(runs)
    return 0 if all(within_targets(r) for r in runs) else 1


def one_run(args: argparse.Namespace) -> dict[str, float]:
    """One whole bench run, the floor measured right after it."""
    with tempfile.TemporaryDirectory(prefix="hostd-bench-") as name:
        res = asyncio.run(bench(Path(name), args.in_process, args.profile, args.partial_lines,
                                args.read_hold, args.rx_buffer, args.advanced_ok,
                                args.upload))
    res["floor_us_per_wakeup"] = 1e6 * wakeup.measure(3000, 0.00168, write=True)[0]
    res["ended"] = time.time()
    return res


def within_targets(res: dict[str, float]) -> bool:
    return all(res[k] < v for k, v in TARGETS.items() if k in res)


def print_figures(res: dict[str, float]) -> None:
    for key, value in res.items():
        if key == "ended":
            continue
        target = TARGETS.get(key)
        mark = "" if target is None else (" ok" if value < target else " OVER TARGET")
        print(f"{key:28} {value:10.2f}{'' if target is None else f'  (target < {target:g})'}"
              f"{mark}")


RUN_COLUMNS = ("floor_us_per_wakeup", "watch_cpu_pct", "stream_cpu_pct", "status_p99_ms",
               "idle_rss_mb", "link_timeouts")


def print_runs(runs: list[dict[str, float]]) -> None:
    """A line a run (its end time, floor and the targets' figures), then median and max."""
    print("run  ended     " + " ".join(f"{c:>19}" for c in RUN_COLUMNS))
    for i, r in enumerate(runs, 1):
        ended = time.strftime("%H:%M:%S", time.localtime(r["ended"]))
        print(f"{i:<4} {ended}  " + " ".join(f"{r[c]:19.2f}" for c in RUN_COLUMNS))
    for name, fn in (("median", statistics.median), ("max", max)):
        print(f"{name:<15}" + " ".join(f"{fn([r[c] for r in runs]):19.2f}"
                                       for c in RUN_COLUMNS))
    for key, target in TARGETS.items():
        over = sum(r[key] >= target for r in runs)
        print(f"{key}: target < {target:g}, {len(runs) - over} of {len(runs)} runs within")

if __name__ == "__main__":
    sys.exit(main())
