"""The replay's per-layer air check on parts without overhang, across the process settings.

Run: ``.venv/bin/python bench/bridging.py [--models cylinder pipe2 pipe3 | FILE.stl ...]
[--widths 0.45 0.65] [--densities 0.2] [--heights 0.2] [--planar]``.
The parts with a real overhang, which must stay refused (planar: no decomposition takes it
off): ``--planar --models gamma mushroom disc-on-post`` (QA's Γ bracket and mushroom,
``tests/slicer/test_overhang.py``; the disc on a post of ``test_replay_thin_layers.py``).

Each model is sliced at every combination of line width, infill density and layer height
without the check, then replayed; printed per slice: whether the file passes, the layer
nearest the refusal (its unsupported share of the extrusion and longest unsupported run,
``OVERHANG_SHARE`` / ``OVERHANG_RUN``), the layers in the air, the share of the judged
samples counted as bridging, the seconds of the replay's bridging stage and of the slice.
A part without overhang must pass everywhere (``docs/gcode-format.md``, layers in the air).
"""

from __future__ import annotations

import argparse
import itertools
import time
from pathlib import Path

import manifold3d as m3
import trimesh
from harness import MODELS

from kinematics.machine import MachineGeometry
from slicer.gcode import parse_lines
from slicer.mesh import place_on_platform, repair, to_trimesh
from slicer.pipeline import slice_model
from slicer.printhead import Printhead
from slicer.replay import replay_check
from slicer.settings import ProcessSettings


def _box(lo: tuple[float, float, float], size: tuple[float, float, float]) -> m3.Manifold:
    return m3.Manifold.cube(list(size)).translate(list(lo))


FAULTS = {
    "gamma": lambda: _box((0, 0, 0), (10, 10, 40)) + _box((0, 0, 32), (30, 10, 8)),
    "mushroom": lambda: (m3.Manifold.cylinder(20, 4, 4, 48)
                         + m3.Manifold.cylinder(5, 15, 15, 48).translate([0, 0, 20])),
    "disc-on-post": lambda: (m3.Manifold.cylinder(2.0, 3.0, 3.0, 48)
                             + m3.Manifold.cylinder(1.0, 6.0, 6.0, 48).translate((0, 0, 2.0))),
}


def load(name: str) -> trimesh.Trimesh:
    """A model of ``bench/harness.py`` or of ``FAULTS`` by name, or an STL file."""
    if name in MODELS:
        return MODELS[name]()
    if name in FAULTS:
        return to_trimesh(FAULTS[name]())
    path = Path(name)
    if not path.is_file():
        raise SystemExit(f"bridging.py: {name}: neither a model "
                         f"({', '.join([*MODELS, *FAULTS])}) nor a file")
    mesh = trimesh.load(path, force="mesh")
    assert isinstance(mesh, trimesh.Trimesh)
    return mesh


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="*", default=["cylinder"])
    parser.add_argument("--widths", nargs="*", type=float, default=[0.45, 0.65])
    parser.add_argument("--densities", nargs="*", type=float, default=[0.2])
    parser.add_argument("--heights", nargs="*", type=float, default=[0.2])
    parser.add_argument("--planar", action="store_true", help="the planar control instead")
    args = parser.parse_args()
    for name in args.models:
        mesh = load(name)
        placed, _ = place_on_platform(repair(mesh))
        for w, d, h in itertools.product(args.widths, args.densities, args.heights):
            t0 = time.perf_counter()
            res = slice_model(mesh, ProcessSettings(line_width=w, infill_density=d,
                                                    layer_height=h),
                              MachineGeometry(), Printhead.default(), planar=args.planar,
                              check=False)
            rep = replay_check(parse_lines(res.lines), placed, Printhead.default(), 150.0,
                               placed=True)
            worst = rep.worst_layer or {}
            air = ", ".join(f"{a['subpart']}:{a['layer']}" for a in rep.overhang_layers)
            print(f"{Path(name).stem} w {w:g} density {d:g} t {h:g}: "
                  f"{'ok' if rep.ok else 'REFUSED'}; worst layer "
                  f"{worst.get('subpart')}:{worst.get('layer')} (z {worst.get('z', 0):.2f}) "
                  f"{100 * worst.get('share', 0):.1f}% of {worst.get('extruded_mm', 0):.0f} mm "
                  f"unsupported, run {worst.get('run_mm', 0):.1f} mm; in the air: "
                  f"{air or '-'}; supported {100 * rep.supported:.2f}% (bridging "
                  f"{100 * rep.bridged:.2f}%); bridging stage "
                  f"{rep.timings.get('bridging', 0):.2f} s, slice + replay "
                  f"{time.perf_counter() - t0:.1f} s", flush=True)


if __name__ == "__main__":
    main()
