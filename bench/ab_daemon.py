"""Two versions of the daemon compared on the streaming bench, run alternately.

Run: ``.venv/bin/python bench/ab_daemon.py --base CHECKOUT [--rounds 3]``, where CHECKOUT is
another version of this repository (e.g. made by ``git worktree add /tmp/base <commit>``).
Each round runs each checkout's own ``bench/daemon.py`` once, the base first in odd rounds
and second in even ones (a shared VM's speed drifts within minutes, so only alternation
compares two versions; ``floor_us_per_wakeup`` tells the slow spells). Printed per run: the
daemon's CPU share and CPU milliseconds per 1000 lines in both phases, the lines acknowledged
per read, the wire share and the floor; then the mean and median of each per version.
Without ``--base`` it says so and exits.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve()
FIGURES = {"watch_cpu_pct": "watch%", "stream_cpu_pct": "stream%",
           "watch_cpu_ms_per_1000_lines": "watch_ms", "stream_cpu_ms_per_1000_lines": "stream_ms",
           "acked_lines_per_read": "per_read", "wire_share_pct": "wire%",
           "floor_us_per_wakeup": "floor_us"}


def run(checkout: Path) -> dict[str, float]:
    """One run of ``checkout``'s ``bench/daemon.py``: its figures by name."""
    done = subprocess.run([sys.executable, str(checkout / "bench" / "daemon.py")],
                          capture_output=True, text=True, cwd=checkout, check=False)
    figures: dict[str, float] = {}
    for line in done.stdout.splitlines():
        parts = line.split()
        if len(parts) >= 2 and parts[0] in FIGURES:
            figures[parts[0]] = float(parts[1])
    missing = FIGURES.keys() - figures.keys()
    if missing:
        raise SystemExit(f"{checkout}: bench/daemon.py gave no {', '.join(sorted(missing))}\n"
                         + done.stdout + done.stderr)
    return figures


def line(tag: str, fig: dict[str, float]) -> str:
    return f"{tag:>7} " + " ".join(f"{short} {fig[key]:7.2f}" for key, short in FIGURES.items())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", type=Path, help="the other checkout")
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    if args.base is None:
        print("nothing to compare: give --base CHECKOUT (another version of this repository)")
        return
    if not (args.base / "bench" / "daemon.py").is_file():
        sys.exit(f"--base {args.base}: not a checkout of this repository (no bench/daemon.py)")
    here = HERE.parents[1]
    runs: dict[str, list[dict[str, float]]] = {"base": [], "this": []}
    for k in range(args.rounds):
        order = [("base", args.base), ("this", here)]
        for tag, checkout in order if k % 2 == 0 else order[::-1]:
            runs[tag].append(run(checkout))
            print(line(tag, runs[tag][-1]), flush=True)
    for stat in (statistics.mean, statistics.median):
        for tag, figs in runs.items():
            print(line(f"{stat.__name__[:4]} {tag}",
                       {key: stat(f[key] for f in figs) for key in FIGURES}))


if __name__ == "__main__":
    main()
