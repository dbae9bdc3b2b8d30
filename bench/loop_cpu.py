"""Where the daemon's CPU goes while it streams: thread CPU per event-loop callback.

Run: ``.venv/bin/python bench/loop_cpu.py [--top 25] [-- BENCH_ARG...]``. It runs
``bench/daemon.py`` once (with the arguments after ``--``, e.g. ``-- --advanced-ok``) with
:mod:`loop_site` installed as ``sitecustomize`` in the daemon's process, and prints, over the
daemon's whole life (start-up, idle, both streaming phases, shutdown), the thread CPU of
each kind of event-loop callback (a task's steps under its coroutine's name), of the
``epoll`` waits, of ``os.read`` and ``os.write``, and of a few methods of the serial link
(nested in the callbacks: ``DirectSerialTransport._read_held`` is one held read of the port
and everything it sets off), of the ``printer.status`` snapshot and its parts, of the job's
progress bookkeeping and of the streamer's batch work. Milliseconds in all, calls,
microseconds a call.

The timing itself costs a few microseconds a timed call, so the figures are a little high;
they tell where the time goes, while ``bench/daemon.py`` gives the CPU share.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
DAEMON_PROGRAM = "hostd/main.py"  # the daemon's sys.argv[0] under ``python -m hostd.main``


def run_bench(tmp: Path, extra: list[str]) -> str:
    """One ``bench/daemon.py`` run (arguments ``extra``) with the timing installed; its own
    output."""
    site = tmp / "site"
    site.mkdir()
    shutil.copy(HERE / "loop_site.py", site / "sitecustomize.py")
    env = {**os.environ, "PYTHONPATH": str(site),
           "HOSTD_LOOP_CPU": str(tmp / "loop")}
    done = subprocess.run([sys.executable, str(HERE / "daemon.py"), *extra], env=env,
                          capture_output=True, text=True, check=False)
    return done.stdout + done.stderr


def daemon_totals(tmp: Path) -> tuple[int, list[tuple[int, int, str]]]:
    """The daemon's process CPU (ns) and its (calls, ns, name) rows."""
    for path in tmp.glob("loop.*"):
        program, cpu, *rows = path.read_text().splitlines()
        if program.endswith(DAEMON_PROGRAM):
            table = [(int(c), int(ns), name) for c, ns, name in
                     (row.split("\t", 2) for row in rows)]
            return int(cpu), table
    raise SystemExit("the daemon wrote no figures (did bench/daemon.py run?)")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--top", type=int, default=25, help="rows to print (default 25)")
    ap.add_argument("bench_args", nargs="*", metavar="-- BENCH_ARG",
                    help="arguments for bench/daemon.py, after --")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="hostd-loop-") as name:
        tmp = Path(name)
        output = run_bench(tmp, args.bench_args)
        cpu, table = daemon_totals(tmp)
    print(output.rstrip())
    print(f"\ndaemon process CPU {cpu / 1e6:.1f} ms over its life; by callback:")
    print(f"{'ms':>9} {'calls':>8} {'us/call':>8}  name")
    for calls, ns, name in sorted(table, key=lambda row: -row[1])[:args.top]:
        print(f"{ns / 1e6:9.1f} {calls:8d} {ns / 1e3 / max(calls, 1):8.1f}  {name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
