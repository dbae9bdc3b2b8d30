"""Seconds per decomposition stage for the samples and a ~50k-face branched pipe.

Run: ``.venv/bin/python bench/decompose.py [--repeat N]`` (target: the 50k-face pipe in under
2 s). Each model is decomposed N times (default 3) and the fastest run is reported, with its
process CPU time next to the wall time: on a shared machine the wall time of a single run
mostly measures the neighbours.
"""

from __future__ import annotations

import argparse
import time

import trimesh

from kinematics.machine import MachineGeometry
from slicer import samples
from slicer.decompose import DecomposeSettings, Decomposition, decompose
from slicer.printhead import Printhead

STAGES = ("load", "partition", "build_order", "planes_split", "verify")


def remeshed_pipe3(target: int = 50_000) -> trimesh.Trimesh:
    """pipe3 with finer circles, split 1 → 4 until it has about ``target`` faces."""
    mesh = samples.pipe3(segments=96)
    while len(mesh.faces) * 4 <= target * 1.5:
        mesh = mesh.subdivide()
    return mesh


MODELS = {"cylinder": samples.cylinder, "pipe2": samples.pipe2, "pipe3": samples.pipe3,
          "curved": samples.curved_pipe, "pipe3-50k": remeshed_pipe3}


def best_of(mesh: trimesh.Trimesh, repeat: int) -> tuple[Decomposition, float, float]:
    """The fastest of ``repeat`` decompositions: (result, wall s, CPU s)."""
    head, machine = Printhead.default(), MachineGeometry()
    best = None
    for _ in range(repeat):
        wall, cpu = time.perf_counter(), time.process_time()
        dec = decompose(mesh, DecomposeSettings(), machine, head)
        run = (dec, time.perf_counter() - wall, time.process_time() - cpu)
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
    models = {name: MODELS[name]() for name in args.models or MODELS}
    print(f"{'model':>10} {'faces':>7} {'parts':>5} {'iters':>5} "
          + " ".join(f"{k:>12}" for k in STAGES) + f" {'wall s':>7} {'cpu s':>6}")
    for name, mesh in models.items():
        dec, wall, cpu = best_of(mesh, args.repeat)
        iters = sum(s.iterations for s in dec.subparts)
        stages = " ".join(f"{dec.timings.get(k, 0.0):>12.3f}" for k in STAGES)
        print(f"{name:>10} {len(mesh.faces):>7} {len(dec.subparts):>5} {iters:>5} {stages} "
              f"{wall:>7.2f} {cpu:>6.2f}", flush=True)


if __name__ == "__main__":
    main()
