"""Orientation solver: the table angles that turn a build direction to machine +Z.

For a unit direction d = (dx, dy, dz) in the platform frame with azimuth φ = atan2(dy, dx),
``Rx(A) Rz(C) d = +Z`` has exactly two solutions away from the singularity:

* A = +θ, C = 90° − φ  (C swings d onto +Y, then A tilts it up), and
* A = −θ, C = −90° − φ,

where θ = atan2(√(dx² + dy²), dz) is the tilt from vertical (the paper's eq. 7 writes it as
arccos(dz), which loses all precision for nearly vertical directions; its eq. 8, arctan(dy/dx),
loses the quadrant).

At the singularity (d vertical, A = 0) every C works: the current C is kept, so a straight
vertical part never makes the table spin.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from kinematics.errors import UnreachableDirection
from kinematics.machine import SINGULAR_EPS, MachineGeometry

Pose = tuple[float, float]


def _unit(direction: ArrayLike) -> np.ndarray:
    d = np.asarray(direction, dtype=float).reshape(3)
    n = float(np.linalg.norm(d))
    if not math.isfinite(n) or n == 0.0:
        raise UnreachableDirection(f"direction {d.tolist()} has no length")
    return d / n


def orientation_solutions(direction: ArrayLike) -> tuple[Pose, Pose] | None:
    """Both (A, C) solutions in degrees, or ``None`` at the singularity (d parallel to Z).

    C is returned in (-180°, 180°]; callers shift it by whole turns as they need.
    """
    d = _unit(direction)
    rho = math.hypot(d[0], d[1])
    if rho < SINGULAR_EPS:
        return None
    tilt = math.degrees(math.atan2(rho, d[2]))  # exact near vertical, unlike acos(dz)
    phi = math.degrees(math.atan2(d[1], d[0]))
    return (tilt, _wrap(90.0 - phi)), (-tilt, _wrap(-90.0 - phi))


def _wrap(c: float) -> float:
    w = math.fmod(c + 180.0, 360.0)
    w = w + 360.0 if w <= 0.0 else w
    return w - 180.0


def _nearest_turn(c: float, current: float, limits: tuple[float, float] | None) -> float | None:
    """The value c + 360·k nearest ``current`` within ``limits`` (None if no k fits)."""
    best = c + 360.0 * round((current - c) / 360.0)
    if limits is None:
        return best
    lo, hi = limits
    candidates = [best + 360.0 * k for k in range(-2, 3)]
    inside = [x for x in candidates if lo - 1e-9 <= x <= hi + 1e-9]
    if not inside:
        first = c + 360.0 * math.ceil((lo - c) / 360.0)
        return first if first <= hi + 1e-9 else None
    return min(inside, key=lambda x: abs(x - current))


def _in(value: float, limits: tuple[float, float]) -> bool:
    return limits[0] - 1e-9 <= value <= limits[1] + 1e-9


def solve_orientation(direction: ArrayLike, geometry: MachineGeometry,
                      current_c: float = 0.0) -> Pose:
    """Table angles (A, C) in degrees that make ``direction`` point to machine +Z.

    Of the two solutions, the one inside the limits whose C is nearest ``current_c`` (shifted
    by whole turns, so no needless unwinding) wins; ties go to the smaller |A|. Near the
    singularity the current C is kept.

    Raises
    ------
    UnreachableDirection
        No solution lies within ``geometry.a_limits`` / ``c_limits``.
    """
    d = _unit(direction)
    sols = orientation_solutions(d)
    if sols is None:
        return _vertical(d, geometry, current_c)
    options = []
    for a, c in sols:
        shifted = _nearest_turn(c, current_c, geometry.c_limits)
        if _in(a, geometry.a_limits) and shifted is not None:
            options.append((abs(shifted - current_c), abs(a), a, shifted))
    if not options:
        raise _unreachable(d, geometry)
    _, _, a, c = min(options)
    return a, c


def _vertical(d: np.ndarray, geometry: MachineGeometry, current_c: float) -> Pose:
    if d[2] < 0 or not _in(0.0, geometry.a_limits):
        raise _unreachable(d, geometry)
    c = current_c
    if geometry.c_limits is not None:
        c = min(max(c, geometry.c_limits[0]), geometry.c_limits[1])
    return 0.0, c


def _unreachable(d: np.ndarray, geometry: MachineGeometry) -> UnreachableDirection:
    tilt = math.degrees(math.atan2(math.hypot(d[0], d[1]), d[2]))
    dirn = "[" + ", ".join(f"{x:.4g}" for x in d) + "]"
    lims = f"A limits [{geometry.a_limits[0]:g}, {geometry.a_limits[1]:g}]°"
    if geometry.c_limits is not None:
        lims += f", C limits [{geometry.c_limits[0]:g}, {geometry.c_limits[1]:g}]°"
    return UnreachableDirection(
        f"build direction {dirn} needs a tilt of {tilt:.2f}° from vertical, outside {lims}")


def reachable_mask(directions: ArrayLike, a_limits: tuple[float, float]) -> np.ndarray:
    """Which directions some A within ``a_limits`` turns to +Z (C assumed continuous).

    Parameters
    ----------
    directions : (n, 3) float
        Directions in the platform frame (need not be unit; zero rows are unreachable).
    a_limits : (2,) float

    Returns
    -------
    (n,) bool
    """
    d = np.asarray(directions, dtype=float).reshape(-1, 3)
    norm = np.linalg.norm(d, axis=1)
    ok = np.isfinite(norm) & (norm > 0)
    tilt = np.degrees(np.arctan2(np.hypot(d[:, 0], d[:, 1]), d[:, 2]))
    lo, hi = a_limits
    fits = ((tilt >= lo - 1e-9) & (tilt <= hi + 1e-9)) | ((-tilt >= lo - 1e-9) &
                                                          (-tilt <= hi + 1e-9))
    return ok & fits


def solve_path(directions: ArrayLike, geometry: MachineGeometry,
               current_c: float = 0.0) -> np.ndarray:
    """Solve a sequence of directions, each C nearest the previous one.

    Returns
    -------
    (n, 2) float
        A, C per direction, degrees.
    """
    out = []
    c = current_c
    for d in np.asarray(directions, dtype=float).reshape(-1, 3):
        a, c = solve_orientation(d, geometry, c)
        out.append((a, c))
    return np.asarray(out, dtype=float).reshape(-1, 2)
