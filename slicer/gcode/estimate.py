"""Filament and time estimates of a joint-space move list, vectorised over all moves.

Time model (documented simplification of a firmware planner):

* every move follows a trapezoidal speed profile: accelerate at ``a`` from its entry speed to
  its cruise speed (the feed, capped by the machine's top speed), cruise, decelerate to its
  exit speed; short moves get a triangular profile;
* the speed at a junction between two linear-only moves is ``min(v_i, v_j) · max(0, cos θ)``
  (θ the turn angle): full speed straight on, zero at right angles and sharper; junctions
  next to a move that turns the table, a travel↔extrusion change or an extruder-only move
  are zero;
* entry and exit speeds are made reachable within the move itself (one pass; no look-ahead
  across moves), so a long run of tiny segments is never estimated faster than possible;
* a move that turns the table takes the longer of its linear time and its rotary time (peak
  angular travel of A or C at ``max_rotary_velocity`` / ``max_rotary_accel``); extruder-only
  moves (retract/unretract) run at their feed with the linear acceleration.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from slicer.gcode.program import SUB, E, F, G
from slicer.settings import ProcessSettings


@dataclass(frozen=True)
class MotionLimits:
    """Machine limits of the time model: mm/s, mm/s², degrees/s, degrees/s²."""

    max_velocity: float = 200.0
    max_accel: float = 1000.0
    max_rotary_velocity: float = 90.0
    max_rotary_accel: float = 360.0

    @classmethod
    def from_settings(cls, s: ProcessSettings) -> MotionLimits:
        """The limits held in the process settings."""
        return cls(s.max_velocity, s.max_accel, s.max_rotary_velocity, s.max_rotary_accel)


@dataclass
class Estimate:
    """Filament (mm of filament), mass (g) and time (s), in total and per sub-part."""

    filament_mm: float
    mass_g: float
    time_s: float
    subparts: list[dict[str, float]] = field(default_factory=list)

    def header(self) -> dict[str, object]:
        """The ``;HOSTD_ESTIMATE`` payload."""
        return {"filament_mm": round(self.filament_mm, 2), "time_s": round(self.time_s, 1),
                "mass_g": round(self.mass_g, 3), "subparts": self.subparts}


def trapezoid_time(length: np.ndarray, v_entry: np.ndarray, v_exit: np.ndarray,
                   v_max: np.ndarray, accel: np.ndarray | float) -> np.ndarray:
    """Duration of trapezoidal (or triangular) profiles, vectorised.

    Parameters
    ----------
    length : (n,) float
        Distance, ≥ 0.
    v_entry, v_exit : (n,) float
        Speeds at the ends, reachable within ``length`` (clipped to ``v_max``).
    v_max : (n,) float
        Cruise speed, > 0.
    accel : (n,) float or float
        Acceleration, > 0.

    Returns
    -------
    (n,) float
        Seconds; 0 where ``length`` is 0.
    """
    length = np.asarray(length, dtype=float)
    v = np.asarray(v_max, dtype=float) * np.ones_like(length)
    a = np.asarray(accel, dtype=float) * np.ones_like(length)
    v0 = np.minimum(v_entry, v)
    v1 = np.minimum(v_exit, v)
    d_acc = (v * v - v0 * v0) / (2 * a)
    d_dec = (v * v - v1 * v1) / (2 * a)
    cruise = d_acc + d_dec <= length
    safe_v = np.where(v > 0, v, 1.0)
    t_cruise = (v - v0) / a + (v - v1) / a + (length - d_acc - d_dec) / safe_v
    vp = np.sqrt(np.maximum((2 * a * length + v0 * v0 + v1 * v1) / 2, 0.0))
    vp = np.maximum(vp, np.maximum(v0, v1))
    t_peak = (vp - v0) / a + (vp - v1) / a
    return np.where(length > 0, np.where(cruise, t_cruise, t_peak), 0.0)


def _junctions(d: np.ndarray, length: np.ndarray, v: np.ndarray, smooth: np.ndarray,
               g: np.ndarray) -> np.ndarray:
    """Speed at each junction: (n + 1,) with 0 at both ends of the program."""
    unit = d / np.where(length > 0, length, 1.0)[:, None]
    cos = np.einsum("ij,ij->i", unit[:-1], unit[1:])
    ok = smooth[:-1] & smooth[1:] & (g[:-1] == g[1:])
    vj = np.where(ok, np.minimum(v[:-1], v[1:]) * np.clip(cos, 0.0, 1.0), 0.0)
    return np.concatenate([[0.0], vj, [0.0]])


def move_times(start: np.ndarray, end: np.ndarray, feed: np.ndarray, e: np.ndarray,
               g: np.ndarray, limits: MotionLimits) -> np.ndarray:
    """Seconds per move.

    Parameters
    ----------
    start, end : (n, 5) float
        Joint poses [X, Y, Z, A, C] before and after each move (NaN start = unknown: no
        motion counted on that axis).
    feed : (n,) float
        mm/s (degrees/s for moves that only turn the table).
    e : (n,) float
        Relative filament per move.
    g : (n,) int
        0 travel, 1 extrusion.
    """
    delta = end - start
    delta[np.isnan(delta)] = 0.0  # unknown start: no motion counted
    d = delta[:, :3]
    length = np.linalg.norm(d, axis=1)
    turn = np.abs(delta[:, 3:5]).max(axis=1)
    v = np.minimum(feed, limits.max_velocity)
    smooth = (length > 0) & (turn == 0)
    vj = _junctions(d, length, v, smooth, g)
    a = limits.max_accel
    v_in = np.minimum(vj[:-1], np.sqrt(vj[1:] ** 2 + 2 * a * length))
    v_out = np.minimum(vj[1:], np.sqrt(v_in ** 2 + 2 * a * length))
    t_lin = trapezoid_time(length, v_in, v_out, np.where(v > 0, v, 1.0), a)
    t_rot = np.zeros_like(turn)  # profiles of length 0 take no time: only turns are timed
    k = np.flatnonzero(turn > 0)
    v_rot = np.where(length[k] > 0, limits.max_rotary_velocity,
                     np.minimum(feed[k], limits.max_rotary_velocity))
    t_rot[k] = trapezoid_time(turn[k], np.zeros(len(k)), np.zeros(len(k)),
                              np.where(v_rot > 0, v_rot, 1.0), limits.max_rotary_accel)
    t_e = np.zeros_like(turn)
    k = np.flatnonzero((length == 0) & (turn == 0) & (e != 0))
    t_e[k] = trapezoid_time(np.abs(e[k]), np.zeros(len(k)), np.zeros(len(k)),
                            np.where(feed[k] > 0, feed[k], 1.0), a)
    return np.maximum(t_lin, t_rot) + t_e


def deposited(start: np.ndarray, end: np.ndarray, e: np.ndarray) -> np.ndarray:
    """Filament that leaves the nozzle while the axes move (mm per move), (n,)."""
    step = end[:, :3] - start[:, :3]
    step[np.isnan(step)] = 0.0
    moving = np.linalg.norm(step, axis=1) > 0
    return np.where(moving & (e > 0), e, 0.0)


def estimate_program(rows: np.ndarray, limits: MotionLimits, area: float,
                     density: float) -> Estimate:
    """Estimate of a program's move rows (see :mod:`slicer.gcode.program`), (n, 9).

    ``area`` is the filament cross-section (mm²) and ``density`` the material's (g/mm³).
    """
    start = np.full((len(rows), 5), np.nan)
    if len(rows):
        start[1:] = rows[:-1, :5]
    end = rows[:, :5]
    times = move_times(start, end, rows[:, F], rows[:, E], rows[:, G].astype(int), limits)
    fil = deposited(start, end, rows[:, E])
    sub = rows[:, SUB].astype(int)
    per = []
    for k in np.unique(sub[sub >= 0]):
        m = sub == k
        f = float(fil[m].sum())
        per.append({"index": int(k), "filament_mm": round(f, 2),
                    "mass_g": round(f * area * density, 3),
                    "time_s": round(float(times[m].sum()), 1)})
    total = float(fil.sum())
    return Estimate(total, total * area * density, float(times.sum()), per)


def estimate_moves(start: np.ndarray, end: np.ndarray, feed: np.ndarray, e: np.ndarray,
                   g: np.ndarray, limits: MotionLimits, area: float, density: float) -> Estimate:
    """Estimate of a file's moves as :mod:`slicer.gcode.reader` gives them, any slicer's.

    The same time model and filament count as :func:`estimate_program`, for a benchmark
    that compares files of several slicers with one estimator.

    Parameters
    ----------
    start, end : (n, 5) float
        Joint poses [X, Y, Z, A, C] before and after each move (NaN: not known yet; a file
        without A and C words keeps them NaN: no table motion).
    feed : (n,) float
        mm/s; NaN before the file's first F runs at ``limits.max_velocity``.
    e : (n,) float
        Relative filament per move, mm.
    g : (n,) int
        0 travel, 1 extrusion.
    limits : MotionLimits
    area, density : float
        Filament cross-section (mm²) and the material's density (g/mm³).

    Returns
    -------
    Estimate
        Totals only (no sub-parts).
    """
    feed = np.where(np.isnan(feed), limits.max_velocity, feed)
    times = move_times(np.asarray(start, dtype=float), np.asarray(end, dtype=float), feed,
                       np.asarray(e, dtype=float), np.asarray(g, dtype=int), limits)
    total = float(deposited(start, end, e).sum())
    return Estimate(total, total * area * density, float(times.sum()))
