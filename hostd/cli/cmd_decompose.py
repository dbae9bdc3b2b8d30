"""``hostctl decompose MODEL.stl -o DIR``: offline model decomposition (no daemon)."""

from __future__ import annotations

import argparse
import json
import re
import time
from pathlib import Path
from typing import Any

import numpy as np

from hostd.cli.errors import EXIT_FAILED, CliError
from hostd.cli.options import add_decompose_options, bounded
from hostd.config import Config, ConfigError, load
from hostd.config.paths import INSTALLED_CONFIG, offline_config


def register(subparsers: Any) -> None:
    """Add the ``decompose`` verb."""
    p = subparsers.add_parser(
        "decompose", help="split an STL into support-free sub-parts (offline)",
        description="Decompose MODEL.stl into sub-parts printable along their own directions; "
                    "writes decomposition.json, part_<k>.stl and preview.png into DIR. A "
                    "refused decomposition (exit 1) still writes decomposition.json (the "
                    "refusal) and preview.png (the part, the point it names in red).")
    p.add_argument("model", help="ASCII or binary STL")
    p.add_argument("-o", "--output", required=True, help="output directory")
    add_decompose_options(p)
    p.add_argument("--root", type=int, default=None,
                   help="coarse region of the root (the numbers labelled in preview.png)")
    p.add_argument("--config", default=None, metavar="FILE",
                   help=f"config file (default: {INSTALLED_CONFIG} if it exists, else the "
                        "shipped defaults)")
    p.add_argument("--no-preview", action="store_true", help="skip preview.png")
    p.set_defaults(func=run)


def _settings(cfg: Config, args: argparse.Namespace) -> Any:
    from slicer.decompose import DecomposeSettings, SearchSettings

    search = SearchSettings(offset_max=cfg["decompose.plane_offset_max"],
                            angle_max=cfg["decompose.plane_angle_max"],
                            area_growth_max=cfg["decompose.area_growth_max"],
                            max_iterations=cfg["decompose.max_iterations"])
    parts = cfg["decompose.parts"] if args.parts is None else bounded("parts", args.parts)
    seed = cfg["decompose.seed"] if args.seed is None else bounded("seed", args.seed)
    if args.root is not None and args.root < 0:
        raise CliError(f"--root {args.root}: region numbers start at 0")
    return DecomposeSettings(parts=parts, root=args.root, seed=seed, search=search,
                             nozzle_diameter=cfg["machine.nozzle_diameter"])


def run(args: argparse.Namespace) -> int:
    """Run the decomposition and print a short table."""
    from kinematics.machine import MachineGeometry
    from slicer.decompose import (
        DecompositionError,
        RootRegionError,
        decompose_on_bases,
        write_decomposition,
    )
    from slicer.mesh import MeshError, load_mesh, merged_note
    from slicer.printhead import Printhead, PrintheadError

    try:
        cfg = load(args.config or offline_config())
    except ConfigError as exc:
        raise CliError(str(exc)) from None
    settings = _settings(cfg, args)
    spans = [cfg[f"machine.{a}_range"] for a in "xyz"]
    build_volume = np.array([hi - lo for lo, hi in spans], dtype=float)
    machine = MachineGeometry(tuple(cfg["machine.table_origin"]), tuple(cfg["machine.a_pivot"]),
                              tuple(cfg["machine.a_limits"]), cfg["machine.c_limits"])
    try:
        head = Printhead.from_records(cfg["printhead.segments"])
    except PrintheadError as exc:
        raise CliError(f"{cfg.source}: printhead.segments: {exc}") from None
    t0 = time.perf_counter()
    try:
        mesh, placement = load_mesh(args.model, build_volume, settings.nozzle_diameter)
        dec = decompose_on_bases(mesh, settings, machine, head, build_volume, placement.matrix)
    except MeshError as exc:
        raise CliError(str(exc)) from None
    except RootRegionError as exc:
        raise CliError(f"--root {exc.root}: {exc}") from None
    except DecompositionError as exc:
        _write_refusal(Path(args.output), mesh, placement.matrix, settings, str(exc),
                       not args.no_preview)
        raise CliError(f"{args.model}: {exc}", EXIT_FAILED) from None
    out = Path(args.output)
    try:
        write_decomposition(dec, out)
        if not args.no_preview:
            from slicer.preview import render_preview
            render_preview(dec, out / "preview.png")
    except OSError as exc:
        raise CliError(f"{out}: cannot write: {exc.strerror or exc}") from None
    if placement.merged_shells:
        print(merged_note(placement.merged_shells))
    if dec.base is not None and dec.base.note:
        print(dec.base.note)
    _table(dec, time.perf_counter() - t0)
    return 0


NEAR = re.compile(r"near \[(-?[\d.]+), (-?[\d.]+), (-?[\d.]+)\] mm")
"""The point a refusal names (``near [x, y, z] mm``, in the frame the part stood in as
placed: the first one a message names; those after it are other faces')."""


def _write_refusal(out: Path, mesh: Any, placement: np.ndarray, settings: Any, reason: str,
                   preview: bool) -> None:
    """``decomposition.json`` holding the refusal, and ``preview.png`` the part as placed
    with the point it names in red."""
    from slicer.preview import render_refused

    found = NEAR.search(reason)
    points = [[float(v) for v in found.groups()]] if found else []
    payload = {"refused": reason, "points": points, "placement": placement.tolist(),
               "seed": settings.seed, "parts": settings.parts}
    try:
        out.mkdir(parents=True, exist_ok=True)
        (out / "decomposition.json").write_text(json.dumps(payload, indent=2) + "\n",
                                                encoding="utf-8")
        if preview:
            render_refused(mesh, np.array(points).reshape(-1, 3), reason, out / "preview.png")
    except OSError as exc:
        raise CliError(f"{out}: cannot write: {exc.strerror or exc}") from None


def _table(dec: Any, seconds: float) -> None:
    print(f"{'part':>4} {'parent':>6} {'volume mm³':>11} {'base mm²':>9} "
          f"{'direction':>22} {'iter':>5} {'overhang':>9}")
    for s in dec.subparts:
        d = "[" + ", ".join(f"{x:+.2f}" for x in s.build_direction) + "]"
        parent = "-" if s.parent is None else str(s.parent)
        over = dec.overhang[s.index].area if len(dec.overhang) == len(dec.subparts) else 0.0
        print(f"{s.index:>4} {parent:>6} {s.volume:>11.1f} {s.base_area:>9.1f} {d:>22} "
              f"{s.iterations:>5} {over:>9.1f}")
    total = sum(s.volume for s in dec.subparts)
    print(f"{len(dec.subparts)} sub-parts, {total:.1f} of {dec.volume:.1f} mm³, "
          f"k={dec.k} ({dec.regions} regions), order {dec.order}, {seconds:.2f} s")
    if len(dec.attempts) > 1:
        for line in dec.attempts:
            print(f"  tried {line}")
    print(f"seed {dec.seed} (attempt {len(dec.attempts)}), overhang {dec.overhang_area:.1f} mm²"
          f" beyond {dec.overhang_deg:g}°")
