"""Seconds per slicing stage, STL to checked G-code, with the paper's Table 1 comparison.

Run: ``.venv/bin/python bench/slice.py [--heights 0.1 0.2 0.3] [--models pipe2 ...]
[--repeat N] [--no-layer-processes]`` (``--repeat``: the fastest of N slices per case is
shown; ``--no-layer-processes``: long sub-parts' toolpaths on threads only).
Each model and layer height is sliced five-axis (decompose, plan, G-code, read, replay) and
planar (A = C = 0, no decomposition). Printed: seconds per stage, total wall and CPU time,
filament and time of both prints and the decrement (the paper's Table 1). Target: pipe3-50k
at 0.2 mm in under 10 s. On a shared machine the wall time also measures the neighbours, so
the CPU time (with the worker processes') is printed beside it. ``paths`` is the toolpath
part of ``plan``; ``gcode`` builds the program's moves, ``text`` (the estimate and the
formatted lines) runs on a thread beside ``read`` and ``replay``. The slices run in this
process, its imports done: :mod:`cli_slice` times whole ``hostctl slice`` processes.
"""

from __future__ import annotations

import argparse
import contextlib

import trimesh
from harness import MODELS, best_of, check_models

from kinematics.machine import MachineGeometry
from slicer.paths import planner
from slicer.pipeline import SliceResult, slice_model
from slicer.printhead import Printhead
from slicer.settings import ProcessSettings

STAGES = ("load", "plan", "plan.paths", "gcode", "text", "read", "replay")  # paths: in plan


def run(mesh: trimesh.Trimesh, height: float, planar: bool, repeat: int
        ) -> tuple[SliceResult, float, float]:
    """The fastest of ``repeat`` slices, each from cold caches, as a fresh ``hostctl slice``
    runs (the planner keeps skeletons and solids of a mesh it has seen): (result, wall s,
    CPU s)."""
    def cold() -> SliceResult:
        planner.clear_caches()
        return slice_model(mesh, ProcessSettings(layer_height=height), MachineGeometry(),
                           Printhead.default(), planar=planar)

    return best_of(cold, repeat)


def _row(name: str, faces: int, h: float, kind: str, res: SliceResult, wall: float,
         cpu: float) -> str:
    t = res.timings
    stages = " ".join(f"{t.get(k, 0.0):>6.2f}" for k in STAGES)
    rep = res.replay
    return (f"{name:>10} {faces:>6} {h:>4.2f} {kind:>6} {res.subparts:>3} {stages} "
            f"{wall:>7.2f} {cpu:>6.2f} {res.estimate['filament_mm']:>8.0f} "
            f"{res.estimate['time_s']:>7.0f} {100 * rep['wall_supported']:>6.2f} "
            f"{rep['collisions']:>4}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--heights", type=float, nargs="+", default=[0.1, 0.2, 0.3])
    parser.add_argument("--models", nargs="*", default=[], help=f"any of {', '.join(MODELS)} "
                        "(default: pipe2 pipe3 at every height, pipe3-50k at 0.2)")
    parser.add_argument("--repeat", type=int, default=1,
                        help="slices per case; the fastest is shown (the machine may be shared)")
    parser.add_argument("--no-layer-processes", action="store_true",
                        help="the toolpaths of long sub-parts on threads only, not in worker "
                             "processes by chunks of layers (the comparison)")
    args = parser.parse_args()
    check_models(parser, args.models)
    if args.no_layer_processes:
        planner.layer_processes = lambda longest: contextlib.nullcontext(None)
    jobs = ([(m, h) for m in args.models for h in args.heights] if args.models else
            [(m, h) for m in ("pipe2", "pipe3") for h in args.heights] + [("pipe3-50k", 0.2)])
    print(f"{'model':>10} {'faces':>6} {'h':>4} {'kind':>6} {'sp':>3} "
          + " ".join(f"{k.removeprefix('plan.'):>6}" for k in STAGES)
          + f" {'wall s':>7} {'cpu s':>6} {'fil mm':>8} {'time s':>7} {'wall%':>6} {'coll':>4}")
    table = []
    for name, h in jobs:
        mesh = MODELS[name]()
        five, w5, c5 = run(mesh, h, planar=False, repeat=args.repeat)
        print(_row(name, len(mesh.faces), h, "5-axis", five, w5, c5), flush=True)
        flat, wp, cp = run(mesh, h, planar=True, repeat=args.repeat)
        print(_row(name, len(mesh.faces), h, "planar", flat, wp, cp), flush=True)
        table.append((name, h, flat.estimate, five.estimate))
    print("\nTable 1 (planar vs five-axis; the paper's planar prints include support)")
    print(f"{'model':>10} {'h':>4} {'fil planar':>10} {'fil 5ax':>8} {'dec %':>6} "
          f"{'t planar':>9} {'t 5ax':>7} {'dec %':>6}")
    for name, h, p, f in table:
        fp, ff, tp, tf = (float(p["filament_mm"]), float(f["filament_mm"]),
                          float(p["time_s"]), float(f["time_s"]))
        print(f"{name:>10} {h:>4.2f} {fp:>10.0f} {ff:>8.0f} {100 * (fp - ff) / fp:>6.2f} "
              f"{tp:>9.0f} {tf:>7.0f} {100 * (tp - tf) / tp:>6.2f}")


if __name__ == "__main__":
    main()
