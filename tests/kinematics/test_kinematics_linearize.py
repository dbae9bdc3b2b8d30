from __future__ import annotations

import itertools

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from kinematics.linearize import linearize_move
from kinematics.machine import MachineGeometry
from kinematics.transform import inverse

GEOM = MachineGeometry()
coord = st.floats(-80, 80, allow_nan=False)
ang = st.floats(-90, 90, allow_nan=False)


def _worst_deviation(wps: np.ndarray, p0: np.ndarray, p1: np.ndarray) -> float:
    """Dense check, independent of the implementation's own sample points."""
    s = np.linspace(0, 1, 101)
    worst = 0.0
    seg = p1 - p0
    for j0, j1 in itertools.pairwise(wps):
        lerp = j0 + (j1 - j0) * s[:, None]
        tip = inverse(lerp[:, :3], lerp[:, 3], lerp[:, 4], GEOM)
        # distance from the straight platform-frame segment
        u = np.clip((tip - p0) @ seg / max(seg @ seg, 1e-12), 0, 1)
        dist = np.linalg.norm(tip - (p0 + u[:, None] * seg), axis=1)
        worst = max(worst, float(dist.max()))
    return worst


@settings(max_examples=60, deadline=None)
@given(st.tuples(coord, coord, st.floats(0, 80)), st.tuples(coord, coord, st.floats(0, 80)),
       ang, ang, st.floats(-360, 360), st.floats(-360, 360),
       st.sampled_from([0.005, 0.01, 0.1]))
def test_tip_stays_within_tolerance_of_the_straight_line(p0, p1, a0, a1, c0, c1, tol) -> None:
    p0, p1 = np.asarray(p0), np.asarray(p1)
    wps = linearize_move(p0, p1, a0, c0, a1, c1, GEOM, tol)
    assert np.allclose(inverse(wps[0, :3], a0, c0, GEOM), p0, atol=1e-9)
    assert np.allclose(inverse(wps[-1, :3], a1, c1, GEOM), p1, atol=1e-9)
    assert np.all(np.diff(wps[:, 3]) * np.sign(a1 - a0) >= -1e-12)  # A moves monotonically
    assert _worst_deviation(wps, p0, p1) <= tol * 1.05


def test_move_without_rotation_is_not_split() -> None:
    wps = linearize_move([0, 0, 5], [40, 10, 5], 30.0, 10.0, 30.0, 10.0, GEOM)
    assert len(wps) == 2


def test_large_rotation_far_from_axis_is_split_and_tighter_tolerance_splits_more() -> None:
    args = ([60, 0, 40], [60, 0, 40], 0.0, 0.0, 80.0, 170.0, GEOM)
    coarse = linearize_move(*args, tol=0.1)
    fine = linearize_move(*args, tol=0.005)
    assert 2 < len(coarse) < len(fine)
