"""Split moves that turn the table so the tool tip stays on a straight platform-frame line.

The firmware interpolates every joint (X Y Z A C) linearly and has no tool-centre-point
control, so while A or C change the tip sweeps an arc relative to the part. Each move is split
at its midpoint, recursively, until the tip deviates from the straight path by at most ``tol``
at every checked point; new waypoints lie exactly on the path.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from kinematics.errors import KinematicsError
from kinematics.machine import MachineGeometry
from kinematics.transform import forward, inverse

CHECK_POINTS = np.linspace(0.0, 1.0, 9)[1:-1]  # interior samples of every piece
MAX_DEPTH = 24


def joints(p: np.ndarray, a: np.ndarray, c: np.ndarray, geometry: MachineGeometry) -> np.ndarray:
    """Joint vectors [X, Y, Z, A, C] for platform points ``p`` (n, 3) at angles ``a``, ``c``."""
    return np.column_stack([forward(p, a, c, geometry), a, c])


def deviation(s0: np.ndarray, s1: np.ndarray, start: np.ndarray, end: np.ndarray,
              geometry: MachineGeometry) -> np.ndarray:
    """Largest tip deviation of each linear joint piece [s0, s1] of the move start→end.

    Parameters
    ----------
    s0, s1 : (k,) float
        Piece bounds as fractions of the whole move.
    start, end : (5,) float
        Platform point (3) and A, C at the move's ends: [px, py, pz, a, c].

    Returns
    -------
    (k,) float
        mm.
    """
    def exact(s: np.ndarray) -> np.ndarray:
        pose = start + (end - start) * s[..., None]
        return joints(pose[..., :3].reshape(-1, 3), pose[..., 3].ravel(), pose[..., 4].ravel(),
                      geometry).reshape(*s.shape, 5)

    j0, j1 = exact(s0), exact(s1)
    w = CHECK_POINTS[None, :, None]
    lerp = j0[:, None, :] + (j1 - j0)[:, None, :] * w
    tip = inverse(lerp[..., :3], lerp[..., 3], lerp[..., 4], geometry)
    s = s0[:, None] + (s1 - s0)[:, None] * CHECK_POINTS[None, :]
    wanted = start[:3] + (end[:3] - start[:3]) * s[..., None]
    return np.linalg.norm(tip - wanted, axis=-1).max(axis=1)


def linearize_move(p0: ArrayLike, p1: ArrayLike, a0: float, c0: float, a1: float, c1: float,
                   geometry: MachineGeometry, tol: float = 0.01) -> np.ndarray:
    """Joint-space waypoints of a straight platform-frame move while A/C change.

    Parameters
    ----------
    p0, p1 : (3,) float
        Start and end of the move in the platform frame, mm.
    a0, c0, a1, c1 : float
        Table angles at the start and the end, degrees.
    geometry : MachineGeometry
    tol : float
        Largest allowed tip deviation from the straight line, mm.

    Returns
    -------
    (k, 5) float
        [X, Y, Z, A, C] waypoints including both ends (k ≥ 2); consecutive waypoints are
        meant to be joined by linear joint moves.
    """
    start = np.concatenate([np.asarray(p0, float).reshape(3), [a0, c0]])
    end = np.concatenate([np.asarray(p1, float).reshape(3), [a1, c1]])
    bounds = np.array([0.0, 1.0])
    if a0 != a1 or c0 != c1:
        bounds = _refine(bounds, start, end, geometry, tol)
    pose = start + (end - start) * bounds[:, None]
    return joints(pose[:, :3], pose[:, 3], pose[:, 4], geometry)


def _refine(bounds: np.ndarray, start: np.ndarray, end: np.ndarray,
            geometry: MachineGeometry, tol: float) -> np.ndarray:
    for _ in range(MAX_DEPTH):
        bad = deviation(bounds[:-1], bounds[1:], start, end, geometry) > tol
        if not bad.any():
            return bounds
        mids = 0.5 * (bounds[:-1] + bounds[1:])[bad]
        bounds = np.sort(np.concatenate([bounds, mids]))
    raise KinematicsError(f"move {start.tolist()} -> {end.tolist()} cannot be linearised "
                          f"to {tol} mm in {MAX_DEPTH} halvings")
