"""Wall-overhang figures of issue 8 on the sample pipes, five-axis beside the planar control.

Run: ``.venv/bin/python bench/walls.py [--height 0.2] [--models pipe2 steep30 ...]``.
Each model is sliced five-axis and planar (A = C = 0, no decomposition) and replayed; printed:
inside, coverage, supported (with the bridging share), wall points supported, the number of
layers with more than 5 % of their wall points unsupported (and which), and collisions.
Targets (issue 8): five-axis walls ≥ 99.5 % with no unsupported wall layer; the planar control
failing both. The steep models have one branch 30° / 35° above the horizontal (the sample
pipes' branches leave at 45°, which a planar print's 0.2 mm layers hold within the 45° rule).
"""

from __future__ import annotations

import argparse
import re
from collections.abc import Callable

import trimesh

from kinematics.machine import MachineGeometry
from slicer.mesh import samples
from slicer.pipeline import slice_model
from slicer.printhead import Printhead
from slicer.settings import ProcessSettings

MODELS: dict[str, Callable[[], trimesh.Trimesh]] = {
    "pipe2": samples.pipe2, "pipe3": samples.pipe3,
    "steep30": lambda: samples.branched_pipe(((25.0, 0.0, 30.0),)),
    "steep35": lambda: samples.branched_pipe(((25.0, 0.0, 35.0),)),
    "curved": samples.curved_pipe}


def layer_ranges(names: list[str]) -> str:
    """``sub-part k layer i`` names as ranges per sub-part: ``0:116-139,178 1:0``."""
    runs: dict[str, list[int]] = {}
    for name in names:
        m = re.fullmatch(r"sub-part (\d+) layer (\d+)", name) or re.fullmatch(
            r"()layer (\d+)", name)
        if m:
            runs.setdefault(m.group(1), []).append(int(m.group(2)))
    out = []
    for part, idx in runs.items():
        spans, start = [], idx[0]
        for a, b in zip(idx, [*idx[1:], None], strict=True):
            if b != a + 1:
                spans.append(f"{start}-{a}" if a > start else f"{a}")
                start = b if b is not None else start
        out.append((f"{part}:" if part else "") + ",".join(spans))
    return " ".join(out) or "-"


def row(name: str, kind: str, rep: dict[str, object]) -> str:
    """One table row of a replay report."""
    bad = list(rep["unsupported_wall_layers"])  # type: ignore[call-overload]
    return (f"| {name} | {kind} | {100 * rep['inside']:.2f} % | {100 * rep['coverage']:.2f} % "
            f"| {100 * rep['supported']:.2f} % ({100 * rep['bridged']:.2f} %) "
            f"| {100 * rep['wall_supported']:.2f} % | {len(bad)} ({layer_ranges(bad)}) "
            f"| {rep['collisions']} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--height", type=float, default=0.2)
    parser.add_argument("--models", nargs="*", default=list(MODELS), choices=list(MODELS))
    args = parser.parse_args()
    print("| model | print | inside | coverage | supported (bridging) | walls supported "
          "| unsupported wall layers | collisions |")
    print("|---|---|---|---|---|---|---|---|")
    for name in args.models:
        mesh = MODELS[name]()
        for kind, planar in (("five-axis", False), ("planar", True)):
            res = slice_model(mesh, ProcessSettings(layer_height=args.height),
                              MachineGeometry(), Printhead.default(), planar=planar)
            print(row(name, kind, res.replay), flush=True)


if __name__ == "__main__":
    main()
