"""How steep the model's surface is where a layer's walls went unsupported, and the layer
height at which the support rule would hold it.

The rule (:mod:`~slicer.replay.support`) holds a bead whose offset from the one under it is
at most ``t · tan 45° + LATERAL_SLACK · w``; a wall overhanging θ below a layer's plane
steps ``t · tan θ`` per layer. So a wall a little steeper than 45° (a ball meeting its
stem in a ring at 52.7°, which no direction of planar layers holds all round) is held at
``t ≤ LATERAL_SLACK · w / (tan θ − 1)``, while one far steeper (a bore's arch, 75–90°)
needs layers too thin to print: thinner layers are only worth suggesting for the former.
"""

from __future__ import annotations

import math

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from slicer.replay.support import LATERAL_SLACK, OVERHANG_DEG

SURFACE_SPACING = 0.3  # mm between the surface samples that find the faces near a point
MAX_SURFACE_SAMPLES = 200_000
NEAR = 1.0  # mm around each point


def overhang_deg(points: np.ndarray, axes: np.ndarray, mesh: trimesh.Trimesh) -> float:
    """How far the model's surface around ``points`` overhangs below their layers' planes,
    degrees (0: along the layer normal, 90: facing straight down it): the steepest of the
    surface within :data:`NEAR` of any point (the plan at a thinner height need not fail
    where this one did; its steepest nearby face bounds it); nan without points.

    Parameters
    ----------
    points : (k, 3) float
        Unsupported wall samples, in ``mesh``'s frame.
    axes : (k, 3) float
        Each one's layer normal (unit).
    mesh : trimesh.Trimesh
        The model.
    """
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    if not len(p):
        return math.nan
    count = int(min(MAX_SURFACE_SAMPLES, max(1000, mesh.area / SURFACE_SPACING**2)))
    samples, faces = trimesh.sample.sample_surface(mesh, count, seed=0)
    tree = cKDTree(samples)
    near = tree.query_ball_point(p, r=NEAR)
    _, nearest = tree.query(p)
    rows = [np.asarray(n if n else [m], dtype=np.int64) for n, m in zip(near, nearest,
                                                                         strict=True)]
    owner = np.repeat(np.arange(len(p)), [len(r) for r in rows])
    n = np.asarray(mesh.face_normals, dtype=float)[faces[np.concatenate(rows)]]
    down = np.clip(-np.einsum("ij,ij->i", n, np.asarray(axes, dtype=float)[owner]), -1.0, 1.0)
    return float(np.degrees(np.arcsin(down.max())))


def held_height(angle_deg: float, line_width: float) -> float:
    """Largest layer height at which the support rule holds a wall overhanging
    ``angle_deg``, mm (inf up to 45°)."""
    return float(held_heights(np.array([angle_deg], dtype=float), line_width)[0])


def thickness_step(line_width: float) -> float:
    """How much thicker a layer may be than the one on it where a wall overhangs 45°, mm.

    Each layer's outline is its section at mid-height, so on a wall at 45° the bead of a
    layer of height ``t`` on one of ``t'`` steps out ``(t + t') / 2``, and the rule holds it
    up to ``t' + LATERAL_SLACK · w``: ``t`` may exceed ``t'`` by ``2 · LATERAL_SLACK · w``.
    Layers thinned for a steeper wall above ramp down to it by at most this much a layer
    (a thin layer on a thick one would step out over air)."""
    return 2.0 * LATERAL_SLACK * line_width


def held_heights(angles_deg: np.ndarray, line_width: float) -> np.ndarray:
    """:func:`held_height` of each of ``angles_deg`` (k,) float: (k,) float, mm (inf up to
    45°, 0 at 90°)."""
    a = np.radians(np.clip(np.asarray(angles_deg, dtype=float), 0.0, 90.0))
    excess = np.tan(a) - math.tan(math.radians(OVERHANG_DEG))
    return np.where(excess > 0.0, LATERAL_SLACK * line_width / np.maximum(excess, 1e-300),
                    math.inf)
