"""Every path of a plan as one run of vertices: filament per segment and joint poses.

The G-code writer (:mod:`slicer.gcode.writer`) needs, per path vertex, the filament of the segment
ending there and the machine position at the layer's table angles. Both are computed for the
whole plan at once here instead of per path.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from kinematics.machine import MachineGeometry
from kinematics.transform import rx, rz
from slicer.plan import Layer, Path


@dataclass(frozen=True)
class Extrusions:
    """Paths as one run of print-order vertices (closed paths return to their start).

    Attributes
    ----------
    points : (N, 3) float
        Vertices of every path, path after path.
    e : (N,) float
        mm of filament of the segment ending at each vertex (0 at a path's first vertex).
    start : (P + 1,) int
        Path j's vertices are ``start[j]:start[j + 1]``.
    """

    points: np.ndarray
    e: np.ndarray
    start: np.ndarray

    @classmethod
    def of(cls, paths: Sequence[Path], area: float) -> Extrusions:
        """``E = w · (h0 + h1)/2 · L · flow / area`` per segment, for all paths at once."""
        raw = [np.asarray(p.points, dtype=float).reshape(-1, 3) for p in paths]
        n = np.array([len(r) for r in raw], dtype=np.int64)
        if not n.sum():
            return cls(np.zeros((0, 3)), np.zeros(0), np.zeros(len(paths) + 1, dtype=np.int64))
        h = np.concatenate([np.broadcast_to(np.asarray(p.height, dtype=float), (len(r),))
                            for p, r in zip(paths, raw, strict=True)])
        close = np.array([p.closed for p in paths]) & (n > 2)
        m = n + close
        start, first = np.r_[0, np.cumsum(m)], np.r_[0, np.cumsum(n)]
        idx = np.arange(start[-1]) - np.repeat(start[:-1] - first[:-1], m)
        idx[start[1:][close] - 1] = first[:-1][close]
        pts, h = np.concatenate(raw)[idx], h[idx]
        length = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        w = np.repeat([p.width for p in paths], m)[1:]
        flow = np.repeat([p.flow for p in paths], m)[1:]
        e = np.r_[0.0, w * 0.5 * (h[:-1] + h[1:]) * length * flow / area]
        e[start[:-1][m > 0]] = 0.0
        return cls(pts, e, start)


def _turn(rot: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``rot @ p`` per row of p (n, 3), summed term by term in the order of
    :func:`kinematics.transform.forward`'s einsum (bit-identical to it)."""
    return np.column_stack([(rot[i, 0] * p[:, 0] + rot[i, 1] * p[:, 1]) + rot[i, 2] * p[:, 2]
                            for i in range(3)])


def forward_at(points: np.ndarray, a: float, c: float, geometry: MachineGeometry) -> np.ndarray:
    """:func:`kinematics.transform.forward` of points (n, 3) at one pose (A, C), (n, 3).

    The same numbers, without one rotation matrix per point:
    ``m = Rx(A) (Rz(C) p + t − q) + q``.
    """
    turned = _turn(rz(c), points) + geometry.t - geometry.q
    return _turn(rx(a), turned) + geometry.q


def joint_poses(ext: Extrusions, layers: Sequence[Layer], geometry: MachineGeometry
                ) -> np.ndarray:
    """Joint pose [X, Y, Z, A, C] of every vertex of ``ext`` at its layer's angles, (N, 5).

    ``ext`` holds the paths of ``layers`` in order.
    """
    first_path = np.r_[0, np.cumsum([len(la.paths) for la in layers], dtype=np.int64)]
    bounds = ext.start[first_path]
    out = np.empty((len(ext.points), 5))
    for la, lo, hi in zip(layers, bounds[:-1], bounds[1:], strict=True):
        if hi > lo:
            out[lo:hi, :3] = forward_at(ext.points[lo:hi], la.a, la.c, geometry)
            out[lo:hi, 3], out[lo:hi, 4] = la.a, la.c
    return out
