"""The reference pipes exported turned: which face each stands on, the outcome and its cost.

Run: ``.venv/bin/python bench/flipped.py [--repeat N] [--as-placed]``. Every model of
``../shared/models`` is written to STL turned as a user might have exported it (180° and 90°
about X; pipe2 135° about Y, its branch end straight down; pipe3 with its 150° branch
pointing down), loaded as ``hostctl`` loads it, and decomposed by
:func:`slicer.decompose.decompose_on_bases` (``--as-placed``: by ``decompose`` alone, the part as
the loader stands it, as before the base choice). Printed per case: the face it stands on (mm²,
and whether it was turned), sub-parts, overhang, wall and process CPU seconds of the fastest
of N runs, and a refusal's first words. Last, the cost of the base search alone
(:func:`slicer.mesh.placement.flat_bases`) on a part that stands well, on the 50k-face pipe3.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import trimesh
from harness import best_of, pipe3_50k

from kinematics.machine import MachineGeometry
from slicer.decompose import (
    DecomposeSettings,
    Decomposition,
    DecompositionError,
    decompose,
    decompose_on_bases,
)
from slicer.mesh import flat_bases, load_mesh, standing_base
from slicer.printhead import Printhead

MODELS = Path(__file__).resolve().parents[2] / "shared" / "models"
HEAD = Printhead.default()
MACHINE = MachineGeometry()
BRANCH2 = np.array([np.cos(np.radians(150.0)), np.sin(np.radians(150.0)), 1.0]) / np.sqrt(2.0)


def turns() -> dict[str, np.ndarray]:
    """The 4×4 turns a file is exported with."""
    rot = trimesh.transformations.rotation_matrix
    return {"upright": np.eye(4), "x180": rot(np.pi, [1, 0, 0]), "x90": rot(np.pi / 2, [1, 0, 0]),
            "y135": rot(np.radians(135.0), [0, 1, 0]),
            "branch2down": trimesh.geometry.align_vectors(BRANCH2, [0.0, 0.0, -1.0])}


CASES = [("pipe2", "upright"), ("pipe2", "x180"), ("pipe2", "x90"), ("pipe2", "y135"),
         ("pipe3", "upright"), ("pipe3", "x180"), ("pipe3", "x90"), ("pipe3", "branch2down"),
         ("cylinder", "x180"), ("cylinder", "x90")]


def run(path: Path, as_placed: bool) -> tuple[Decomposition | str, float]:
    """(the decomposition or the refusal, area of the face it stands on)."""
    mesh, placement = load_mesh(path)
    try:
        if as_placed:
            dec = decompose(mesh, DecomposeSettings(), MACHINE, HEAD, None, placement.matrix)
            return dec, standing_base(mesh).area
        dec = decompose_on_bases(mesh, DecomposeSettings(), MACHINE, HEAD, None,
                                 placement.matrix)
    except DecompositionError as exc:
        return str(exc), standing_base(mesh).area
    assert dec.base is not None
    return dec, dec.base.area


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=1, help="runs per case (best reported)")
    parser.add_argument("--as-placed", action="store_true",
                        help="decompose as the loader stands it (no other face tried)")
    args = parser.parse_args()
    print(f"{'model':>9} {'exported':>11} {'stands on':>13} {'parts':>5} {'overhang':>9} "
          f"{'wall s':>7} {'cpu s':>6}  outcome")
    with tempfile.TemporaryDirectory() as tmp:
        for model, turn in CASES:
            mesh = trimesh.load_mesh(MODELS / f"{model}.stl")
            mesh.apply_transform(turns()[turn])
            path = Path(tmp) / f"{model}_{turn}.stl"
            mesh.export(path)
            (out, area), wall, cpu = best_of(lambda p=path: run(p, args.as_placed), args.repeat)
            _row(model, turn, out, area, wall, cpu)
    big = pipe3_50k()
    _, wall, cpu = best_of(lambda: flat_bases(big), 3)
    print(f"flat_bases on pipe3-50k ({len(big.faces)} faces): {wall * 1e3:.0f} ms wall, "
          f"{cpu * 1e3:.0f} ms CPU")


def _row(model: str, turn: str, out: Decomposition | str, area: float, wall: float,
         cpu: float) -> None:
    if isinstance(out, str):
        face, parts, over, outcome = f"{area:.0f} mm²", "-", "-", f"refused: {out[:60]}..."
    else:
        turned = out.base is not None and out.base.turn is not None
        face = f"{area:.0f} mm²{' (T)' if turned else ''}"
        parts, over, outcome = str(len(out.subparts)), f"{out.overhang_area:.1f}", "ok"
    print(f"{model:>9} {turn:>11} {face:>13} {parts:>5} {over:>9} {wall:>7.2f} {cpu:>6.2f}  "
          f"{outcome}", flush=True)


if __name__ == "__main__":
    main()
