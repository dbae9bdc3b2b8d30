"""Rebuilding the modal state of a long file, as a resume does: line by line against by runs.

Run: ``.venv/bin/python bench/modal.py [--lines 1000000] [--repeat 3]``. The file is
five-axis moves with relative E and, now and then, a fan, temperature or travel command.
Printed: the best seconds of :meth:`ModalState.apply` on every line and of
:meth:`ModalState.apply_many` on the whole file, per million lines, and whether the two
states are the same (they must be, bit for bit).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hostd.printer.modal import ModalState


def sample_file(lines: int) -> list[str]:
    """``lines`` commands: a start script, then moves with an odd command among them."""
    out = ["G28", "M104 S210", "G90", "M83"]
    for i in range(lines - len(out)):
        if i % 4000 == 0:
            out.append(f"G0 Z{i * 1e-4:.3f} F3000")
        elif i % 9000 == 1:
            out.append("M106 S255")
        else:
            out.append(f"G1 X{10 + (i % 997) * 0.037:.3f} Y{20 - (i % 991) * 0.011:.3f} "
                       f"A{(i % 90) * 0.5:.3f} C{(i % 360) * 1.0:.3f} E{0.01 + (i % 7) * 1e-3:.5f}")
    return out


def best(run: Callable[[], ModalState], repeat: int) -> tuple[ModalState, float]:
    """The state ``run`` leaves and its best time of ``repeat``."""
    times, state = [], ModalState()
    for _ in range(max(1, repeat)):
        t0 = time.perf_counter()
        state = run()
        times.append(time.perf_counter() - t0)
    return state, min(times)


def one_by_one(commands: list[str]) -> ModalState:
    state = ModalState()
    for command in commands:
        state.apply(command)
    return state


def by_runs(commands: list[str]) -> ModalState:
    state = ModalState()
    state.apply_many(commands)
    return state


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lines", type=int, default=1_000_000)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    commands = sample_file(args.lines)
    per_million = 1e6 / len(commands)
    a, t_lines = best(lambda: one_by_one(commands), args.repeat)
    b, t_runs = best(lambda: by_runs(commands), args.repeat)
    print(f"modal bench: {len(commands)} commands, best of {args.repeat}")
    print(f"{'line_by_line_s_per_million':32s} {t_lines * per_million:8.2f}")
    print(f"{'by_runs_s_per_million':32s} {t_runs * per_million:8.2f}")
    print(f"{'same_state':32s} {repr(a.snapshot()) == repr(b.snapshot())}")


if __name__ == "__main__":
    main()
