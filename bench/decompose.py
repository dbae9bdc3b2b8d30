"""Seconds per decomposition stage for the samples, a ~50k-face branched pipe and the hard
models.

Run: ``.venv/bin/python bench/decompose.py [--repeat N] [--refine-steps 0] [--worker
{yes,no,both}] [MODEL ...]`` (target: the 50k-face pipe in under 2 s; ``--refine-steps 0``
skips the plane refinement). A MODEL is a bench model or ``h:NAME``, the hard model
``shared/models/hard/NAME.stl`` made 50 000 faces. Each model is decomposed N times (default
3) and the fastest run is reported, with its process CPU time next to the wall time (its
worker's included): on a shared machine the wall time of a single run mostly measures the
neighbours. ``--worker`` says whether the attempts after a slow first one may go to a worker
process (``yes``, as the slicer does: :mod:`slicer.decompose.ahead`, which still starts
none when the first attempt is quick or other processes keep the cores busy), must all be
made here (``no``), or both, side by side in one run (a row each, the runs alternated).
"""

from __future__ import annotations

import argparse
import math

import trimesh
from harness import MODELS, best_of, check_models, model_mesh

import slicer.decompose.ahead as ahead
from kinematics.machine import MachineGeometry
from slicer.decompose import DecomposeSettings, Decomposition, SearchSettings, decompose
from slicer.printhead import Printhead

STAGES = ("load", "partition", "build_order", "planes_split", "verify", "waited")
WORKER = {"yes": (True,), "no": (False,), "both": (False, True)}


def decompose_once(mesh: trimesh.Trimesh, refine_steps: int, worker: bool) -> Decomposition:
    settings = DecomposeSettings(search=SearchSettings(refine_steps=refine_steps))
    after = ahead.AHEAD_AFTER
    ahead.AHEAD_AFTER = after if worker else math.inf
    try:
        return decompose(mesh, settings, MachineGeometry(), Printhead.default())
    finally:
        ahead.AHEAD_AFTER = after


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="runs per model (best reported)")
    parser.add_argument("--refine-steps", type=int, default=SearchSettings().refine_steps,
                        help="plane refinement steps (0: the paper's first feasible plane)")
    parser.add_argument("--worker", choices=sorted(WORKER), default="yes",
                        help="attempts after a slow first one shared with a worker process")
    parser.add_argument("models", nargs="*",
                        help=f"any of {', '.join(MODELS)}, or h:NAME (default: the former)")
    args = parser.parse_args()
    models = {n: model_mesh(n) for n in check_models(parser, args.models, hard=True)}
    print(f"{'model':>12} {'faces':>7} {'parts':>5} {'iters':>5} {'tries':>5} {'worker':>6} "
          + " ".join(f"{k:>12}" for k in STAGES) + f" {'wall s':>7} {'cpu s':>6}")
    for name, mesh in models.items():
        runs = {w: [] for w in WORKER[args.worker]}
        for _ in range(max(1, args.repeat)):  # alternated: the machine's drift hits both
            for w, got in runs.items():
                got.append(best_of(lambda m=mesh, w=w: decompose_once(m, args.refine_steps,
                                                                       w), 1))
        for w, got in runs.items():
            dec, wall, cpu = min(got, key=lambda r: r[1])
            iters = sum(s.iterations for s in dec.subparts)
            stages = " ".join(f"{dec.timings.get(k, 0.0):>12.3f}" for k in STAGES)
            print(f"{name:>12} {len(mesh.faces):>7} {len(dec.subparts):>5} {iters:>5} "
                  f"{len(dec.attempts):>5} {'yes' if w else 'no':>6} {stages} {wall:>7.2f} "
                  f"{cpu:>6.2f}", flush=True)


if __name__ == "__main__":
    main()
