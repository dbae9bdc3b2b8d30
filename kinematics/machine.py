"""Geometry of the tilting-rotary table (LinuxCNC ``xyzac-trt`` convention).

For a point ``p`` in the platform frame (origin at the table centre on its surface, z along the
C axis) the nozzle position in machine coordinates is::

    m = Rx(A) · (Rz(C) · p + t − q) + q

with ``t = table_origin`` (machine position of the platform origin at A = C = 0) and
``q = a_pivot`` (a point on the A axis, which is parallel to machine X).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

ANGLE_EPS = 1e-9  # radians-free tolerance for "the same angle", degrees
SINGULAR_EPS = 1e-9  # |horizontal part| of a unit direction below which C is free


@dataclass(frozen=True)
class MachineGeometry:
    """Where the rotary table sits and how far it turns.

    Parameters
    ----------
    table_origin : (3,) float
        Machine position of the platform origin at A = C = 0, mm.
    a_pivot : (3,) float
        A point on the A axis (parallel to machine X), mm.
    a_limits : (2,) float
        Tilt range [min, max], degrees.
    c_limits : (2,) float or None
        Rotation range [min, max], degrees; ``None`` for a continuous C axis.
    """

    table_origin: tuple[float, float, float] = (250.0, 250.0, 100.0)
    a_pivot: tuple[float, float, float] = (250.0, 250.0, 80.0)
    a_limits: tuple[float, float] = (-90.0, 90.0)
    c_limits: tuple[float, float] | None = None

    @property
    def t(self) -> np.ndarray:
        """``table_origin`` as a (3,) float array."""
        return np.asarray(self.table_origin, dtype=float)

    @property
    def q(self) -> np.ndarray:
        """``a_pivot`` as a (3,) float array."""
        return np.asarray(self.a_pivot, dtype=float)

    def header(self) -> dict[str, object]:
        """The ``;HOSTD_KINEMATICS`` header payload that lets any tool replay a file."""
        return {"type": "xyzac-trt", "table_origin": list(self.table_origin),
                "a_pivot": list(self.a_pivot), "a_limits": list(self.a_limits),
                "c_limits": None if self.c_limits is None else list(self.c_limits)}
