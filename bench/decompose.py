"""Seconds per decomposition stage for the samples and a ~50k-face branched pipe.

Run: ``.venv/bin/python bench/decompose.py`` (target: the 50k-face pipe in under 2 s).
"""

from __future__ import annotations

import time

import trimesh

from kinematics.machine import MachineGeometry
from slicer import samples
from slicer.decompose import DecomposeSettings, decompose
from slicer.printhead import Printhead


def remeshed_pipe3(target: int = 50_000) -> trimesh.Trimesh:
    """pipe3 with finer circles, split 1 → 4 until it has about ``target`` faces."""
    mesh = samples.pipe3(segments=96)
    while len(mesh.faces) * 4 <= target * 1.5:
        mesh = mesh.subdivide()
    return mesh


def main() -> None:
    models = {"cylinder": samples.cylinder(), "pipe2": samples.pipe2(),
              "pipe3": samples.pipe3(), "pipe3-50k": remeshed_pipe3()}
    head, machine = Printhead.default(), MachineGeometry()
    print(f"{'model':>10} {'faces':>7} {'parts':>5} {'iters':>5} "
          + " ".join(f"{k:>12}" for k in ("load", "partition", "build_order", "planes_split",
                                           "verify")) + f" {'total s':>8}")
    for name, mesh in models.items():
        t = time.perf_counter()
        dec = decompose(mesh, DecomposeSettings(), machine, head)
        total = time.perf_counter() - t
        iters = sum(s.iterations for s in dec.subparts)
        stages = " ".join(f"{dec.timings.get(k, 0.0):>12.3f}" for k in
                          ("load", "partition", "build_order", "planes_split", "verify"))
        print(f"{name:>10} {len(mesh.faces):>7} {len(dec.subparts):>5} {iters:>5} {stages} "
              f"{total:>8.2f}")


if __name__ == "__main__":
    main()
