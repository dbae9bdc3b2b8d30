"""Seconds per planning stage (plan_print only) for the samples and a ~50k-face branched pipe.

Run: ``.venv/bin/python bench/plan.py [--repeat N] [models ...]`` (target: the 50k-face pipe
planned in ≤ 3 s, a small share of the 10 s STL → checked G-code budget of ``bench/slice.py``).
``--hard pipe3_15 tee_low ...`` plans those of ``shared/models/hard`` made 50 000 faces instead;
``--lean`` plans the root with leaning layers, as the closed loop's leaning tries do (its
stage ``lean``: pricing every direction in every band, ``lean_price``, choosing the plan,
``lean_solve``, as often as a refused cut makes it solve again, and stacking the pieces).
Each model is decomposed once, then planned N times (default 3); the fastest run is reported
with its process CPU time next to the wall time (on a shared machine the wall time of a single
run mostly measures the neighbours). The skeleton cache is cleared before every run.
``--decompositions DIR`` keeps the decompositions in DIR, so another version of the planner
runs on the same sub-parts: ``PYTHONPATH=/path/to/old/checkout .venv/bin/python bench/plan.py
--decompositions DIR`` (the stages that version reports).

Stages: sections, skeleton, layers (marching) and obstacles are wall seconds of the main
thread; paths is the wall time of the toolpath stage that follows (all sub-parts at once, the
per-layer polygon work on a thread pool, :mod:`slicer.paths.subpart_paths`); zones and toolpaths
are the CPU seconds of the threads inside it (on two cores they add up to more than paths).
"""

from __future__ import annotations

import argparse
import contextlib
import pickle
from functools import partial
from pathlib import Path

import trimesh
from harness import MODELS, best_of, check_models, hard_model

from kinematics.machine import MachineGeometry
from slicer.decompose import DecomposeSettings, Decomposition, decompose
from slicer.paths import LEAN, planner
from slicer.plan import PrintPlan
from slicer.printhead import Printhead
from slicer.settings import ProcessSettings

try:  # as in a slice (slicer.pipeline.slice_model); a checkout before it has no switch
    from slicer.hugepages import small_pages
except ImportError:
    small_pages = contextlib.nullcontext

STAGES = ("lean", "lean_price", "lean_solve", "sections", "skeleton", "layers", "zones",
          "toolpaths", "obstacles", "paths")


def plan_once(dec: Decomposition, lean: bool = False) -> PrintPlan:
    """One plan from cold caches (the skeleton and solid caches are cleared first), the
    root leaning (the closed loop's first leaning try) when ``lean``."""
    planner.clear_caches()
    with small_pages():
        return planner.plan_print(dec, ProcessSettings(), MachineGeometry(),
                                  Printhead.default(), lean=LEAN if lean else None)


def decomposition(name: str, mesh: trimesh.Trimesh, cache: Path | None) -> Decomposition:
    """The model's decomposition, from ``cache/NAME.pkl`` when there (saved there if not)."""
    file = None if cache is None else cache / f"{name}.pkl"
    if file is not None and file.exists():
        with file.open("rb") as f:
            return pickle.load(f)
    dec = decompose(mesh, DecomposeSettings(), MachineGeometry(), Printhead.default())
    if file is not None:
        file.parent.mkdir(parents=True, exist_ok=True)
        with file.open("wb") as f:
            pickle.dump(dec, f)
    return dec


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="runs per model (best reported)")
    parser.add_argument("--decompositions", type=Path, metavar="DIR",
                        help="reuse the decomposition pickled in DIR/MODEL.pkl (written there "
                        "the first time), so two versions of the planner (PYTHONPATH) are "
                        "timed on the same sub-parts")
    parser.add_argument("--hard", nargs="+", default=[], metavar="NAME",
                        help="models of shared/models/hard made 50 000 faces (instead of MODELS)")
    parser.add_argument("--lean", action="store_true", help="the root's layers leaning")
    parser.add_argument("models", nargs="*", help=f"any of {', '.join(MODELS)} (default: all)")
    args = parser.parse_args()
    names = [] if args.hard and not args.models else check_models(parser, args.models)
    makers = {**{n: MODELS[n] for n in names},
              **{n: partial(hard_model, n) for n in args.hard}}
    print(f"{'model':>10} {'faces':>7} {'parts':>5} {'layers':>6} {'paths':>6} "
          + " ".join(f"{k:>9}" for k in STAGES) + f" {'wall s':>7} {'cpu s':>6}")
    for name, make in makers.items():
        mesh = make()
        dec = decomposition(name, mesh, args.decompositions)
        plan, wall, cpu = best_of(lambda d=dec: plan_once(d, args.lean), args.repeat)
        layers = [la for sp in plan.subparts for la in sp.layers]
        paths = sum(len(la.paths) for la in layers)
        stages = " ".join(f"{plan.timings.get(k, 0.0):>9.3f}" for k in STAGES)
        print(f"{name:>10} {len(mesh.faces):>7} {len(plan.subparts):>5} {len(layers):>6} "
              f"{paths:>6} {stages} {wall:>7.2f} {cpu:>6.2f}", flush=True)


if __name__ == "__main__":
    main()
