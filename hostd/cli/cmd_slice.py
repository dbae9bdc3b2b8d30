"""``hostctl slice MODEL.stl -o OUT.gcode``: offline five-axis slicing with a replay check."""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import Any

from hostd.cli.errors import EXIT_FAILED, CliError
from hostd.cli.options import add_allow_overhang, add_decompose_options, decompose_overrides
from hostd.config import ConfigError, load
from hostd.config.paths import INSTALLED_CONFIG, offline_config


def register(subparsers: Any) -> None:
    """Add the ``slice`` verb."""
    p = subparsers.add_parser(
        "slice", help="slice an STL to checked five-axis G-code (offline)",
        description="Decompose MODEL.stl, slice every sub-part along its own direction, write "
                    "joint-space G-code and replay-check it; a file with head collisions, a "
                    "layer printed in the air or unsupported wall layers is refused (exit 1, "
                    "no file; --preview still drawn, the failing region in red).")
    p.add_argument("model", help="ASCII or binary STL")
    p.add_argument("-o", "--output", required=True, help="G-code file to write")
    p.add_argument("--layer-height", type=float, default=None,
                   help="nominal layer height, mm (default: config process.layer_height)")
    p.add_argument("--config", default=None, metavar="FILE",
                   help=f"config file (default: {INSTALLED_CONFIG} if it exists, else the "
                        "shipped defaults)")
    p.add_argument("--preview", default=None, help="write a PNG of the toolpaths here")
    p.add_argument("--planar", action="store_true",
                   help="3-axis control: no decomposition, horizontal layers, A = C = 0")
    add_decompose_options(p)
    add_allow_overhang(p, "write the file")
    p.set_defaults(func=run)


def _inputs(args: argparse.Namespace) -> dict[str, Any]:
    from hostd.config import convert
    from slicer.printhead import PrintheadError

    try:
        cfg = load(args.config or offline_config())
    except ConfigError as exc:
        raise CliError(str(exc)) from None
    override: dict[str, float] = {}
    if args.layer_height is not None:
        h = args.layer_height
        if not math.isfinite(h) or not 0.04 <= h <= 0.8 * cfg["machine.nozzle_diameter"]:
            raise CliError(f"--layer-height {h:g}: must lie in [0.04, "
                           f"{0.8 * cfg['machine.nozzle_diameter']:g}] mm")
        override["layer_height"] = h
    try:
        return convert.slice_inputs(cfg, decompose=decompose_overrides(args), **override)
    except PrintheadError as exc:
        raise CliError(f"{cfg.source}: printhead.segments: {exc}") from None
    except (TypeError, ValueError) as exc:
        raise CliError(f"{cfg.source}: process: {exc}") from None


def _slice(args: argparse.Namespace, inputs: dict[str, Any]) -> Any:
    from slicer.advice import SLICE_OPTIONS
    from slicer.decompose import DecompositionError
    from slicer.gcode import GcodeError
    from slicer.mesh import MeshError
    from slicer.paths import SlicingError
    from slicer.pipeline import ReplayRefusal, SliceError, slice_model

    try:
        return slice_model(args.model, planar=args.planar, keep_plan=args.preview is not None,
                           allow_overhang=args.allow_overhang, knobs=SLICE_OPTIONS, **inputs)
    except MeshError as exc:
        raise CliError(str(exc)) from None
    except GcodeError as exc:
        raise CliError(f"{args.config}: {exc}") from None
    except ReplayRefusal as exc:  # the file is refused, its preview still drawn
        if args.preview and exc.plan is not None:
            _preview(exc.plan, args.preview, exc.marks, _mark_note(exc))
        raise CliError(f"{args.model}: {exc}", EXIT_FAILED) from None
    except (DecompositionError, SlicingError, SliceError) as exc:
        raise CliError(f"{args.model}: {exc}", EXIT_FAILED) from None


def _mark_note(exc: Exception) -> str:
    """What the red points of a refusal's preview are."""
    from slicer.pipeline import UnsupportedWallsError

    if isinstance(exc, UnsupportedWallsError):
        return "refused: unsupported wall points"
    return "refused: layers printed in the air"


def _preview(plan: Any, path: str, marks: Any, note: str) -> None:
    """Draw the toolpath preview of ``plan`` with ``marks`` in red."""
    from slicer.preview import render_toolpaths

    try:
        render_toolpaths(plan, path, marks=marks, note=note)
    except OSError as exc:
        raise CliError(f"cannot write: {exc.filename or path}: {exc.strerror or exc}",
                       EXIT_FAILED) from None


def _check_outputs(args: argparse.Namespace) -> None:
    """Refuse, before minutes of slicing, outputs that could not be written or would
    overwrite the model."""
    out = Path(args.output)
    model = Path(args.model)
    if model.exists() and out.exists() and out.resolve() == model.resolve():
        raise CliError(f"-o {args.output}: that is the model itself; name another file")
    wanted = [(out, "-o")] + ([(Path(args.preview), "--preview")] if args.preview else [])
    for path, flag in wanted:
        if not path.parent.is_dir():
            raise CliError(f"{flag} {path}: no such directory {path.parent}")
    if args.preview and Path(args.preview).suffix.lower() != ".png":
        raise CliError(f"--preview {args.preview}: the preview is a PNG image; name a *.png "
                       "file")


def run(args: argparse.Namespace) -> int:
    """Slice, write, print the summary."""
    t0 = time.perf_counter()
    _check_outputs(args)
    result = _slice(args, _inputs(args))
    from slicer.gcode import write_gcode

    out = Path(args.output)
    try:
        write_gcode(out, result.lines)
    except OSError as exc:
        raise CliError(f"cannot write: {exc.filename or out}: {exc.strerror or exc}",
                       EXIT_FAILED) from None
    if args.preview:
        walls = result.walls.p if result.walls is not None else None
        _preview(result.plan, args.preview, walls, "unsupported wall points (allowed)")
    if result.warning:
        print(f"hostctl: warning: {result.warning}", file=sys.stderr)
    _summary(result, out, time.perf_counter() - t0)
    return 0


def _summary(r: Any, out: Path, seconds: float) -> None:
    from slicer.mesh import merged_note

    est, rep = r.estimate, r.replay
    lo, hi = r.thickness
    print(f"wrote {out}: {len(r.lines)} lines")
    if r.merged_shells:
        print(merged_note(r.merged_shells))
    turned = _turned_degrees(r.lines)
    if r.base_note:  # turned to stand on a larger face, or one is named
        print(r.base_note)
    elif turned > 0.5:
        print(f"placed turned {turned:.0f}° from the file's orientation: the part's own "
              "bottom has no flat base to stand on, so it stands on its largest flat face")
    print(f"sub-parts {r.subparts}, layers {r.layers}, local thickness {lo:.3f}–{hi:.3f} mm")
    count, thinnest = r.thinned
    if count:
        print(f"{count} layers thinner than the layer height (down to {thinnest:.3f} mm) where "
              "the surface overhangs a little past what it holds")
    tried = int(r.timings.get("alternatives_tried", 0))
    if tried and r.seed is not None:  # the closed loop tried other decompositions
        again = f"--seed {r.seed}" + (f" --parts {r.parts}" if r.parts else "")
        print(f"decomposition seed {r.seed}, the best of {tried + 1} decompositions tried "
              f"({again} repeats it)")
    print(f"filament {est['filament_mm']:.0f} mm ({est['mass_g']:.1f} g), "
          f"time {_hms(float(est['time_s']))} ({est['time_s']:.0f} s)")
    if rep:
        from slicer.replay import worst_layer_text

        print(f"replay: inside {100 * rep['inside']:.2f}%, coverage "
              f"{100 * rep['coverage']:.2f}%, supported {100 * rep['supported']:.2f}% "
              f"(walls {100 * rep['wall_supported']:.2f}%, "
              f"{len(rep['unsupported_wall_layers'])} unsupported wall layers, "
              f"{rep.get('wall_layers_over_air', 0)} over air; worst layer "
              f"{worst_layer_text(rep.get('worst_layer'))}), collisions {rep['collisions']}")
    print(f"seconds {seconds:.2f} ({_stages(r.timings)})")


def _turned_degrees(lines: list[str]) -> float:
    """How far the placement (the ``;HOSTD_PLACEMENT`` header) tilted the file's Z axis."""
    from slicer.gcode.markers import PLACEMENT, parse_marker, parse_payload

    for line in lines[:8]:
        name, payload = parse_marker(line) or ("", "")
        if name == PLACEMENT:
            zz = float(parse_payload(payload)["matrix"][2][2])
            return math.degrees(math.acos(max(-1.0, min(1.0, zz))))
    return 0.0


COUNTS = {"repair": ("repair_rounds", "round"), "alternatives": ("alternatives_tried", "tried")}
"""Stages of the closed loop, with the count each comes with: ``repair 7.66 (2 rounds)``."""


def _stages(timings: dict[str, float]) -> str:
    """The top-level stages in pipeline order; the text is formatted beside the replay."""
    order = ("load", "plan", "gcode", "read", "replay")
    counts = {key for key, _ in COUNTS.values()}
    out = [f"{k} {timings[k]:.2f}" for k in order if k in timings]
    out += [_stage(k, v, timings) for k, v in timings.items()
            if "." not in k and k not in order and k != "text" and k not in counts]
    if "text" in timings:
        out.append(f"text {timings['text']:.2f} beside the replay" if "replay" in timings
                   else f"text {timings['text']:.2f}")
    return ", ".join(out)


def _stage(name: str, seconds: float, timings: dict[str, float]) -> str:
    """``name seconds``, and its count in parentheses for a stage of the closed loop."""
    if name not in COUNTS or COUNTS[name][0] not in timings:
        return f"{name} {seconds:.2f}"
    key, word = COUNTS[name]
    n = int(timings[key])
    plural = "s" if n != 1 and word == "round" else ""
    return f"{name} {seconds:.2f} ({n} {word}{plural})"


def _hms(s: float) -> str:
    h, rem = divmod(round(s), 3600)
    return f"{h}:{rem // 60:02d}:{rem % 60:02d}"
