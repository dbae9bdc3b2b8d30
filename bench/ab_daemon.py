"""Two versions of the daemon compared on the streaming bench, run alternately.

Run: ``.venv/bin/python bench/ab_daemon.py --base CHECKOUT [--rounds 3]``, where CHECKOUT is
another version of this repository (e.g. made by ``git worktree add /tmp/base <commit>``).
Each round runs each checkout's own ``bench/daemon.py`` once, the base first in odd rounds
and second in even ones (a shared VM's speed drifts within minutes, so only alternation
compares two versions; ``floor_us_per_wakeup`` tells the slow spells). Printed per run: the
daemon's CPU share and CPU milliseconds per 1000 lines in both phases, the lines acknowledged
per read, the wire share in both phases and the floor; then the mean and median of each per version.
Without ``--base`` it says so and exits. Arguments after ``--`` go to both benches (e.g.
``-- --advanced-ok``); both checkouts' benches must know them.

``--together`` runs the two benches at the same time instead (each with its own emulator,
the four processes on this machine's cores), so both meet the same spell of the VM; printed
per round and summed up: the ratio this/base of the CPU per 1000 lines in each phase.
"""

from __future__ import annotations

import argparse
import signal
import statistics
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve()
FIGURES = {"watch_cpu_pct": "watch%", "stream_cpu_pct": "stream%",
           "watch_cpu_ms_per_1000_lines": "watch_ms", "stream_cpu_ms_per_1000_lines": "stream_ms",
           "acked_lines_per_read": "per_read", "watch_wire_share_pct": "wwire%",
           "wire_share_pct": "wire%",
           "floor_us_per_wakeup": "floor_us"}
OPTIONAL = {"upload_s": "upload_s"}  # printed when both benches give it (``--upload``)


def start(checkout: Path, extra: list[str]) -> subprocess.Popen[str]:
    """``checkout``'s own ``bench/daemon.py``, started with the arguments ``extra``."""
    return subprocess.Popen([sys.executable, str(checkout / "bench" / "daemon.py"), *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=checkout)


def figures_of(checkout: Path, proc: subprocess.Popen[str]) -> dict[str, float]:
    """The figures by name of a started bench, once it has finished."""
    stdout, stderr = proc.communicate()
    figures: dict[str, float] = {}
    for line in stdout.splitlines():
        parts = line.split()
        if len(parts) >= 2 and (parts[0] in FIGURES or parts[0] in OPTIONAL):
            figures[parts[0]] = float(parts[1])
    missing = FIGURES.keys() - figures.keys()
    if missing:
        raise SystemExit(f"{checkout}: bench/daemon.py gave no {', '.join(sorted(missing))}\n"
                         + stdout + stderr)
    return figures


def stop(proc: subprocess.Popen[str]) -> None:
    """Stop a bench still running: Ctrl-C, so that it stops its daemon and emulator."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()


def run(checkout: Path, extra: list[str]) -> dict[str, float]:
    """One run of ``checkout``'s ``bench/daemon.py``: its figures by name."""
    return figures_of(checkout, start(checkout, extra))


RATIOS = ("watch_cpu_ms_per_1000_lines", "stream_cpu_ms_per_1000_lines")


def together(base: Path, here: Path, rounds: int, extra: list[str]) -> None:
    """Both benches at once, ``rounds`` times: the ratios this/base of the CPU per line."""
    ratios: dict[str, list[float]] = {key: [] for key in RATIOS}
    for _ in range(rounds):
        procs = {"base": start(base, extra), "this": start(here, extra)}
        try:
            figs = {"base": figures_of(base, procs["base"]),
                    "this": figures_of(here, procs["this"])}
        finally:  # a bench that failed must not leave the other one running
            for proc in procs.values():
                stop(proc)
        for tag in ("base", "this"):
            print(line(tag, figs[tag]))
        for key in RATIOS:
            ratios[key].append(figs["this"][key] / figs["base"][key])
        print("  ratio " + " ".join(f"{FIGURES[k]} {ratios[k][-1]:.3f}" for k in RATIOS),
              flush=True)
    for key, values in ratios.items():
        print(f"{FIGURES[key]:>9} this/base: geometric mean {statistics.geometric_mean(values):.3f}"
              f", median {statistics.median(values):.3f}, range {min(values):.3f}–"
              f"{max(values):.3f} ({len(values)} rounds)")


def line(tag: str, fig: dict[str, float]) -> str:
    shown = {**FIGURES, **{k: v for k, v in OPTIONAL.items() if k in fig}}
    return f"{tag:>7} " + " ".join(f"{short} {fig[key]:7.2f}" for key, short in shown.items())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", type=Path, help="the other checkout")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--together", action="store_true",
                        help="run the two benches at the same time (paired ratios)")
    parser.add_argument("bench_args", nargs="*", metavar="-- BENCH_ARG",
                        help="arguments for both benches, after --")
    args = parser.parse_args()
    if args.base is None:
        print("nothing to compare: give --base CHECKOUT (another version of this repository)")
        return
    if not (args.base / "bench" / "daemon.py").is_file():
        sys.exit(f"--base {args.base}: not a checkout of this repository (no bench/daemon.py)")
    here = HERE.parents[1]
    if args.together:
        together(args.base, here, args.rounds, args.bench_args)
        return
    runs: dict[str, list[dict[str, float]]] = {"base": [], "this": []}
    for k in range(args.rounds):
        order = [("base", args.base), ("this", here)]
        for tag, checkout in order if k % 2 == 0 else order[::-1]:
            runs[tag].append(run(checkout, args.bench_args))
            print(line(tag, runs[tag][-1]), flush=True)
    for stat in (statistics.mean, statistics.median):
        for tag, figs in runs.items():
            print(line(f"{stat.__name__[:4]} {tag}",
                       {key: stat(f[key] for f in figs) for key in {**FIGURES, **OPTIONAL}
                        if all(key in f for f in figs)}))


if __name__ == "__main__":
    main()
