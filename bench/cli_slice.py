"""Wall and CPU seconds of a fresh ``hostctl slice`` process, as an operator runs it.

Run: ``.venv/bin/python bench/cli_slice.py [--model pipe3-50k] [--height 0.2] [--repeat 3]``.
The model is written to an STL file in a temporary directory, then sliced ``--repeat`` times
by ``hostctl slice MODEL.stl -o OUT.gcode --layer-height H`` (the default config), each in a
process of its own. Printed per run: the process's wall seconds (start to exit: interpreter,
imports, config, slice, file written), its CPU seconds (user + system, worker processes
included), and the ``seconds`` the command itself reports (from before the slicer's
imports). :mod:`slice` times ``slice_model`` alone, in a process that has imported it.
"""

from __future__ import annotations

import argparse
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from harness import MODELS, check_models

SECONDS = re.compile(r"^seconds ([0-9.]+)", re.MULTILINE)


def hostctl() -> list[str]:
    """The ``hostctl`` beside this interpreter, or the module it runs."""
    script = Path(sys.executable).with_name("hostctl")
    return [str(script)] if script.exists() else [sys.executable, "-m", "hostd.cli.main"]


def children_cpu() -> float:
    """CPU seconds of the waited-for child processes so far."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def one_run(stl: Path, out: Path, height: float) -> tuple[float, float, float]:
    """(wall s, CPU s, the command's own seconds) of one ``hostctl slice``."""
    cmd = [*hostctl(), "slice", str(stl), "-o", str(out), "--layer-height", str(height)]
    cpu, wall = children_cpu(), time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    wall, cpu = time.perf_counter() - wall, children_cpu() - cpu
    if done.returncode != 0:
        sys.exit(f"hostctl slice failed ({done.returncode}): {done.stderr.strip()}")
    found = SECONDS.search(done.stdout)
    return wall, cpu, float(found.group(1)) if found else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="pipe3-50k", help=f"any of {', '.join(MODELS)}")
    parser.add_argument("--height", type=float, default=0.2)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    check_models(parser, [args.model])
    with tempfile.TemporaryDirectory() as tmp:
        stl = Path(tmp) / f"{args.model}.stl"
        MODELS[args.model]().export(stl)
        runs = [one_run(stl, Path(tmp) / "out.gcode", args.height)
                for _ in range(max(1, args.repeat))]
    print(f"hostctl slice {args.model}.stl --layer-height {args.height:g}")
    for i, (wall, cpu, own) in enumerate(runs, 1):
        print(f"  run {i}: {wall:6.2f} s wall  {cpu:6.2f} s CPU  (reported {own:.2f} s)")
    walls = [r[0] for r in runs]
    print(f"  best {min(walls):.2f} s, median {statistics.median(walls):.2f} s wall")


if __name__ == "__main__":
    main()
