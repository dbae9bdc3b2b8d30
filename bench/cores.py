"""How many cores a slice keeps busy, stage by stage: where the second core idles.

Run: ``.venv/bin/python bench/cores.py [--model pipe3-50k] [--height 0.2] [--every 0.1]``.
One cold slice (STL to checked G-code, as ``hostctl slice`` does) while a thread reads the
machine's busy time from ``/proc/stat`` every ``--every`` seconds. Printed: one row per
interval with the busy cores (0 to the core count, the whole machine's: run it on an
otherwise idle machine) as a bar, and the pipeline stage running on the main thread then
(``text``, the file's formatting, runs beside ``read`` and ``replay``); then the mean busy
cores per stage. A stage well under the core count is where work could overlap.
"""

from __future__ import annotations

import argparse
import os
import statistics
import threading
import time
from pathlib import Path

from harness import MODELS, check_models

from kinematics.machine import MachineGeometry
from slicer.paths import planner
from slicer.pipeline import slice_model
from slicer.printhead import Printhead
from slicer.settings import ProcessSettings

MAIN_STAGES = ("load", "plan", "gcode", "read", "replay")  # in order, on the main thread


def _busy_total() -> tuple[int, int]:
    """(busy, total) clock ticks of the whole machine so far."""
    ticks = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    idle = ticks[3] + ticks[4]  # idle, iowait
    return sum(ticks) - idle, sum(ticks)


class Sampler(threading.Thread):
    """Busy cores per interval, as (end time since start s, cores)."""

    def __init__(self, every: float) -> None:
        super().__init__(daemon=True)
        self.every, self.cores = every, os.cpu_count() or 1
        self.rows: list[tuple[float, float]] = []
        self.stop = threading.Event()
        self.t0 = time.perf_counter()

    def run(self) -> None:
        busy, total = _busy_total()
        while not self.stop.wait(self.every):
            b, t = _busy_total()
            self.rows.append((time.perf_counter() - self.t0,
                              self.cores * (b - busy) / max(t - total, 1)))
            busy, total = b, t


def _stage_at(t: float, bounds: list[tuple[float, str]]) -> str:
    """The main-thread stage running at ``t`` s (bounds: (end s, name) in order)."""
    return next((name for end, name in bounds if t <= end), "")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="pipe3-50k")
    parser.add_argument("--height", type=float, default=0.2)
    parser.add_argument("--every", type=float, default=0.1, help="seconds per row")
    args = parser.parse_args()
    check_models(parser, [args.model])
    mesh = MODELS[args.model]()
    planner.clear_caches()
    sampler = Sampler(args.every)
    sampler.start()
    res = slice_model(mesh, ProcessSettings(layer_height=args.height), MachineGeometry(),
                      Printhead.default())
    sampler.stop.set()
    sampler.join()
    end, bounds = 0.0, []
    for name in MAIN_STAGES:
        end += res.timings.get(name, 0.0)
        bounds.append((end, name))
    width = 40
    per_stage: dict[str, list[float]] = {name: [] for name in MAIN_STAGES}
    print(f"{args.model} at {args.height} mm: {res.seconds:.2f} s wall, "
          f"{sampler.cores} cores")
    for t, busy in sampler.rows:
        stage = _stage_at(t - 0.5 * args.every, bounds)
        per_stage.setdefault(stage, []).append(busy)
        bar = "#" * round(width * busy / sampler.cores)
        print(f"{t:6.2f} s {bar:<{width}} {busy:4.2f} {stage}")
    print("mean busy cores per stage: " + ", ".join(
        f"{name} {statistics.mean(v):.2f}" for name, v in per_stage.items() if v and name))


if __name__ == "__main__":
    main()
