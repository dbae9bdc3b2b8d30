"""Robustness sweep: seeded branched-pipe variants × decomposition seeds, tallied.

Run: ``.venv/bin/python bench/decompose_sweep.py [--variants 40] [--seeds 3] [--jobs 2]``.

Every case must either give a valid decomposition (watertight sub-parts, volumes summing to the
part's within 0.5 %, constraints I and II by the independent brute-force check of
``tests/slicer/decompose_checks.py``) or be refused with a one-line ``DecompositionError``
naming the boundary and the constraint. Anything else (another error, an internal exception, an
invalid result) is listed as BAD; the exit status is 1 when there is any.
"""

from __future__ import annotations

import argparse
import sys
import time
import traceback
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "slicer"))

from decompose_checks import check_decomposition, is_clean_failure

from kinematics.machine import MachineGeometry
from slicer.decompose import DecomposeSettings, DecompositionError, decompose
from slicer.mesh import samples
from slicer.printhead import Printhead


def run_case(case: tuple[int, int]) -> tuple[int, int, str, str, float]:
    """(variant, seed, outcome, detail, seconds); outcome is ok, refused or BAD."""
    variant, seed = case
    head, machine = Printhead.default(), MachineGeometry()
    mesh = samples.branched_pipe(**samples.pipe_variant(variant))
    t0 = time.perf_counter()
    try:
        dec = decompose(mesh, DecomposeSettings(seed=seed), machine, head)
    except DecompositionError as exc:
        outcome = "refused" if is_clean_failure(str(exc)) else "BAD"
        return variant, seed, outcome, str(exc), time.perf_counter() - t0
    except Exception as exc:  # the sweep reports every internal error
        detail = f"{type(exc).__name__}: {exc} @ {traceback.format_exc(limit=-1).strip()}"
        return variant, seed, "BAD", detail, time.perf_counter() - t0
    seconds = time.perf_counter() - t0
    try:
        check_decomposition(mesh, dec, head, machine.a_limits)
    except AssertionError as exc:
        return variant, seed, "BAD", f"invalid result: {exc}", seconds
    return variant, seed, "ok", f"{len(dec.subparts)} sub-parts", seconds


def main() -> int:
    """Run the sweep and print one line per case and the tally."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variants", type=int, default=40)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()
    cases = [(v, s) for v in range(args.variants) for s in range(args.seeds)]
    tally: dict[str, int] = {}
    with ProcessPoolExecutor(args.jobs) as pool:
        for v, s, outcome, detail, sec in pool.map(run_case, cases):
            tally[outcome] = tally.get(outcome, 0) + 1
            print(f"variant {v:3d} seed {s}: {outcome:7s} {sec:5.1f} s  {detail}  "
                  f"{samples.pipe_variant(v)}", flush=True)
    print("tally: " + ", ".join(f"{k} {n}" for k, n in sorted(tally.items())))
    return 1 if tally.get("BAD") else 0


if __name__ == "__main__":
    raise SystemExit(main())
