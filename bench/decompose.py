"""Seconds per decomposition stage for the samples and a ~50k-face branched pipe.

Run: ``.venv/bin/python bench/decompose.py [--repeat N] [--refine-steps 0]`` (target: the
50k-face pipe in under 2 s; ``--refine-steps 0`` skips the plane refinement). Each model is
decomposed N times (default 3) and the fastest run is reported, with its process CPU time
next to the wall time: on a shared machine the wall time of a single run mostly measures the
neighbours.
"""

from __future__ import annotations

import argparse

import trimesh
from harness import MODELS, best_of, check_models

from kinematics.machine import MachineGeometry
from slicer.decompose import DecomposeSettings, Decomposition, SearchSettings, decompose
from slicer.printhead import Printhead

STAGES = ("load", "partition", "build_order", "planes_split", "verify")


def decompose_once(mesh: trimesh.Trimesh, refine_steps: int) -> Decomposition:
    settings = DecomposeSettings(search=SearchSettings(refine_steps=refine_steps))
    return decompose(mesh, settings, MachineGeometry(), Printhead.default())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="runs per model (best reported)")
    parser.add_argument("--refine-steps", type=int, default=SearchSettings().refine_steps,
                        help="plane refinement steps (0: the paper's first feasible plane)")
    parser.add_argument("models", nargs="*", help=f"any of {', '.join(MODELS)} (default: all)")
    args = parser.parse_args()
    models = {name: MODELS[name]() for name in check_models(parser, args.models)}
    print(f"{'model':>10} {'faces':>7} {'parts':>5} {'iters':>5} "
          + " ".join(f"{k:>12}" for k in STAGES) + f" {'wall s':>7} {'cpu s':>6}")
    for name, mesh in models.items():
        dec, wall, cpu = best_of(lambda m=mesh: decompose_once(m, args.refine_steps),
                                  args.repeat)
        iters = sum(s.iterations for s in dec.subparts)
        stages = " ".join(f"{dec.timings.get(k, 0.0):>12.3f}" for k in STAGES)
        print(f"{name:>10} {len(mesh.faces):>7} {len(dec.subparts):>5} {iters:>5} {stages} "
              f"{wall:>7.2f} {cpu:>6.2f}", flush=True)


if __name__ == "__main__":
    main()
