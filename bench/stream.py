"""Streaming throughput of the serial link through the emulated board on a pty.

For each baud rate, receive buffer and flow-control mode, ``hostd-sim --pty --throttle`` runs
in its own process (wire limited to baud/10 bytes/s both ways, planner on a simulated clock so
the wire is the bottleneck) and this process streams a job through ``SerialLink``: a real
five-axis slice of the sample pipe (``sliced``), synthetic planar lines (~30 bytes) and
synthetic five-axis lines carrying every axis (~65 bytes, a worst case). Printed:
lines/s, wire bytes/s, the share of the wire limit, resent lines, lines sent in parts
(``serial.partial_lines``: the first part of a line goes out when the credit is short of the
whole line) and host CPU seconds per 1000 lines.

The machine may be shared: ``--repeat N`` runs every case N times and prints its best run
(highest share; the CPU figure is the least of the N).

Run: ``.venv/bin/python bench/stream.py [--lines N] [--job sliced|planar|five-axis]
[--repeat N] [--no-partial-lines] [--read-hold SHARE]``.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import sys
import tempfile
import time
from pathlib import Path

from hostd.link import LinkSettings, SerialLink, frame


def planar_job(n: int) -> list[str]:
    """Typical planar slicer output: ``G1 X.. Y.. E..`` lines of about 30 bytes."""
    out = ["G28", "G90", "M83", "G92 E0"]
    for i in range(n - len(out)):
        t = i * 0.05
        out.append(f"G1 X{250 + 40 * math.cos(t):.2f} Y{250 + 40 * math.sin(t):.2f} "
                   f"E{0.021 + 0.002 * math.sin(t):.4f}")
    return out


def five_axis_job(n: int) -> list[str]:
    """A sliced-looking job: layer moves with A/C tilts, extrusion, a fan change per layer."""
    out = ["G28", "G90", "M83", "G92 E0"]
    for i in range(n - len(out)):
        if i % 400 == 0:
            out.append(f"M106 S{(i // 400 * 37) % 256}")
            continue
        t = i * 0.05
        out.append(f"G1 X{250 + 40 * math.cos(t):.3f} Y{250 + 40 * math.sin(t):.3f} "
                   f"Z{100 + i * 0.002:.3f} A{15 * math.sin(t / 9):.3f} C{(t * 8) % 360:.3f} "
                   f"E{0.021 + 0.002 * math.sin(t):.5f}")
    return out


async def run_case(baud: int, buffer: int, mode: str, lines: list[str],
                   partial: bool = True, read_hold: float = LinkSettings.read_hold
                   ) -> dict[str, float]:
    """Stream ``lines`` once; return the measured figures.

    ``mode``: ``pingpong``, ``window`` (byte credit of the receive buffer) or ``window+aok``
    (the board sends ADVANCED_OK, so lines waiting in its command queue free credit).
    """
    flow = mode.split("+")[0]
    aok = ["--advanced-ok"] if mode.endswith("+aok") else []
    tmp = tempfile.TemporaryDirectory(prefix="hostd-stream-")
    log = Path(tmp.name) / "executed.log"
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "hostd.sim.main", "--pty", "--throttle", "--baud", str(baud),
        "--rx-buffer-bytes", str(buffer), "--log", str(log), *aok,
        stdout=asyncio.subprocess.PIPE)
    try:
        assert proc.stdout is not None
        path = (await proc.stdout.readline()).decode().strip()
        link = SerialLink(LinkSettings(port=path, baud=baud, flow_control=flow,
                                       rx_buffer_bytes=buffer, partial_lines=partial,
                                       read_hold=read_hold, ok_timeout=5.0))
        await link.connect()
        cpu0, t0 = time.process_time(), time.perf_counter()
        sent0 = link.status()["lines_sent"]
        count = 0
        async for _ in link.stream(lines):
            count += 1
        wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
        status = link.status()
        await link.close()
    finally:
        proc.terminate()
        await proc.wait()
    with tmp:
        check_executed(log, ["M115", *lines])  # the link asks M115 when it connects
    wire = sum(len(frame(i + sent0 + 1, c)) + 1 for i, c in enumerate(lines))
    return {"lines_s": count / wall, "bytes_s": wire / wall, "share": wire / wall / (baud / 10),
            "resent": status["lines_resent"], "split": status["lines_split"],
            "cpu_per_1000": cpu / count * 1000, "acked": count}


def check_executed(log: Path, lines: list[str]) -> None:
    """Exit with a message unless the board executed ``lines`` exactly once, in order (its
    M105 nudges aside)."""
    done = [c for c in log.read_text().splitlines() if c != "M105"]
    sent = [c for c in lines if c != "M105"]
    if done != sent:
        first = next((i for i, (a, b) in enumerate(zip(done, sent, strict=False)) if a != b),
                     min(len(done), len(sent)))
        sys.exit(f"stream: the board executed {len(done)} of {len(sent)} lines, first "
                 f"difference at line {first + 1}: something was lost or repeated")


def sliced_job(n: int) -> list[str]:
    """The first ``n`` commands of a real five-axis slice of the sample two-branched pipe."""
    from hostd.config import convert, defaults
    from hostd.link import strip_gcode
    from slicer.mesh import pipe2
    from slicer.pipeline import slice_model

    result = slice_model(pipe2(), check=False, **convert.slice_inputs(defaults()))
    cmds = [c for c in map(strip_gcode, result.lines) if c]
    return cmds[len(cmds) // 3:len(cmds) // 3 + n]  # mid-print: layers, not the start script


JOBS = {"sliced": sliced_job, "planar": planar_job, "five-axis": five_axis_job}


async def main(n: int, jobs: list[str], repeat: int, partial: bool, hold: float) -> None:
    print(f"partial lines: {'on' if partial else 'off'}; read hold {hold:g}; "
          f"best of {repeat}")
    print(f"{'job':>9} {'baud':>7} {'buffer':>6} {'mode':>10} {'lines/s':>8} {'bytes/s':>8} "
          f"{'wire %':>6} {'resent':>6} {'split':>5} {'cpu s/1000':>10}")
    for job in jobs:
        await run_job(job, JOBS[job](n), repeat, partial, hold)


async def run_job(job: str, lines: list[str], repeat: int, partial: bool,
                  hold: float) -> None:
    """Every baud rate, buffer size and mode for one job."""
    for baud in (115200, 250000):
        for buffer in (127, 63):
            for flow in ("pingpong", "window", "window+aok"):
                runs = [await run_case(baud, buffer, flow, lines, partial, hold)
                        for _ in range(repeat)]
                assert all(r["acked"] == len(lines) for r in runs)
                r = max(runs, key=lambda run: run["share"])
                cpu = min(run["cpu_per_1000"] for run in runs)
                print(f"{job:>9} {baud:>7} {buffer:>6} {flow:>10} {r['lines_s']:>8.0f} "
                      f"{r['bytes_s']:>8.0f} {r['share'] * 100:>5.1f}% {r['resent']:>6.0f} "
                      f"{r['split']:>5.0f} {cpu:>10.3f}", flush=True)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--lines", type=int, default=1000)
    parser.add_argument("--job", choices=list(JOBS), action="append",
                        help="only this job (repeatable; default: all)")
    parser.add_argument("--repeat", type=int, default=1, help="runs per case; the best is shown")
    parser.add_argument("--partial-lines", action=argparse.BooleanOptionalAction,
                        default=LinkSettings.partial_lines,
                        help="send the first part of a line when the credit is short")
    parser.add_argument("--read-hold", type=float, default=LinkSettings.read_hold,
                        help="serial.read_hold: share of the wire time still queued that "
                             "the port is left unread while oks arrive quickly (0: each at "
                             "once)")
    args = parser.parse_args()
    asyncio.run(main(args.lines, args.job or list(JOBS), args.repeat, args.partial_lines,
                     args.read_hold))
