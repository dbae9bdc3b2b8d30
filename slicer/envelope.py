"""Does a part, and the program written for it, stay inside the machine?

Checks that neither the planner nor the replay makes, run by :mod:`slicer.pipeline`:

* the part's footprint on the platform (its largest distance from the C axis, in the
  platform frame) against ``machine.platform_radius``, before planning;
* a program that extrudes nothing (every wall thinner than the line width), and
* every machine X/Y/Z the program moves to (the printed values, transitions, reorientations
  and the end script's ``{safe_z}`` included) against ``machine.x_range``/``y_range``/
  ``z_range``.

Moves are straight lines in joint space, so a move whose end points lie inside the (box
shaped) travel stays inside it. The functions here are pure numpy; :func:`refuse` wraps a
finding in :class:`EnvelopeError`, a :class:`~slicer.mesh.errors.MeshError` (a part that cannot be
printed, one line naming the file) so that callers report it as bad input.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from slicer.gcode.markers import LAYER, TRANSITION, parse_marker, parse_payload
from slicer.mesh import MeshError

AXES = "XYZ"
DEFAULT_TRAVEL = ((0.0, 500.0), (0.0, 500.0), (0.0, 700.0))
"""``machine.x_range``, ``y_range``, ``z_range`` of the shipped config, mm."""
FOOTPRINT_TOL = 1e-6  # mm: a part exactly as wide as the platform fits


class EnvelopeError(MeshError):
    """The part or its moves leave the machine (travel, platform) or nothing is printed."""


@dataclass(frozen=True)
class TravelViolation:
    """The worst excursion of one machine axis beyond its travel.

    Attributes
    ----------
    axis : int
        0, 1, 2 for X, Y, Z.
    row : int
        Index of the first position that reaches ``value``.
    value : float
        The position reached, mm.
    low, high : float
        The axis' travel, mm.
    """

    axis: int
    row: int
    value: float
    low: float
    high: float

    def message(self, where: str) -> str:
        """One line naming the axis, the value reached, the range and ``where``."""
        name = AXES[self.axis]
        return (f"machine {name} reaches {self.value:.3f} mm, outside machine."
                f"{name.lower()}_range [{self.low:g}, {self.high:g}] ({where})")


def footprint_radius(points: ArrayLike) -> float:
    """Largest distance of platform-frame points from the C axis (the platform's centre).

    Parameters
    ----------
    points : (n, 3) float
        The placed part's vertices, platform frame, mm.

    Returns
    -------
    float
        mm; 0 for no points.
    """
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    return float(np.hypot(p[:, 0], p[:, 1]).max()) if len(p) else 0.0


def footprint_message(radius: float, platform_radius: float) -> str | None:
    """Why a part of footprint ``radius`` does not fit the platform, or None if it fits."""
    if radius <= platform_radius + FOOTPRINT_TOL:
        return None
    return (f"does not fit on the platform: footprint radius {radius:.1f} mm exceeds "
            f"machine.platform_radius {platform_radius:g} mm")


def travel_violation(xyz: ArrayLike, travel: ArrayLike) -> TravelViolation | None:
    """The largest excursion of any axis beyond its travel, or None if all lie inside.

    Parameters
    ----------
    xyz : (n, 3) float
        Machine positions as written (NaN for an axis not set yet: ignored), mm.
    travel : (3, 2) float
        [min, max] of X, Y and Z, mm.

    Returns
    -------
    TravelViolation or None
    """
    p = np.asarray(xyz, dtype=float).reshape(-1, 3)
    lim = np.asarray(travel, dtype=float).reshape(3, 2)
    if len(p) == 0:
        return None
    with np.errstate(invalid="ignore"):
        excess = np.fmax(lim[:, 0] - p, p - lim[:, 1])  # (n, 3), > 0 outside, NaN unset
    excess = np.where(np.isnan(excess), -np.inf, excess)
    flat = int(np.argmax(excess))
    row, axis = divmod(flat, 3)
    if excess[row, axis] <= 0.0:
        return None
    return TravelViolation(axis, row, float(p[row, axis]), float(lim[axis, 0]),
                           float(lim[axis, 1]))


def extruded_length(xyz: ArrayLike, e: ArrayLike) -> float:
    """Length of the moves that extrude (E > 0 while the tool moves), mm.

    Parameters
    ----------
    xyz : (n, 3) float
        Machine position each move ends at (NaN where unknown), mm.
    e : (n,) float
        Filament each move pushes, mm (retracts < 0).

    Returns
    -------
    float
        Sum of the lengths of moves with E > 0 from the previous position; 0 when the
        program prints nothing.
    """
    p = np.asarray(xyz, dtype=float).reshape(-1, 3)
    if len(p) < 2:
        return 0.0
    step = np.linalg.norm(np.diff(p, axis=0), axis=1)
    printing = np.asarray(e, dtype=float)[1:] > 0.0
    return float(np.nansum(np.where(printing, step, 0.0)))


def nothing_to_print_message(line_width: float, layers: int) -> str:
    """The refusal of a part whose toolpaths are all empty."""
    return (f"nothing to print: walls thinner than the line width ({line_width:g} mm) leave "
            f"no toolpath in any of the {layers} layers")


def place_of(row: int, at: ArrayLike, texts: list[str]) -> str:
    """Where move ``row`` lies in the file, from the markers written before it.

    Parameters
    ----------
    row : int
        Index of a move row.
    at : (m,) int
        Move rows before each raw line (non-decreasing).
    texts : list of str
        The m raw lines.

    Returns
    -------
    str
        ``"sub-part k, layer i"``, ``"transition to sub-part k"`` or ``"start"``.
    """
    before = int(np.searchsorted(np.asarray(at), row, side="right"))
    for text in reversed(texts[:before]):
        name, payload = parse_marker(text) or ("", "")
        if name == LAYER:
            layer = parse_payload(payload)
            return f"sub-part {layer['subpart']}, layer {layer['index']}"
        if name == TRANSITION:
            return f"transition to sub-part {parse_payload(payload)['to']}"
    return "start"


def refuse(name: str, message: str | None) -> None:
    """Raise :class:`EnvelopeError` ``"<name>: <message>"`` when there is a message."""
    if message is not None:
        raise EnvelopeError(f"{name}: {message}")
