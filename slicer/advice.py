"""What a refused slice says: where, why, and what to try, in the caller's own words.

A refusal suggests settings to change (another decomposition seed, the coarse part count) or
how to let the file through anyway; every one it names must be something the operator can set
where the message is read. :class:`Knobs` says how the caller names them: the config keys by
default (a library caller), ``hostctl slice``'s options there (:data:`SLICE_OPTIONS`), and
``hostctl print``'s for a daemon job (:data:`PRINT_OPTIONS`). A knob the caller has not is
``None`` and never suggested.

A thinner layer is suggested for unsupported walls only where it holds them: the support rule
is an angle (45°) plus a tenth of a line width, so thinner layers hold a wall a little
steeper than 45° (a ball meeting its stem in a ring at 52.7°: ``hard_samples`` ball11, over
air at 0.2 and 0.15 mm, held at 0.1 mm) and not a far steeper one (``hard/tee_low.stl``'s
upright arch, before the closed loop: 14 layers over air at 0.2 mm, 19 at 0.15 mm, 21 at
0.1 mm). :func:`thinner_layers` gives the height (:func:`slicer.replay.held_height` of the
steepest surface near the unsupported walls, :func:`slicer.replay.overhang_deg`), when it
is one worth printing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from slicer.replay import (
    BAD_LAYER_SHARE,
    OVERHANG_DEG,
    ReplayReport,
    held_height,
    overhang_text,
    wall_layer_text,
)


@dataclass(frozen=True)
class Knobs:
    """How the caller names each setting a refusal may suggest (``None``: not offered).

    Attributes
    ----------
    seed, parts : str or None
        The decomposition's seed and coarse part count K.
    allow_overhang : str or None
        Writing (queueing) a file with unsupported wall layers anyway.
    layer_height : str or None
        The nominal layer height.
    """

    seed: str | None = "decompose.seed"
    parts: str | None = "decompose.parts"
    allow_overhang: str | None = "allow_overhang=True"
    layer_height: str | None = "process.layer_height"


CONFIG_KEYS = Knobs()
SLICE_OPTIONS = Knobs("--seed", "--parts", "--allow-overhang", "--layer-height")
PRINT_OPTIONS = Knobs("--seed", "--parts", "--allow-overhang", None)  # sliced as configured
THINNEST = 0.05  # mm: a thinner layer height is not suggested


def overhang_message(layers: list[dict[str, Any]], seed: int | None,
                     knobs: Knobs = CONFIG_KEYS) -> str:
    """One line for a replay's ``overhang_layers`` (worst first, at least one): the worst
    layer, how many more, and what to try (another decomposition seed; for the planar
    control (``seed`` None), the five-axis slice)."""
    worst = layers[0]
    more = f" (and {len(layers) - 1} more layers)" if len(layers) > 1 else ""
    if seed is None:
        advice = ("the planar control cannot print this overhang without support; slice it "
                  "five-axis (without --planar)")
    else:
        advice = (f"the decomposition left an overhang in sub-part {worst['subpart']}"
                  + _try(_decomposition(seed, knobs)))
    return (f"replay found a layer printed in the air; refusing to write the file: "
            f"{overhang_text(worst)}{more}; {advice}")


def walls_message(report: ReplayReport, seed: int | None, knobs: Knobs = CONFIG_KEYS,
                  thinner: tuple[float, float] | None = None) -> str:
    """One line refusing a file with unsupported wall layers: how many, why, the worst (its
    sub-part, layer, share and a point in the part's frame), and what to try; ``thinner`` is
    (layer height, the surface's overhang in degrees) of :func:`thinner_layers`."""
    if seed is None:
        ways = ["slicing it five-axis (without --planar)"]
    else:
        ways = _decomposition(seed, knobs)
    if thinner is not None and knobs.layer_height is not None:
        ways.insert(0, f"{knobs.layer_height} {thinner[0]:.2f} or thinner (the walls there "
                       f"overhang {thinner[1]:.0f}°, which that holds)")
    if knobs.allow_overhang is not None:
        ways.append(f"{knobs.allow_overhang} to write it as it is")
    return (f"{_walls_found(report)}; refusing to write the file: worst "
            f"{wall_layer_text(report.wall_layers[0])}{_try(ways)}")


def thinner_layers(angle_deg: float, layer_height: float, line_width: float
                   ) -> tuple[float, float] | None:
    """(layer height, ``angle_deg``) to suggest for walls overhanging ``angle_deg`` that the
    replay did not hold at ``layer_height``: the largest height that holds them
    (:func:`slicer.replay.held_height`) rounded down to 0.01 mm, or None when that is not
    below ``layer_height`` or is under :data:`THINNEST` (or the angle is nan)."""
    held = held_height(angle_deg, line_width)
    if not math.isfinite(held):
        return None
    held = math.floor(held * 100.0 + 1e-9) / 100.0
    if not THINNEST <= held < layer_height:
        return None
    return held, angle_deg


def walls_warning(report: ReplayReport, knobs: Knobs = CONFIG_KEYS) -> str:
    """One line for a file written with unsupported wall layers, as the operator asked."""
    asked = "" if knobs.allow_overhang is None else f" ({knobs.allow_overhang})"
    return (f"{_walls_found(report)}; written anyway, as asked{asked}: worst "
            f"{wall_layer_text(report.wall_layers[0])}")


def _walls_found(report: ReplayReport) -> str:
    """``replay found N unsupported wall layers over air (why)``."""
    n = report.wall_layers_over_air
    return (f"replay found {n} unsupported wall layer{'s' if n != 1 else ''} over air (over "
            f"{100 * BAD_LAYER_SHARE:g}% of a layer's wall points with nothing beneath them "
            f"within {OVERHANG_DEG:g}° and no sparse infill to bridge)")


def _decomposition(seed: int, knobs: Knobs) -> list[str]:
    """Another decomposition: the next seed, another coarse part count."""
    ways = []
    if knobs.seed is not None:
        ways.append(f"{knobs.seed} {seed + 1} (or another seed)")
    if knobs.parts is not None:
        ways.append(f"another {knobs.parts} (the coarse part count)")
    return ways


def _try(ways: list[str]) -> str:
    """``"; try a, b or c"`` (nothing without ways)."""
    if not ways:
        return ""
    if len(ways) == 1:
        return f"; try {ways[0]}"
    return f"; try {', '.join(ways[:-1])} or {ways[-1]}"
