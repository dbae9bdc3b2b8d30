"""Time and filament estimates against closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from slicer.gcode.estimate import MotionLimits, estimate_program, move_times, trapezoid_time
from slicer.gcode.program import NCOL, SUB, E, F, G

LIM = MotionLimits(max_velocity=200.0, max_accel=1000.0, max_rotary_velocity=90.0,
                   max_rotary_accel=360.0)


def _rows(poses: list[list[float]], e: list[float], feed: list[float], g: int = 1) -> np.ndarray:
    rows = np.zeros((len(poses), NCOL))
    rows[:, :5] = poses
    rows[:, E], rows[:, F], rows[:, G], rows[:, SUB] = e, feed, g, 0
    return rows


def test_single_straight_move_is_the_closed_form_trapezoid():
    # from rest to rest: accelerate to v, cruise, decelerate
    length, v, a = 100.0, 50.0, 1000.0
    expected = 2 * v / a + (length - v * v / a) / v
    start = np.array([[0.0, 0, 0, 0, 0]])
    end = np.array([[length, 0, 0, 0, 0]])
    t = move_times(start, end, np.array([v]), np.array([0.0]), np.array([0]), LIM)
    assert t[0] == pytest.approx(expected, rel=1e-12)


def test_short_move_is_triangular():
    length, a = 1.0, 1000.0
    t = trapezoid_time(np.array([length]), np.zeros(1), np.zeros(1), np.array([100.0]), a)
    assert t[0] == pytest.approx(2 * math.sqrt(length / a), rel=1e-12)


def test_feed_is_capped_by_the_machine():
    start = np.zeros((1, 5))
    end = np.array([[400.0, 0, 0, 0, 0]])
    t = move_times(start, end, np.array([1000.0]), np.zeros(1), np.zeros(1, int), LIM)
    assert t[0] == pytest.approx(2 * 200 / 1000 + (400 - 200 ** 2 / 1000) / 200)


def test_straight_junction_is_faster_than_a_corner():
    straight = _rows([[0, 0, 0, 0, 0], [10, 0, 0, 0, 0], [20, 0, 0, 0, 0]], [0, 1, 1],
                     [50, 50, 50])
    corner = _rows([[0, 0, 0, 0, 0], [10, 0, 0, 0, 0], [10, 10, 0, 0, 0]], [0, 1, 1],
                   [50, 50, 50])
    t_s = estimate_program(straight, LIM, 2.4, 1.24e-3).time_s
    t_c = estimate_program(corner, LIM, 2.4, 1.24e-3).time_s
    assert t_s < t_c
    # a full stop at the corner: two independent from-rest moves
    one = 2 * 50 / 1000 + (10 - 50 ** 2 / 1000) / 50
    assert t_c == pytest.approx(2 * one)


def test_rotary_move_uses_rotary_limits():
    start = np.zeros((1, 5))
    end = np.array([[0, 0, 0, 45.0, 0]])
    t = move_times(start, end, np.array([1000.0]), np.zeros(1), np.zeros(1, int), LIM)
    assert t[0] == pytest.approx(2 * 90 / 360 + (45 - 90 ** 2 / 360) / 90)


def test_retract_time_and_filament_counts_only_deposits():
    rows = _rows([[0, 0, 0, 0, 0], [0, 0, 0, 0, 0], [10, 0, 0, 0, 0], [10, 0, 0, 0, 0]],
                 [0.0, 1.0, 0.5, -1.0], [100, 35, 40, 35])
    est = estimate_program(rows, LIM, 2.405, 1.24e-3)
    assert est.filament_mm == pytest.approx(0.5)
    assert est.mass_g == pytest.approx(0.5 * 2.405 * 1.24e-3)
    assert est.subparts[0]["index"] == 0
    assert est.time_s > 2 * (2 * math.sqrt(1.0 / 1000))
