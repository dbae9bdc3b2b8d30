"""Seconds per replay-check stage on already sliced programs (no re-planning between runs).

Run: ``.venv/bin/python bench/replay.py [--models pipe3-50k ...] [--repeat 3] [--planar]``.
Each model is sliced once at ``--height`` without the check and its G-code text cached under
``--cache`` (``out/bench-replay`` by default, rebuilt with ``--fresh``); the replay check is
then run ``--repeat`` times on the parsed text against the placed mesh. Printed: the best
total wall and process CPU seconds, per stage the best wall and CPU seconds over the runs
(with ``--threads 1`` the stages run one after another and a stage's CPU counts every core
it used; with two threads stages overlap and the CPU is the stage's own thread's), then the
figures of the last run, so a change that moves them shows at once.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import trimesh
from harness import MODELS, check_models

from kinematics.machine import MachineGeometry
from slicer.gcode import ParsedGcode, parse_lines
from slicer.hugepages import small_pages
from slicer.mesh import place_on_platform, repair
from slicer.pipeline import slice_model
from slicer.printhead import Printhead
from slicer.replay import ReplayReport, replay_check
from slicer.settings import ProcessSettings

FIGURES = ("points", "inside", "coverage", "shell_coverage", "supported", "bridged",
           "wall_points", "wall_supported", "collisions")


def sliced(name: str, height: float, planar: bool, cache: Path, fresh: bool
           ) -> tuple[ParsedGcode, trimesh.Trimesh]:
    """The parsed G-code of ``name`` (cached text) and the mesh placed on the platform."""
    mesh = MODELS[name]()
    path = cache / f"{name}-{height:.2f}-{'planar' if planar else '5axis'}.gcode"
    if fresh or not path.exists():
        res = slice_model(mesh, ProcessSettings(layer_height=height), MachineGeometry(),
                          Printhead.default(), planar=planar, check=False)
        cache.mkdir(parents=True, exist_ok=True)
        path.write_text("\n".join(res.lines) + "\n")
    placed, _ = place_on_platform(repair(mesh))
    return parse_lines(path.read_text().splitlines()), placed


def best_stages(parsed: ParsedGcode, mesh: trimesh.Trimesh, repeat: int, threads: int
                ) -> tuple[ReplayReport, dict[str, float], dict[str, float], float, float]:
    """(last report, best wall s per stage, best CPU s per stage, best total wall, CPU)."""
    wall: dict[str, float] = {}
    cpu: dict[str, float] = {}
    total_wall = total_cpu = float("inf")
    rep = None
    for _ in range(max(1, repeat)):
        w0, c0 = time.perf_counter(), time.process_time()
        rep = replay_check(parsed, mesh, Printhead.default(), 150.0, placed=True,
                           threads=threads)
        total_wall = min(total_wall, time.perf_counter() - w0)
        total_cpu = min(total_cpu, time.process_time() - c0)
        for k, v in rep.timings.items():
            wall[k] = min(wall.get(k, float("inf")), v)
        for k, v in rep.cpu_timings.items():
            cpu[k] = min(cpu.get(k, float("inf")), v)
    assert rep is not None
    return rep, wall, cpu, total_wall, total_cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="*", default=["pipe3-50k"],
                        help=f"any of {', '.join(MODELS)}")
    parser.add_argument("--height", type=float, default=0.2)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--planar", action="store_true", help="also the planar control")
    parser.add_argument("--threads", type=int, default=2,
                        help="1: stages one after another, CPU per stage of the process")
    parser.add_argument("--cache", type=Path, default=Path("out/bench-replay"))
    parser.add_argument("--fresh", action="store_true", help="re-slice, ignoring the cache")
    args = parser.parse_args()
    check_models(parser, args.models)
    for name in args.models:
        for planar in (False, True) if args.planar else (False,):
            parsed, mesh = sliced(name, args.height, planar, args.cache, args.fresh)
            with small_pages():  # as in a slice (slicer.pipeline.slice_model)
                rep, wall, cpu, tw, tc = best_stages(parsed, mesh, args.repeat, args.threads)
            kind = "planar" if planar else "5-axis"
            print(f"{name} {args.height:.2f} {kind}: {rep.points} samples, {args.threads} "
                  f"thread(s), best of {args.repeat}: {tw:.2f} s wall, {tc:.2f} s CPU")
            for k in wall:
                print(f"  {k:>10} {wall[k]:6.2f} s wall {cpu[k]:6.2f} s CPU")
            d = rep.to_dict()
            print("  " + ", ".join(f"{k} {d[k]:.5g}" if isinstance(d[k], float) else
                                   f"{k} {d[k]}" for k in FIGURES))
            print(f"  unsupported wall layers: {rep.unsupported_wall_layers}")
            print(f"  collisions: {rep.collision_messages}", flush=True)


if __name__ == "__main__":
    main()
