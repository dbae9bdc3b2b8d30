"""Wall and CPU seconds of a fresh ``hostctl slice`` process, as an operator runs it.

Run: ``.venv/bin/python bench/cli_slice.py [--model pipe3-50k] [--height 0.2] [--repeat 3]
[--base CHECKOUT] [--allow-overhang]``. The model (a bench model, or ``h:NAME`` for
``shared/models/hard/NAME.stl`` made 50 000 faces, as ``bench/cura_compare.py`` makes it) is
written to an STL file in a temporary directory, then sliced ``--repeat`` times by ``hostctl
slice MODEL.stl -o OUT.gcode --layer-height H`` (the default config), each in a process of
its own. Printed per run: the process's wall seconds (start to exit: interpreter, imports,
config, slice, file written), its CPU seconds (user + system, worker processes included),
the ``seconds`` the command itself reports (from before the slicer's imports) and an MD5 of
the file's commands (comment lines left out: the same MD5, the same moves). With ``--base``
(another version of this repository, e.g. ``git worktree add /tmp/base <commit>``) each
round runs that version's slicer (first on ``PYTHONPATH``) and then this one: on a shared VM
only alternation compares two versions. :mod:`slice` times ``slice_model`` alone, in a
process that has imported it.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from harness import MODELS, check_models, model_mesh

SECONDS = re.compile(r"^seconds ([0-9.]+)", re.MULTILINE)
HERE = Path(__file__).resolve().parents[1]


def hostctl() -> list[str]:
    """The ``hostctl`` beside this interpreter, or the module it runs."""
    script = Path(sys.executable).with_name("hostctl")
    return [str(script)] if script.exists() else [sys.executable, "-m", "hostd.cli.main"]


def children_cpu() -> float:
    """CPU seconds of the waited-for child processes so far."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def one_run(stl: Path, out: Path, height: float, checkout: Path, allow: bool
            ) -> tuple[float, float, float, str]:
    """(wall s, CPU s, the command's own seconds, MD5 of the commands) of one ``hostctl
    slice`` with ``checkout``'s slicer."""
    cmd = [*hostctl(), "slice", str(stl), "-o", str(out), "--layer-height", str(height),
           *(["--allow-overhang"] if allow else [])]
    env = {**os.environ, "PYTHONPATH": str(checkout)}
    cpu, wall = children_cpu(), time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, check=False, env=env)
    wall, cpu = time.perf_counter() - wall, children_cpu() - cpu
    if done.returncode != 0:
        sys.exit(f"hostctl slice failed ({done.returncode}): {done.stderr.strip()}")
    found = SECONDS.search(done.stdout)
    return wall, cpu, float(found.group(1)) if found else float("nan"), _moves_md5(out)


def _moves_md5(gcode: Path) -> str:
    digest = hashlib.md5()
    with gcode.open("rb") as fh:
        for line in fh:
            if not line.startswith(b";"):
                digest.update(line)
    return digest.hexdigest()[:10]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="pipe3-50k",
                        help=f"any of {', '.join(MODELS)}, or h:NAME (shared/models/hard)")
    parser.add_argument("--height", type=float, default=0.2)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--base", type=Path, help="another checkout, run alternately")
    parser.add_argument("--allow-overhang", action="store_true",
                        help="pass --allow-overhang (write a file with walls over air)")
    args = parser.parse_args()
    check_models(parser, [args.model], hard=True)
    if args.base is not None and not (args.base / "slicer" / "pipeline.py").is_file():
        parser.error(f"--base {args.base}: not a checkout of this repository")
    versions = {"this": HERE} if args.base is None else {"base": args.base.resolve(),
                                                         "this": HERE}
    runs: dict[str, list[tuple[float, float, float, str]]] = {v: [] for v in versions}
    name = args.model.removeprefix("h:")
    print(f"hostctl slice {name}.stl --layer-height {args.height:g}", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        stl = Path(tmp) / f"{name}.stl"
        model_mesh(args.model).export(stl)
        for i in range(1, max(1, args.repeat) + 1):
            for tag, checkout in versions.items():
                got = one_run(stl, Path(tmp) / "out.gcode", args.height, checkout,
                              args.allow_overhang)
                runs[tag].append(got)
                print(f"  {tag} run {i}: {got[0]:6.2f} s wall  {got[1]:6.2f} s CPU  "
                      f"(reported {got[2]:.2f} s)  md5 {got[3]}", flush=True)
    for tag, got in runs.items():
        walls = [r[0] for r in got]
        print(f"  {tag}: best {min(walls):.2f} s, median {statistics.median(walls):.2f} s "
              f"wall, mean CPU {statistics.mean(r[1] for r in got):.2f} s")


if __name__ == "__main__":
    main()
