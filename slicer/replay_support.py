"""Support of deposited points: earlier material (or the platform) beneath along the nozzle.

Rule (issue 8): a point p with nozzle axis u is *supported* when a point q of a bead
centreline deposited in an earlier layer lies at depth ``d = (p - q)·u`` with
``0 < d ≤ 1.5 · max(t, h)`` (t the nominal layer height, h the point's own bead height: wedge
layers may be up to 1.5 t thick) and at a lateral offset ``≤ d · tan 45° + 0.1 w`` (w the
line width), or when the platform (z = 0, within its radius) lies within that depth along the
axis. Samples stand for their piece of centreline (``Samples.step``), so the spacing of the
samples along a path adds no offset. The same rule is applied to every point; wall points
(within 0.75 w of the model surface) are also reported on their own.

A point that fails the rule but lies inside the model away from its surface, with material of
the previous layer within half the sparse infill spacing (w / density) plus one line width
beneath it, *bridges over sparse infill*: reported apart, and not counted as an overhang.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from slicer.replay_kdtree import point_tree
from slicer.replay_samples import Samples

DEPTH_FACTOR = 1.5
OVERHANG_DEG = 45.0
LATERAL_SLACK = 0.1  # × line width
WALL_SLACK = 0.75  # × line width: wall points are this close to the surface
BAD_LAYER_SHARE = 0.05
NEIGHBOURS = 10


def depth_limit(s: Samples, layer_height: float) -> np.ndarray:
    """Largest depth searched beneath each sample, (n,)."""
    return DEPTH_FACTOR * np.maximum(layer_height, s.h) + 1e-6


def _check(s: Samples, top: np.ndarray, below: np.ndarray, dmax: np.ndarray,
           slack: float) -> np.ndarray:
    """Which (top, below) pairs put ``below``'s bead in the support cone of ``top``.

    The material of ``below`` is its piece of bead centreline ``q + τ · step`` (|τ| ≤ 1/2);
    the point of it tested is the one laterally nearest to ``top``'s nozzle axis.
    """
    u = s.u[top]
    rel = s.p[top] - s.p[below]
    step = s.step[below]
    flat_rel = rel - np.einsum("ij,ij->i", rel, u)[:, None] * u
    flat_step = step - np.einsum("ij,ij->i", step, u)[:, None] * u
    den = np.einsum("ij,ij->i", flat_step, flat_step)
    tau = np.clip(np.einsum("ij,ij->i", flat_rel, flat_step) / np.where(den > 0, den, 1.0),
                  -0.5, 0.5)
    rel = rel - tau[:, None] * step
    d = np.einsum("ij,ij->i", rel, u)
    lat = np.linalg.norm(rel - d[:, None] * u, axis=1)
    tan = math.tan(math.radians(OVERHANG_DEG))
    return (s.seq[below] < s.seq[top]) & (d > 0) & (d <= dmax[top]) & (lat <= d * tan + slack)


def platform_support(s: Samples, dmax: np.ndarray, radius: float, slack: float) -> np.ndarray:
    """Samples with the platform plane within reach beneath them, (n,) bool."""
    uz = s.u[:, 2]
    t = np.where(uz > 1e-9, s.p[:, 2] / np.where(uz > 1e-9, uz, 1.0), np.inf)
    foot = s.p[:, :2] - t[:, None] * s.u[:, :2]
    return (t >= -1e-6) & (t <= dmax) & (np.linalg.norm(foot, axis=1) <= radius + slack)


def strict_support(s: Samples, layer_height: float, line_width: float,
                   platform_radius: float, tree: cKDTree | None = None) -> np.ndarray:
    """The support rule for every sample, (n,) bool.

    Candidates are the ``NEIGHBOURS`` samples nearest a point one layer height beneath each
    sample along its axis (where supporting material lies); material of the same or later
    layers is farther from there, so the nearest candidates are the supporting ones.
    """
    dmax = depth_limit(s, layer_height)
    slack = LATERAL_SLACK * line_width
    ok = platform_support(s, dmax, platform_radius, slack)
    if len(s) < 2:
        return ok
    reach = float(dmax.max())
    tan = math.tan(math.radians(OVERHANG_DEG))
    r = math.hypot(reach, reach * tan + slack) + layer_height
    tree = tree or point_tree(s.p)
    todo = np.flatnonzero(~ok)
    for k in (1, min(NEIGHBOURS, len(s))):  # the nearest candidate settles most samples
        _, idx = tree.query(s.p[todo] - s.u[todo] * layer_height, k=k,
                            distance_upper_bound=r, workers=-1)
        idx = idx.reshape(len(todo), k)
        valid = idx < len(s)
        below = np.where(valid, idx, 0)
        top = np.repeat(todo[:, None], k, axis=1)
        hit = valid & _check(s, top.ravel(), below.ravel(), dmax, slack).reshape(valid.shape)
        ok[todo] = hit.any(axis=1)
        todo = todo[~ok[todo]]
    return ok


def bridged(s: Samples, candidates: np.ndarray, layer_height: float, line_width: float,
            infill_density: float) -> np.ndarray:
    """Of the ``candidates`` (bool mask), those bridging over sparse infill, (n,) bool."""
    out = np.zeros(len(s), dtype=bool)
    if infill_density <= 0 or not candidates.any():
        return out
    reach = 0.5 * line_width / infill_density + line_width
    dmax = depth_limit(s, layer_height)
    order = np.argsort(s.seq, kind="stable")
    seq_sorted = s.seq[order]
    for layer in np.unique(s.seq[candidates]):
        lo, hi = np.searchsorted(seq_sorted, [layer - 1, layer])
        if hi <= lo:
            continue
        prev = order[lo:hi]
        idx = np.flatnonzero(candidates & (s.seq == layer))
        _, near = point_tree(s.p[prev]).query(s.p[idx])
        q = prev[near]
        rel = s.p[idx] - s.p[q]
        d = np.einsum("ij,ij->i", rel, s.u[idx])
        lat = np.linalg.norm(rel - d[:, None] * s.u[idx], axis=1)
        out[idx] = (d > 0) & (d <= dmax[idx]) & (lat <= reach)
    return out


def bad_wall_layers(s: Samples, wall: np.ndarray, supported: np.ndarray) -> list[int]:
    """Layers (print order) where more than 5 % of wall points are unsupported."""
    if not wall.any():
        return []
    seq = s.seq[wall]
    n_seq = int(seq.max()) + 2
    total = np.bincount(seq + 1, minlength=n_seq)
    bad = np.bincount(seq[~supported[wall]] + 1, minlength=n_seq)
    share = bad / np.maximum(total, 1)
    return [int(k) - 1 for k in np.flatnonzero(share > BAD_LAYER_SHARE)]
