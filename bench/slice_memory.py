"""Peak RSS of ``hostctl slice`` on generated parts, each in a child process of its own.

Run: ``.venv/bin/python bench/slice_memory.py [--parts box60 tower pipe2 cross ...]
[--cap-gb 4] [--base DIR] [--figures] [--allow-overhang]``. Each part is written as an STL
into a temporary folder and sliced (replay check included, default config) by ``hostctl
slice`` run in a child process, under an address-space limit of ``--cap-gb`` (a part that
needs more fails with a ``MemoryError`` instead of taking the machine). Printed per part:
its volume, the child's peak resident set (``ru_maxrss`` from ``os.wait4``: the slicing
process itself, not its forked layer workers), wall seconds, the replay's seconds, and the
outcome (``ok``, or the exit status and the last line printed: a refusal is one line), with
``--figures`` the replay's figures. ``--base DIR`` runs the slices with ``PYTHONPATH=DIR``
(another checkout, e.g. ``git worktree add /tmp/base HEAD``) to compare versions; run both
in turn, not at once: the machine's memory is shared.

``hard`` adds the models of ``shared/models/hard`` made 50k faces as
``bench/cura_compare.py`` slices them (issue 35's memory goal: under 1.5 GiB each), named
``h:<model>``; ``--parts hard`` runs only those. A refused model's peak is still measured: the
refusal comes after the plan and the check.

``cross`` is the 152 cm³ hollow cross fitting of 50 mm pipes
(:func:`slicer.mesh.samples.pipe_cross`, 7.5 M samples at 0.2 mm), whose replay the check
refused for its memory before it went by tiles and chunks; its five-axis slice has
unsupported wall layers over air, so ``--allow-overhang`` (which a checkout before it does
not know) has it written rather than refused after the check.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

import trimesh
from harness import HARD, hard_model

ROOT = Path(__file__).resolve().parent.parent


def _box(x: float, y: float, z: float) -> Callable[[], trimesh.Trimesh]:
    return lambda: trimesh.creation.box([x, y, z]).apply_translation([0.0, 0.0, z / 2])


def _pipe2_x2() -> trimesh.Trimesh:
    from slicer.mesh import samples

    return samples.pipe2().apply_scale(2.0)


def _pipe2() -> trimesh.Trimesh:
    from slicer.mesh import samples

    return samples.pipe2()


def _cross() -> trimesh.Trimesh:
    from slicer.mesh import samples

    return samples.pipe_cross()


def _hard(name: str) -> Callable[[], trimesh.Trimesh]:
    return lambda: hard_model(name, 50_000)


HARD_MODELS = sorted(p.stem for p in HARD.glob("*.stl"))
PARTS: dict[str, Callable[[], trimesh.Trimesh]] = {
    "box60": _box(60, 60, 10), "tower": _box(30, 30, 100), "box100": _box(100, 100, 10),
    "pipe2": _pipe2, "pipe2x2": _pipe2_x2, "box250": _box(250, 250, 20), "cross": _cross,
    **{f"h:{m}": _hard(m) for m in HARD_MODELS}}

# parts wider than the default platform (radius 150 mm) are sliced with a config of their own
CONFIGS = {"box250": "machine:\n  platform_radius: 200\n"}

CHILD = """
import sys, time
import slicer
from hostd.cli.main import main
print("SLICER " + slicer.__file__, flush=True)
t0 = time.perf_counter()
sys.argv = ["hostctl", "slice", sys.argv[1], "-o", sys.argv[2], *sys.argv[3:]]
try:
    code = main()
finally:
    print(f"WALL {time.perf_counter() - t0:.2f}", flush=True)
sys.exit(code)
"""


def run_part(stl: Path, cap: int, pythonpath: str, config: str | None = None,
             options: tuple[str, ...] = ()) -> dict[str, object]:
    """Slice ``stl`` (with the config text ``config``, else the default config, and the
    ``hostctl slice`` ``options``) in a child process limited to ``cap`` bytes of address
    space: the outcome, wall and replay seconds, replay figures and ``rss_mib``, the child's
    peak resident set."""
    extra = list(options)
    if config is not None:
        cfg = stl.with_suffix(".yaml")
        cfg.write_text(config)
        extra += ["--config", str(cfg)]

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (cap, cap))

    env = {**os.environ, "PYTHONPATH": pythonpath}
    # -P: the child's working folder must not shadow PYTHONPATH's packages
    proc = subprocess.Popen([sys.executable, "-P", "-c", CHILD, str(stl), str(stl.with_suffix(
        ".gcode")), *extra], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env,
        preexec_fn=limit, text=True, cwd=stl.parent)
    assert proc.stdout is not None
    out = proc.stdout.read().splitlines()
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    res: dict[str, object] = {"rss_mib": usage.ru_maxrss / 1024.0, "wall_s": float("nan"),
                              "replay_s": float("nan"), "outcome": "ok"}
    for line in out:
        if line.startswith("SLICER "):
            res["slicer"] = line.removeprefix("SLICER ")
        elif line.startswith("WALL "):
            res["wall_s"] = float(line.split()[1])
        elif line.startswith("seconds ") and "replay " in line:
            res["replay_s"] = float(line.split("replay ")[1].split(",")[0].split()[0])
        elif line.startswith("replay: "):
            res["figures"] = line.removeprefix("replay: ")
    if proc.returncode != 0:
        last = [ln for ln in out if ln.strip() and not ln.startswith("WALL ")]
        res["outcome"] = f"exit {proc.returncode}: {last[-1] if last else ''}"[:160]
    return res


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--parts", nargs="*", default=list(PARTS),
                        choices=[*PARTS, "hard"], help="parts by name; hard: the h:<model>s")
    parser.add_argument("--cap-gb", type=float, default=4.0,
                        help="address-space limit of each slice, GB (default 4)")
    parser.add_argument("--base", help="checkout to slice with instead of this one")
    parser.add_argument("--figures", action="store_true", help="print the replay's figures")
    parser.add_argument("--allow-overhang", action="store_true",
                        help="slice with --allow-overhang (not for a checkout before it)")
    args = parser.parse_args()
    pythonpath = str(Path(args.base).resolve() if args.base else ROOT)
    print(f"slicer from {pythonpath}")
    print(f"{'part':11s} {'volume cm3':>10s} {'peak RSS MiB':>12s} {'wall s':>7s} "
          f"{'replay s':>8s}  outcome")
    parts = [p for name in args.parts
             for p in ([f"h:{m}" for m in HARD_MODELS] if name == "hard" else [name])]
    with tempfile.TemporaryDirectory() as tmp:
        for name in parts:
            mesh = PARTS[name]()
            stl = Path(tmp) / f"{name.replace(':', '_')}.stl"
            mesh.export(stl)
            r = run_part(stl, int(args.cap_gb * 1e9), pythonpath, CONFIGS.get(name),
                         ("--allow-overhang",) if args.allow_overhang else ())
            print(f"{name:11s} {mesh.volume / 1000:10.1f} {r['rss_mib']:12.0f} "
                  f"{r['wall_s']:7.1f} {r['replay_s']:8.2f}  {r['outcome']}", flush=True)
            assert str(r.get("slicer", pythonpath)).startswith(pythonpath), r["slicer"]
            if args.figures and "figures" in r:
                print(f"{'':11s} replay: {r['figures']}")


if __name__ == "__main__":
    main()
