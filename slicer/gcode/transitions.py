"""Moves between sub-parts (paper 2.2.5): lift, rotate the platform, travel, approach.

A transition from the end of one sub-part to the first point of the next is four joint moves:

1. lift straight up (machine Z) to a safe height at the old table angles;
2. turn the table to the new angles with X Y Z fixed (the firmware interpolates A and C
   linearly; the nozzle is above everything, so the turn needs no linearisation);
3. travel in X Y at the safe height to above the approach point;
4. descend in Z to the approach point, ``z_hop`` above the first point along the new nozzle
   axis.

The safe height is ``safe_height`` above the highest point the part reaches at any sampled
instant of the turn, and at least ``PLATFORM_MARGIN`` above the platform rim. The head lies
entirely above its tip, so a tip above every obstacle at every instant cannot touch them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import ConvexHull, QhullError

from kinematics.machine import MachineGeometry
from kinematics.transform import forward

PLATFORM_MARGIN = 5.0  # mm of clearance above the platform rim during a turn
SWEEP_STEP_DEG = 1.0  # angular sampling of a turn
RIM_POINTS = 360


@dataclass(frozen=True)
class Transition:
    """The joint moves of one transition.

    Attributes
    ----------
    poses : (4, 5) float
        End poses [X, Y, Z, A, C] of lift, turn, travel and approach (X/Y/A/C of the lift are
        NaN when the start pose is unknown, i.e. at the beginning of the print: the lift moves
        Z alone, and the turn states the angles).
    rotary : (4,) bool
        Which moves turn the table (their feed is degrees/s).
    safe_z : float
        Machine Z of the lift, mm.
    """

    poses: np.ndarray
    rotary: np.ndarray
    safe_z: float

    @property
    def target(self) -> np.ndarray:
        """The pose the transition ends at (what a readback must find), (5,)."""
        return self.poses[-1]


def obstacle_hull(points: ArrayLike) -> np.ndarray:
    """Vertices of the convex hull of ``points`` (n, 3): the only ones that can be highest."""
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    if len(p) < 5:
        return p
    try:
        return p[ConvexHull(p).vertices]
    except QhullError:  # flat or degenerate sets: keep them all
        return p


def platform_rim(radius: float, n: int = RIM_POINTS) -> np.ndarray:
    """Points on the platform's edge (z = 0), (n, 3): the highest points of a tilted disc."""
    t = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    return np.column_stack([radius * np.cos(t), radius * np.sin(t), np.zeros(n)])


def sweep_max_z(points: np.ndarray, a0: float, c0: float, a1: float, c1: float,
                geometry: MachineGeometry, step_deg: float = SWEEP_STEP_DEG) -> float:
    """Highest machine Z of platform-frame ``points`` (n, 3) while A/C move linearly.

    The turn is sampled so neither angle moves more than ``step_deg`` between samples; the
    bound is padded by the largest chord error of such a step over the points' radius.
    """
    if len(points) == 0:
        return -math.inf
    span = max(abs(a1 - a0), abs(c1 - c0))
    n = max(2, math.ceil(span / step_deg) + 1)
    s = np.linspace(0.0, 1.0, n)
    a = a0 + (a1 - a0) * s
    c = c0 + (c1 - c0) * s
    z = forward(points[None, :, :], a[:, None], c[:, None], geometry)[..., 2]
    reach = float(np.linalg.norm(points + geometry.t - geometry.q, axis=1).max())
    chord = reach * (1.0 - math.cos(math.radians(step_deg)))
    return float(z.max()) + chord


def safe_height_z(hull: np.ndarray, rim: np.ndarray, a0: float, c0: float, a1: float,
                  c1: float, geometry: MachineGeometry, safe_height: float) -> float:
    """Machine Z that clears the part by ``safe_height`` and the platform during a turn."""
    part = sweep_max_z(hull, a0, c0, a1, c1, geometry) + safe_height
    plate = sweep_max_z(rim, a0, c0, a1, c1, geometry) + PLATFORM_MARGIN
    return max(part, plate)


def plan_transition(start: np.ndarray | None, point: ArrayLike, a: float, c: float,
                    hull: np.ndarray, rim: np.ndarray, geometry: MachineGeometry,
                    safe_height: float, z_hop: float) -> Transition:
    """Moves from ``start`` (pose (5,), or None before the first move) to above ``point``.

    Parameters
    ----------
    start : (5,) float or None
        Current [X, Y, Z, A, C]; None at the start of the print (X/Y/A/C left where the
        start script put them: the safe height assumes A = C = 0, as homing leaves them, and
        the lift moves Z alone, so a table left turned is not swung round while the nozzle
        rises; the turn then goes to the new angles at the safe height).
    point : (3,) float
        First point of the next sub-part, platform frame.
    a, c : float
        Table angles of the next sub-part's first layer, degrees.
    hull, rim : (n, 3) float
        Part obstacle hull (:func:`obstacle_hull`) and platform rim (:func:`platform_rim`).
    """
    if start is None:  # the lift turns nothing: its A/C words stay unwritten (NaN)
        start = np.array([np.nan, np.nan, -math.inf, np.nan, np.nan])
    a0, c0 = (0.0, 0.0) if np.isnan(start[3:]).any() else (float(start[3]), float(start[4]))
    above = forward(np.asarray(point, dtype=float).reshape(3), a, c, geometry)
    above = above + np.array([0.0, 0.0, z_hop])
    z = safe_height_z(hull, rim, a0, c0, a, c, geometry, safe_height)
    z = max(z, float(start[2]), float(above[2]))
    poses = np.array([
        [start[0], start[1], z, start[3], start[4]],
        [start[0], start[1], z, a, c],
        [above[0], above[1], z, a, c],
        [above[0], above[1], above[2], a, c],
    ])
    return Transition(poses, np.array([False, True, False, False]), z)
