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


def reachable_mask(directions: ArrayLike, a_limits: tuple[float, float],
                   c_limits: tuple[float, float] | None = None) -> np.ndarray:
    """Which directions some (A, C) within the limits turns to +Z.

    The two solutions of :func:`orientation_solutions`, (θ, 90° − φ) and (−θ, −90° − φ), are
    tested: A within ``a_limits`` and C, shifted by whole turns, within ``c_limits``. A
    vertical direction needs A = 0 (up) or ±180° (down) only: every C works.

    Parameters
    ----------
    directions : (n, 3) float
        Directions in the platform frame (need not be unit; zero rows are unreachable).
    a_limits : (2,) float
        Degrees.
    c_limits : (2,) float or None
        Degrees; ``None`` for a continuous C axis.

    Returns
    -------
    (n,) bool
    """
    d = np.asarray(directions, dtype=float).reshape(-1, 3)
    norm = np.linalg.norm(d, axis=1)
    ok = np.isfinite(norm) & (norm > 0)
    rho = np.hypot(d[:, 0], d[:, 1])
    tilt = np.degrees(np.arctan2(rho, d[:, 2]))
    phi = np.degrees(np.arctan2(d[:, 1], d[:, 0]))
    vertical = rho < SINGULAR_EPS * np.maximum(norm, 1e-300)
    fits = np.zeros(len(d), dtype=bool)
    for sign, c in ((1.0, 90.0 - phi), (-1.0, -90.0 - phi)):
        a = sign * tilt
        fits |= _within(a, a_limits) & (vertical | _c_fits(c, c_limits))
    return ok & fits


def _within(values: np.ndarray, limits: tuple[float, float]) -> np.ndarray:
    return (values >= limits[0] - 1e-9) & (values <= limits[1] + 1e-9)


def _c_fits(c: np.ndarray, limits: tuple[float, float] | None) -> np.ndarray:
    """Whether c + 360·k lies within ``limits`` for some whole k, (n,) bool."""
    if limits is None:
        return np.ones(np.shape(c), dtype=bool)
    lo, hi = limits
    first = c + 360.0 * np.ceil((lo - 1e-9 - c) / 360.0)  # smallest turn at or above lo
    return first <= hi + 1e-9


def pose_of(a_deg: ArrayLike, c_deg: ArrayLike) -> np.ndarray:
    """The platform directions that (A, C) turn to machine +Z, (..., 3) float.

    The inverse of :func:`orientation_solutions`: ``Rz(C)ᵀ Rx(A)ᵀ ẑ`` =
    (sin A sin C, sin A cos C, cos A).
    """
    a = np.radians(np.asarray(a_deg, dtype=float))
    c = np.radians(np.asarray(c_deg, dtype=float))
    return np.stack(np.broadcast_arrays(np.sin(a) * np.sin(c), np.sin(a) * np.cos(c),
                                        np.cos(a)), axis=-1)


def nearest_reachable_direction(direction: ArrayLike, a_limits: tuple[float, float],
                                c_limits: tuple[float, float] | None = None,
                                step: float = 0.5) -> np.ndarray | None:
    """The direction reachable within both limits nearest to ``direction`` (3,), or None.

    ``direction`` itself when reachable; else the best of the (A, C) grid of ``step``
    degrees spanning the limits (both ends included), polished by a finer grid around it.
    ``None`` when the limits are empty.
    """
    d = _unit(direction)
    if reachable_mask(d[None], a_limits, c_limits)[0]:
        return d
    lo_c, hi_c = c_limits if c_limits is not None else (-180.0, 180.0)
    if a_limits[0] > a_limits[1] + 1e-9 or lo_c > hi_c + 1e-9:
        return None
    box = ((a_limits[0], a_limits[1]), (lo_c, hi_c))
    best = None
    for _ in range(3):  # coarse grid, then two finer ones around the best
        axes = [np.unique(np.concatenate([np.arange(lo, hi, step), [hi]])) for lo, hi in box]
        cand = pose_of(*np.meshgrid(*axes, indexing="ij")).reshape(-1, 3)
        best = cand[int(np.argmax(cand @ d))]
        a0, c0 = _pose_near(best, box)
        box = ((max(a_limits[0], a0 - step), min(a_limits[1], a0 + step)),
               (max(lo_c, c0 - step), min(hi_c, c0 + step)))
        step /= 10.0
    return best


def _pose_near(d: np.ndarray, box: tuple[tuple[float, float], tuple[float, float]]
               ) -> tuple[float, float]:
    """The (A, C) of ``box`` that turns ``d`` to +Z (the first solution in it)."""
    sols = orientation_solutions(d) or ((0.0, 0.5 * (box[1][0] + box[1][1])),)
    for a, c in sols:
        turned = c + 360.0 * math.ceil((box[1][0] - 1e-9 - c) / 360.0)
        if _in(a, box[0]) and turned <= box[1][1] + 1e-9:
            return a, turned
    return sols[0]


def needed_pose(direction: ArrayLike) -> str:
    """The table angles that would print ``direction``, as text for refusals.

    E.g. ``"A 45.0°, C 80.0° (or A -45.0°, C -100.0°)"``; ``"A 0°"`` for a vertical one.
    """
    sols = orientation_solutions(direction)
    if sols is None:
        return "A 0°" if _unit(direction)[2] > 0 else "A 180°"
    (a1, c1), (a2, c2) = sols
    return f"A {a1:.1f}°, C {c1:.1f}° (or A {a2:.1f}°, C {c2:.1f}°)"


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
