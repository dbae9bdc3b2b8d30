"""Transitions between sub-parts: safe height over the whole turn, exact approach pose."""

from __future__ import annotations

import numpy as np
import pytest

from kinematics.machine import MachineGeometry
from kinematics.transform import forward
from slicer.gcode.transitions import (
    PLATFORM_MARGIN,
    obstacle_hull,
    plan_transition,
    platform_rim,
    sweep_max_z,
)

GEO = MachineGeometry()
RNG = np.random.default_rng(3)
PART = RNG.uniform([-20, -20, 0], [20, 20, 60], (400, 3))


def _dense_max(points: np.ndarray, a0: float, c0: float, a1: float, c1: float) -> float:
    s = np.linspace(0, 1, 1201)
    z = forward(points[None], (a0 + (a1 - a0) * s)[:, None], (c0 + (c1 - c0) * s)[:, None],
                GEO)[..., 2]
    return float(z.max())


@pytest.mark.parametrize(("a0", "c0", "a1", "c1"), [(0, 0, 45, 30), (45, 30, -60, 200),
                                                    (-90, 0, 90, 0)])
def test_sweep_bound_is_never_below_the_dense_maximum(a0, c0, a1, c1):
    hull = obstacle_hull(PART)
    bound = sweep_max_z(hull, a0, c0, a1, c1, GEO)
    exact = _dense_max(PART, a0, c0, a1, c1)
    assert bound >= exact - 1e-9
    assert bound - exact < 0.05


def test_transition_lifts_turns_travels_and_descends():
    hull, rim = obstacle_hull(PART), platform_rim(150.0)
    start = np.array([260.0, 250.0, 140.0, 0.0, 0.0])
    point = np.array([5.0, -3.0, 30.0])
    tr = plan_transition(start, point, 45.0, 30.0, hull, rim, GEO, 60.0, 0.4)
    lift, turn, travel, _ = tr.poses
    assert np.allclose(lift[[0, 1, 3, 4]], start[[0, 1, 3, 4]]) and lift[2] == tr.safe_z
    assert np.allclose(turn[:3], lift[:3]) and np.allclose(turn[3:], [45.0, 30.0])
    assert travel[2] == tr.safe_z and np.allclose(travel[3:], turn[3:])
    above = forward(point, 45.0, 30.0, GEO) + np.array([0.0, 0.0, 0.4])
    assert np.allclose(tr.target[:3], above) and np.allclose(tr.target[3:], [45.0, 30.0])
    assert tr.safe_z >= _dense_max(PART, 0, 0, 45, 30) + 60.0 - 1e-6
    assert tr.safe_z >= _dense_max(platform_rim(150.0), 0, 0, 45, 30) + PLATFORM_MARGIN - 1e-6
    assert list(tr.rotary) == [False, True, False, False]


def test_first_transition_keeps_unknown_xy():
    tr = plan_transition(None, np.zeros(3), 0.0, 0.0, obstacle_hull(PART), platform_rim(150.0),
                         GEO, 60.0, 0.4)
    assert np.isnan(tr.poses[0, :2]).all() and np.isfinite(tr.target).all()
