"""Support-free on parts a planar print cannot make: the hard models and a seeded sweep.

    .venv/bin/python bench/hard_sweep.py                   # the files of shared/models/hard
    .venv/bin/python bench/hard_sweep.py --variants 24     # slicer.mesh.hard_samples 0..23
    .venv/bin/python bench/hard_sweep.py --variants 24 --heights 0.2 --jobs 2
    .venv/bin/python bench/hard_sweep.py --variants 24 --kinds pipe elbow   # those of 0..23

Every part is sliced as ``hostctl slice`` slices it (``slicer.pipeline.slice_model`` of an STL
file, a variant written to one first, the shipped defaults, the retry loop included) at each
layer height, and judged by the product's
own replay: it **passes** when it is written with walls supported >= 99.8 %, no wall layer
with more than 5 % of its wall points unsupported (issue 8's rule: a wall point bridging
sparse infill inside the part is held),
no head collision and >= 99 % of the material inside the model. One line per slice
(sub-parts, walls, unsupported wall layers and those of them over air, collisions, inside,
the share of the model's shell the beads reach, the layers thinned, seconds, retry rounds,
other decomposition seeds tried and the seed kept, the first three unsupported wall
layers), then the pass share per class and height. Outcomes other than a
pass: ``walls`` (the file ``hostctl slice`` refuses, or writes with --allow-overhang, which
the bench sets to measure it; a file with unsupported wall layers that all bridge sparse
infill is written), ``refused`` (refused before a file: the decomposition or the planner,
with its reason), ``error`` (anything else: a bug).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import sys
import tempfile
import time
from collections import defaultdict
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

HARD = ROOT.parent / "shared" / "models" / "hard"
WALLS, INSIDE = 0.998, 0.99


def slice_one(task: tuple[str, str, float, str]) -> dict[str, object]:
    """Slice one part (a file, or ``variant:<index>``) at one layer height; its figures. With
    a log folder (the task's last item, "" for none), the closed loop's log lines go to
    ``<folder>/<name>-<height>.log``."""
    from slicer.mesh.hard_samples import hard_variant

    kind, source, t, logs = task
    name = Path(source).stem
    with tempfile.TemporaryDirectory() as tmp:
        part = source
        if source.startswith("variant:"):  # written as the STL a user would send
            variant = hard_variant(int(source.split(":")[1]))
            name, part = variant.name, str(Path(tmp) / f"{variant.name}.stl")
            variant.mesh().export(part)
        if not logs:
            return _sliced(kind, name, part, t)
        with _loop_log(Path(logs) / f"{name}-{t:g}.log"):
            return _sliced(kind, name, part, t)


@contextlib.contextmanager
def _loop_log(path: Path) -> Iterator[None]:
    """The closed loop's INFO lines (``slicer.repair``) written to ``path``, each with the
    seconds since the slice began."""
    path.parent.mkdir(parents=True, exist_ok=True)
    handler = logging.FileHandler(path, mode="w")
    start = time.perf_counter()

    class _Since(logging.Formatter):
        def format(self, record: logging.LogRecord) -> str:
            return f"{time.perf_counter() - start:8.1f} {record.name} {record.getMessage()}"

    handler.setFormatter(_Since())
    loop = logging.getLogger("slicer.repair")
    level = loop.level
    loop.addHandler(handler)
    loop.setLevel(logging.INFO)
    try:
        yield
    finally:
        loop.removeHandler(handler)
        loop.setLevel(level)
        handler.close()


def _sliced(kind: str, name: str, part: str, t: float) -> dict[str, object]:
    """``slice_model`` of the STL ``part`` at ``t`` mm, judged."""
    from kinematics.machine import MachineGeometry
    from slicer.decompose import DecompositionError
    from slicer.mesh import MeshError
    from slicer.paths import SlicingError
    from slicer.pipeline import SliceError, slice_model
    from slicer.settings import ProcessSettings

    t0 = time.perf_counter()
    out: dict[str, object] = {"kind": kind, "name": name, "t": t}
    try:
        res = slice_model(part, ProcessSettings(layer_height=t), MachineGeometry(),
                          allow_overhang=True)
    except (SliceError, SlicingError, DecompositionError, MeshError) as exc:
        out.update(outcome="refused", reason=str(exc)[:160])
    except Exception as exc:  # the bench reports every failure as data
        out.update(outcome="error", reason=f"{type(exc).__name__}: {exc}"[:160])
    else:
        rep = res.replay
        bad = rep["unsupported_wall_layers"]
        walls, inside = float(rep["wall_supported"]), float(rep["inside"])
        ok = walls >= WALLS and not bad and rep["collisions"] == 0 and inside >= INSIDE
        out.update(outcome="pass" if ok else "walls", subparts=res.subparts, walls=walls,
                   bad=len(bad), air=int(rep.get("wall_layers_over_air", 0)),
                   collisions=rep["collisions"], inside=inside,
                   shell=float(rep["shell_coverage"]), thinned=res.thinned[0],
                   rounds=int(res.timings.get("repair_rounds", 0)),
                   others=int(res.timings.get("alternatives_tried", 0)), seed=res.seed,
                   where=", ".join(str(w) for w in bad[:3]))
    out["seconds"] = time.perf_counter() - t0
    return out


def line(r: dict[str, object]) -> str:
    """One slice's figures."""
    head = f"{r['name']:<28} {r['t']:<4g} mm  {r['outcome']:<7}"
    if r["outcome"] in ("pass", "walls"):
        return (f"{head} sub-parts {r['subparts']:>2}  walls {100 * r['walls']:6.2f} %  "
                f"bad layers {r['bad']:>3} (over air {r['air']:>3})  collisions "
                f"{r['collisions']}  inside "
                f"{100 * r['inside']:6.2f} %  shell {100 * r['shell']:6.2f} %  thinned "
                f"{r['thinned']:>3}  retries {r['rounds']}  other seeds "
                f"{r['others']} (kept {r['seed']})  {r['seconds']:6.1f} s"
                + (f"  [{r['where']}]" if r["where"] else ""))
    return f"{head} {r['seconds']:6.1f} s  {r['reason']}"


def tasks(args: argparse.Namespace) -> list[tuple[str, str, float, str]]:
    """(class, source, layer height, log folder or "") of every slice asked for."""
    from slicer.mesh.hard_samples import hard_variant

    if args.variants:
        parts = [(hard_variant(i).kind, f"variant:{i}")
                 for i in range(args.start, args.start + args.variants)
                 if not args.kinds or hard_variant(i).kind in args.kinds]
    else:
        parts = [("hard", str(p)) for p in sorted(HARD.glob("*.stl"))]
    return [(k, s, t, args.log) for k, s in parts for t in args.heights]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variants", type=int, default=0, help="sweep this many variants")
    ap.add_argument("--start", type=int, default=0, help="first variant index")
    ap.add_argument("--kinds", nargs="+", default=[],
                    help="only variants of these classes (pipe, elbow, tree, ball)")
    ap.add_argument("--heights", type=float, nargs="+", default=[0.2, 0.3])
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--log", default="", metavar="DIR",
                    help="write each slice's closed-loop log (rounds, decompositions, "
                         "seconds) to DIR/<name>-<height>.log")
    args = ap.parse_args()
    todo = tasks(args)
    results = []
    t0 = time.perf_counter()
    with ProcessPoolExecutor(args.jobs) as pool:
        for r in pool.map(slice_one, todo):
            print(line(r), flush=True)
            results.append(r)
    share: dict[tuple[str, float], list[bool]] = defaultdict(list)
    for r in results:
        share[(str(r["kind"]), float(r["t"]))].append(r["outcome"] == "pass")  # type: ignore[arg-type]
    print(f"\npass share ({time.perf_counter() - t0:.0f} s, {args.jobs} jobs):")
    for (kind, t), oks in sorted(share.items()):
        print(f"  {kind:<6} {t:<4g} mm  {sum(oks):>3} / {len(oks):<3} "
              f"{100 * sum(oks) / len(oks):5.1f} %")
    everything = [r["outcome"] == "pass" for r in results]
    print(f"  all          {sum(everything):>3} / {len(everything):<3} "
          f"{100 * sum(everything) / max(len(everything), 1):5.1f} %")


if __name__ == "__main__":
    main()
