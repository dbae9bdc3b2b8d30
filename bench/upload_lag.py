"""How long the daemon's event loop stalls while an operator queues a large job mid-print.

Run: ``.venv/bin/python bench/upload_lag.py [--lines 400000] [--runs 3] [--checkout DIR]``.
A daemon runs in this process on the built-in emulator (``sim://``, unthrottled) and prints
a job; a task on its event loop wakes every millisecond and records the gaps between its
wake-ups. Meanwhile ``hostctl print`` (the checkout's own, in a process of its own) queues a
G-code job of about ``--lines`` lines. Printed per run: the seconds ``hostctl print`` took and
the longest gaps of the loop while it ran. A gap is time the serial stream could not be fed:
with Marlin's 127-byte buffer at 250000 baud, the buffer holds 5 ms of wire.
``--checkout DIR`` measures another version of this repository (e.g. a ``git worktree``).
``--costs`` first prints what the file costs in one go on this machine: ``json.loads`` of
one request holding it as base64, the base64 decode, the G-code parse, and a pickle of its
bytes (what sending it to a worker process would take).
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import json
import pickle
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parents[1]


async def ticker(gaps: list[float], stop: asyncio.Event) -> None:
    """Wake every millisecond; each wake-up's gap since the last into ``gaps``."""
    last = time.perf_counter()
    while not stop.is_set():
        await asyncio.sleep(0.001)
        now = time.perf_counter()
        gaps.append(now - last)
        last = now


async def one_run(root: Path, lines: int) -> tuple[float, list[float]]:
    from daemon import synthetic_gcode  # bench/daemon.py of ``root``

    from hostd.config.loader import defaults
    from hostd.daemon import Daemon

    with tempfile.TemporaryDirectory() as name:
        tmp = Path(name)
        cfg = defaults().replace(daemon__state_dir=str(tmp / "state"),
                                 daemon__socket=str(tmp / "hostd.sock"),
                                 serial__port="sim://", metrics__enabled=False)
        d = Daemon(cfg)
        await d.start()
        try:
            await d.jobs.submit("printing.gcode", synthetic_gcode(3, 30, 200).encode())
            upload = tmp / "next.gcode"
            upload.write_text(synthetic_gcode(1, max(1, lines // 200), 200))
            return await timed_print(root, tmp / "hostd.sock", upload)
        finally:
            await d.close()


async def timed_print(root: Path, sock: Path, upload: Path) -> tuple[float, list[float]]:
    """``hostctl print upload`` while the ticker runs: its seconds and the loop's gaps."""
    gaps: list[float] = []
    stop = asyncio.Event()
    task = asyncio.create_task(ticker(gaps, stop))
    t0 = time.perf_counter()
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "hostd.cli.main", "--socket", str(sock), "print", str(upload),
        cwd=str(root), stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.PIPE)
    _, err = await proc.communicate()
    took = time.perf_counter() - t0
    stop.set()
    await task
    if proc.returncode:
        raise SystemExit(f"hostctl print failed: {err.decode().strip()}")
    return took, sorted(gaps)


def costs(lines: int) -> None:
    """The one-go costs of a file of ``lines`` lines, in milliseconds: the first of 3 runs
    (as in the daemon, whose buffers are fresh) and the best."""
    from daemon import synthetic_gcode

    from hostd.printer.program import parse_program

    text = synthetic_gcode(1, max(1, lines // 200), 200)
    data = text.encode()
    encoded = base64.b64encode(data).decode()
    request = json.dumps({"jsonrpc": "2.0", "id": 1, "method": "job.submit",
                          "params": {"name": "next.gcode", "data": encoded}})
    steps = {"json.loads of the request": lambda: json.loads(request),
             "base64 decode": lambda: base64.b64decode(encoded, validate=True),
             "G-code parse": lambda: parse_program(text),
             "pickle of the bytes": lambda: pickle.dumps(data, protocol=5)}
    print(f"{len(data) / 1e6:.1f} MB of G-code, {len(request) / 1e6:.1f} MB as one request")
    for name, step in steps.items():
        runs = [_timed(step) for _ in range(3)]
        print(f"  {name:28s} first {runs[0] * 1e3:7.1f} ms, best {min(runs) * 1e3:7.1f} ms")


def _timed(step: Any) -> float:
    t0 = time.perf_counter()
    step()
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lines", type=int, default=400_000, help="lines of the queued job")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--checkout", type=Path, default=HERE,
                    help="the version of this repository to measure (default: this one)")
    ap.add_argument("--costs", action="store_true", help="first, the one-go costs")
    args = ap.parse_args()
    root = args.checkout.resolve()
    sys.path[:0] = [str(root), str(root / "bench")]
    if args.costs:
        costs(args.lines)
    print(f"{root}: hostctl print of a {args.lines}-line job while one prints")
    for k in range(args.runs):
        took, gaps = asyncio.run(one_run(root, args.lines))
        longest = " ".join(f"{g * 1e3:.1f}" for g in gaps[:-7:-1])
        print(f"run {k + 1}: hostctl print {took:.2f} s, {len(gaps)} ticks, "
              f"longest loop gaps (ms): {longest}", flush=True)


if __name__ == "__main__":
    main()
