"""Two versions of the slicer compared on the same cold slices, run alternately.

Run: ``.venv/bin/python bench/ab_slice.py --base CHECKOUT [--rounds 8] [--model pipe3-50k]
[--height 0.2]``, where CHECKOUT is another version of this repository (e.g. made by ``git
worktree add /tmp/base <commit>``); ``--model h:NAME`` takes ``shared/models/hard/NAME.stl``
made 50 000 faces, as ``bench/cura_compare.py`` does. Each round slices the model once with
the base and once with this checkout (STL to checked G-code, as ``hostctl slice`` does,
caches cleared), each in a fresh process with that checkout first on ``PYTHONPATH``. On a
shared VM the speed drifts by a fifth within minutes, so only alternation compares two
versions; the kernel's steal time of each run is printed to tell the slow spells. Printed
per run: wall, CPU (workers included), the stages, steal, the peak RSS of the slicing
process (``rss``, MiB, its worker processes not included) and an MD5 of the G-code (same
MD5: same output); then the mean and median of each figure per version. Without ``--base``
it says so and exits.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve()
FIGURES = ("wall", "cpu", "plan", "gcode", "text", "read", "replay", "steal", "rss")


def _steal_s() -> float:
    """The machine's steal time so far, s (the ``cpu`` line of ``/proc/stat``)."""
    try:
        fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()
        return int(fields[8]) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return 0.0


def one(model: str, height: float) -> dict[str, Any]:
    """One cold slice with the slicer found first on the path: its figures."""
    from harness import cpu_seconds, model_mesh

    from kinematics.machine import MachineGeometry
    from slicer.pipeline import slice_model
    from slicer.printhead import Printhead
    from slicer.settings import ProcessSettings

    try:
        from slicer.paths import planner
    except ImportError:  # a checkout from before the slicer's sub-packages
        from slicer import planner

    mesh = model_mesh(model)
    planner.clear_caches()
    steal, cpu, wall = _steal_s(), cpu_seconds(), time.perf_counter()
    res = slice_model(mesh, ProcessSettings(layer_height=height), MachineGeometry(),
                      Printhead.default())
    out: dict[str, Any] = {"wall": time.perf_counter() - wall, "cpu": cpu_seconds() - cpu,
                              "steal": _steal_s() - steal}
    out.update({k: res.timings.get(k, 0.0)
                for k in ("plan", "gcode", "text", "read", "replay")})
    out["rss"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB → MiB
    out["md5"] = hashlib.md5("\n".join(res.lines).encode()).hexdigest()[:10]
    return out


def _run(checkout: Path, model: str, height: float) -> dict[str, Any]:
    env = {**os.environ, "PYTHONPATH": str(checkout)}
    done = subprocess.run([sys.executable, str(HERE), "--one", "--model", model,
                           "--height", str(height)], env=env, capture_output=True, text=True,
                          check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def _line(tag: str, fig: dict[str, Any]) -> str:
    return (f"{tag:>5} " + " ".join(f"{k} {fig[k]:6.2f}" for k in FIGURES)
            + f" md5 {fig['md5']}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", type=Path, help="the other checkout")
    parser.add_argument("--rounds", type=int, default=8)
    parser.add_argument("--model", default="pipe3-50k",
                        help="a bench model, or h:NAME for shared/models/hard/NAME.stl made "
                             "50 000 faces")
    parser.add_argument("--height", type=float, default=0.2)
    parser.add_argument("--one", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(json.dumps(one(args.model, args.height)))
        return
    if args.base is None:
        print("nothing to compare: give --base CHECKOUT (another version of this repository)")
        return
    if not (args.base / "slicer" / "pipeline.py").is_file():
        sys.exit(f"--base {args.base}: not a checkout of this repository "
                 "(no slicer/pipeline.py)")
    runs: dict[str, list[dict[str, Any]]] = {"base": [], "this": []}
    for _ in range(args.rounds):
        for tag, checkout in (("base", args.base.resolve()), ("this", HERE.parents[1])):
            fig = _run(checkout, args.model, args.height)
            runs[tag].append(fig)
            print(_line(tag, fig), flush=True)
    for tag, figs in runs.items():
        print(f"{tag:>5} " + " ".join(
            f"{k} {statistics.mean(f[k] for f in figs):.2f}/"
            f"{statistics.median(f[k] for f in figs):.2f}" for k in FIGURES)
            + "  (mean/median)")


if __name__ == "__main__":
    main()
