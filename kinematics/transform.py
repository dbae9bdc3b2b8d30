"""Forward and inverse kinematics of the tilting-rotary table, vectorised.

Angles are degrees; right-handed rotations. See :mod:`kinematics.machine` for the convention.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from kinematics.machine import MachineGeometry


def rx(a_deg: ArrayLike) -> np.ndarray:
    """Rotation matrices about X.

    Parameters
    ----------
    a_deg : (n,) float or float
        Angles in degrees.

    Returns
    -------
    (n, 3, 3) float (or (3, 3) for a scalar)
    """
    a = np.radians(np.asarray(a_deg, dtype=float))
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1),
                     np.stack([z, s, c], -1)], -2)


def rz(c_deg: ArrayLike) -> np.ndarray:
    """Rotation matrices about Z; shapes as :func:`rx`."""
    a = np.radians(np.asarray(c_deg, dtype=float))
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1),
                     np.stack([z, z, o], -1)], -2)


def table_rotation(a_deg: ArrayLike, c_deg: ArrayLike) -> np.ndarray:
    """``Rx(A) · Rz(C)``: how directions of the platform frame turn in the machine frame."""
    return rx(a_deg) @ rz(c_deg)


def _broadcast(points: ArrayLike, a_deg: ArrayLike, c_deg: ArrayLike
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    p = np.asarray(points, dtype=float)
    a = np.asarray(a_deg, dtype=float)
    c = np.asarray(c_deg, dtype=float)
    shape = np.broadcast_shapes(p.shape[:-1], a.shape, c.shape)
    return (np.broadcast_to(p, (*shape, 3)), np.broadcast_to(a, shape),
            np.broadcast_to(c, shape))


def forward(points: ArrayLike, a_deg: ArrayLike, c_deg: ArrayLike,
            geometry: MachineGeometry) -> np.ndarray:
    """Machine (nozzle) coordinates of platform-frame points at table angles A, C.

    Parameters
    ----------
    points : (..., 3) float
        Points in the platform frame, mm.
    a_deg, c_deg : (...) float
        Table angles, broadcast against ``points``.
    geometry : MachineGeometry

    Returns
    -------
    (..., 3) float
        ``m = Rx(A) (Rz(C) p + t - q) + q``.
    """
    p, a, c = _broadcast(points, a_deg, c_deg)
    turned = np.einsum("...ij,...j->...i", rz(c), p) + geometry.t - geometry.q
    return np.einsum("...ij,...j->...i", rx(a), turned) + geometry.q


def inverse(machine: ArrayLike, a_deg: ArrayLike, c_deg: ArrayLike,
            geometry: MachineGeometry) -> np.ndarray:
    """Platform-frame points under machine positions at table angles A, C.

    The exact inverse of :func:`forward`: ``p = Rz(-C) (Rx(-A) (m - q) + q - t)``.
    """
    m, a, c = _broadcast(machine, a_deg, c_deg)
    untilted = np.einsum("...ji,...j->...i", rx(a), m - geometry.q) + geometry.q - geometry.t
    return np.einsum("...ji,...j->...i", rz(c), untilted)


def machine_direction(directions: ArrayLike, a_deg: ArrayLike, c_deg: ArrayLike) -> np.ndarray:
    """Platform-frame directions expressed in the machine frame (no translation)."""
    d, a, c = _broadcast(directions, a_deg, c_deg)
    return np.einsum("...ij,...j->...i", table_rotation(a, c), d)
