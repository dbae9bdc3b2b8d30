"""Evasive leaning: a sub-part whose march the head cannot finish, sliced again leaning away.

Beyond the paper. A sub-part's layers follow its skeleton's tangent (paper §2.2.4), and the
march (:mod:`slicer.paths.layers`) can only turn less towards it when the head would hit the
platform or printed material. Where the obstacle stands beside the sub-part's whole course
(an elbow's stub that rises beside the tube it left, a branch low over the platform), no
amount of turning less clears it: the march stops with "no plane clears printed part".

Here such a sub-part is marched again with its layers aimed ``deg`` degrees off the tangent,
away from what is in the way: the head then stands tilted off the obstacle, and the sub-part's
walls overhang by at most ``deg`` on the side the layers lean from (within the 45° limit).
Candidates, tried in order until one marches through: away from the printed material above
the sub-part's base (:func:`away_from_obstacles`), then straight up (off the platform), each
at :data:`TILTS` degrees. The replay judges the file as always.
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from slicer.paths.layers import Direction
from slicer.paths.skeleton import SkeletonCurve

TILTS = (20.0, 35.0)  # degrees off the tangent, tried in this order (walls overhang ≤ this)
ABOVE_BASE = 1.0  # mm: obstacles this far above the base plane are what the head meets
MIN_AWAY = 1e-6  # length below which an away direction has no meaning
OBSTACLES = ("printed part", "platform")  # what a march may evade
SAME = 0.99  # cosine above which two away directions are one
UP = np.array([0.0, 0.0, 1.0])


def away_from_obstacles(mesh: trimesh.Trimesh, base: tuple[np.ndarray, np.ndarray],
                        obstacles: np.ndarray, reach: float) -> np.ndarray | None:
    """Unit direction from the printed material the head could meet to the sub-part.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The sub-part.
    base : ((3,) float, (3,) float)
        Its base plane (point, unit normal into the sub-part).
    obstacles : (n, 3) float
        Samples of the printed material.
    reach : float
        How far from the sub-part's vertices an obstacle counts (the head's reach), mm.

    Returns
    -------
    (3,) float or None
        From the mean of the obstacles within ``reach`` of the sub-part and more than
        ``ABOVE_BASE`` above its base plane, to the mean of the sub-part's vertices near
        them; None when there are none.
    """
    if not len(obstacles):
        return None
    point, normal = base
    high = obstacles[(obstacles - point) @ normal > ABOVE_BASE]
    if not len(high):
        return None
    verts = np.asarray(mesh.vertices)
    near_obstacle = cKDTree(verts).query(high, distance_upper_bound=reach)[0] < reach
    if not near_obstacle.any():
        return None
    close = high[near_obstacle]
    near_vertex = cKDTree(close).query(verts, distance_upper_bound=reach)[0] < reach
    away = verts[near_vertex].mean(axis=0) - close.mean(axis=0)
    norm = float(np.linalg.norm(away))
    return away / norm if norm > MIN_AWAY else None


def tilted(curve: SkeletonCurve, away: np.ndarray, deg: float) -> Direction:
    """Layer normals ``deg`` degrees off the curve's tangent, towards ``away`` (its part
    square to the tangent; the tangent itself where ``away`` runs along it)."""
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    away = np.asarray(away, dtype=float)

    def direction(arc: np.ndarray) -> np.ndarray:
        tau = curve.tangent(np.atleast_1d(np.asarray(arc, dtype=float)))
        side = away[None, :] - (tau @ away)[:, None] * tau
        norm = np.linalg.norm(side, axis=1, keepdims=True)
        ok = norm > MIN_AWAY
        side = np.where(ok, side / np.where(ok, norm, 1.0), 0.0)
        d = np.where(ok, c * tau + s * side, tau)
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    return direction


def candidates(obstacle: str, mesh: trimesh.Trimesh, base: tuple[np.ndarray, np.ndarray],
               obstacles: np.ndarray, reach: float) -> list[tuple[np.ndarray, float]]:
    """(away direction, tilt in degrees) to march with, in the order to try them: away
    from ``obstacle`` first (printed material, or up off the platform), then the other."""
    material = away_from_obstacles(mesh, base, obstacles, reach)
    order = (UP, material) if obstacle == "platform" else (material, UP)
    aways: list[np.ndarray] = []
    for a in order:
        if a is not None and all(float(a @ b) < SAME for b in aways):
            aways.append(a)
    return [(a, deg) for a in aways for deg in TILTS]
