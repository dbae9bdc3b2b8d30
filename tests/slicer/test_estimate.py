"""Time and filament estimates against closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from slicer.gcode.estimate import (
    MotionLimits,
    estimate_moves,
    estimate_program,
    move_times,
    trapezoid_time,
)
from slicer.gcode.program import NCOL, SUB, E, F, G
from slicer.gcode.reader import parse_lines

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


def test_moves_of_a_file_are_estimated_as_the_program():
    rng = np.random.default_rng(7)
    n = 200
    poses = np.cumsum(rng.normal(0.0, 3.0, (n, 5)), axis=0)
    poses[rng.random(n) < 0.7, 3:] = 0.0  # most moves leave the table still
    rows = _rows(poses.tolist(), rng.uniform(-0.5, 1.0, n).tolist(),
                 rng.uniform(10.0, 150.0, n).tolist())
    rows[:, G] = rng.integers(0, 2, n)
    want = estimate_program(rows, LIM, 2.405, 1.24e-3)
    start = np.vstack([np.full((1, 5), np.nan), rows[:-1, :5]])
    got = estimate_moves(start, rows[:, :5], rows[:, F], rows[:, E], rows[:, G].astype(int),
                         LIM, 2.405, 1.24e-3)
    assert got.time_s == pytest.approx(want.time_s, rel=1e-12)
    assert got.filament_mm == pytest.approx(want.filament_mm, rel=1e-12)
    assert got.mass_g == pytest.approx(want.mass_g, rel=1e-12)


def test_a_three_axis_file_with_absolute_extrusion_reads_and_estimates():
    # a file as CuraEngine writes it: M82, G92 E0 resets, extruder-only retracts, no A/C
    text = ["M82", "G92 E0", "G1 F200 E3", "G92 E0", "G0 F3600 X10 Y0 Z0.2",
            "G1 F1200 X20 Y0 E0.5", "G1 X20 Y10 E1.0", "G1 F1500 E0", "G0 F3600 X0 Y0",
            "G1 F1500 E1.0", "G1 F1200 X0 Y10 E1.5"]
    parsed = parse_lines(text)
    est = estimate_moves(parsed.start, parsed.end, parsed.feed, parsed.e, parsed.g, LIM,
                         2.405, 1.24e-3)
    assert est.filament_mm == pytest.approx(1.5)  # primes and retracts leave no bead
    travel = 2 * 60 / 1000 + (math.hypot(20, 10) - 60 ** 2 / 1000) / 60
    assert est.time_s > travel
    assert np.isfinite(est.time_s)
