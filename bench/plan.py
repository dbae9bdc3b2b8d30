"""Seconds per planning stage (plan_print only) for the samples and a ~50k-face branched pipe.

Run: ``.venv/bin/python bench/plan.py [--repeat N] [models ...]`` (target: the 50k-face pipe
planned in ≤ 3 s, a small share of the 10 s STL → checked G-code budget of ``bench/slice.py``).
Each model is decomposed once, then planned N times (default 3); the fastest run is reported
with its process CPU time next to the wall time (on a shared machine the wall time of a single
run mostly measures the neighbours). The skeleton cache is cleared before every run.
"""

from __future__ import annotations

import argparse
import importlib.util
import time
from pathlib import Path

from kinematics.machine import MachineGeometry
from slicer import planner
from slicer.decompose import DecomposeSettings, Decomposition, decompose
from slicer.plan import PrintPlan
from slicer.printhead import Printhead
from slicer.settings import ProcessSettings


def _decompose_bench():
    """bench/decompose.py as a module: the same models and the same 50k-face pipe."""
    spec = importlib.util.spec_from_file_location(
        "bench_decompose", Path(__file__).resolve().parent / "decompose.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


MODELS = _decompose_bench().MODELS

STAGES = ("sections", "skeleton", "layers", "zones", "toolpaths", "obstacles")


def best_of(dec: Decomposition, repeat: int) -> tuple[PrintPlan, float, float]:
    """The fastest of ``repeat`` plans: (plan, wall s, CPU s)."""
    head, machine, settings = Printhead.default(), MachineGeometry(), ProcessSettings()
    best = None
    for _ in range(repeat):
        planner._CURVES.clear()
        planner._SOLIDS.clear()
        wall, cpu = time.perf_counter(), time.process_time()
        plan = planner.plan_print(dec, settings, machine, head)
        run = (plan, time.perf_counter() - wall, time.process_time() - cpu)
        best = run if best is None or run[1] < best[1] else best
    assert best is not None
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="runs per model (best reported)")
    parser.add_argument("models", nargs="*", help=f"any of {', '.join(MODELS)} (default: all)")
    args = parser.parse_args()
    unknown = set(args.models) - set(MODELS)
    if unknown:
        parser.error(f"unknown model(s) {', '.join(sorted(unknown))}; choose from "
                     f"{', '.join(MODELS)}")
    print(f"{'model':>10} {'faces':>7} {'parts':>5} {'layers':>6} {'paths':>6} "
          + " ".join(f"{k:>9}" for k in STAGES) + f" {'wall s':>7} {'cpu s':>6}")
    for name in args.models or MODELS:
        mesh = MODELS[name]()
        dec = decompose(mesh, DecomposeSettings(), MachineGeometry(), Printhead.default())
        plan, wall, cpu = best_of(dec, args.repeat)
        layers = [la for sp in plan.subparts for la in sp.layers]
        paths = sum(len(la.paths) for la in layers)
        stages = " ".join(f"{plan.timings.get(k, 0.0):>9.3f}" for k in STAGES)
        print(f"{name:>10} {len(mesh.faces):>7} {len(plan.subparts):>5} {len(layers):>6} "
              f"{paths:>6} {stages} {wall:>7.2f} {cpu:>6.2f}", flush=True)


if __name__ == "__main__":
    main()
