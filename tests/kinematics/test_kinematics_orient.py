from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from kinematics.errors import UnreachableDirection
from kinematics.machine import MachineGeometry
from kinematics.orient import (
    nearest_reachable_direction,
    needed_pose,
    orientation_solutions,
    pose_of,
    reachable_mask,
    solve_orientation,
    solve_path,
)
from kinematics.transform import machine_direction

GEOM = MachineGeometry()
unit = st.tuples(*(st.floats(-1, 1, allow_nan=False),) * 3).filter(
    lambda v: 0.05 < math.sqrt(sum(x * x for x in v)))


def _unit(v: tuple[float, float, float]) -> np.ndarray:
    d = np.asarray(v, dtype=float)
    return d / np.linalg.norm(d)


@settings(max_examples=300, deadline=None)
@given(unit, st.floats(-1000, 1000, allow_nan=False))
def test_solution_makes_direction_vertical(v: tuple, current_c: float) -> None:
    d = _unit(v)
    assume(d[2] >= 0.0)
    a, c = solve_orientation(d, GEOM, current_c)
    assert np.allclose(machine_direction(d, a, c), [0, 0, 1], atol=1e-9)
    assert GEOM.a_limits[0] - 1e-9 <= a <= GEOM.a_limits[1] + 1e-9


@settings(max_examples=300, deadline=None)
@given(unit)
def test_both_solutions_are_exact(v: tuple) -> None:
    d = _unit(v)
    sols = orientation_solutions(d)
    assume(sols is not None)
    for a, c in sols:
        assert np.allclose(machine_direction(d, a, c), [0, 0, 1], atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(unit, st.floats(-1000, 1000, allow_nan=False))
def test_choice_is_nearest_current_c_never_a_needless_unwind(v: tuple, cur: float) -> None:
    d = _unit(v)
    assume(d[2] >= 0.0 and orientation_solutions(d) is not None)
    _, c = solve_orientation(d, GEOM, cur)
    assert abs(c - cur) <= 180.0 + 1e-9
    for a2, c2 in orientation_solutions(d):  # every in-limit alternative is no nearer
        if GEOM.a_limits[0] <= a2 <= GEOM.a_limits[1]:
            alt = c2 + 360.0 * round((cur - c2) / 360.0)
            assert abs(c - cur) <= abs(alt - cur) + 1e-9


def test_singularity_keeps_current_c() -> None:
    assert solve_orientation([0, 0, 1], GEOM, 137.5) == (0.0, 137.5)
    assert solve_orientation([0, 0, 5], GEOM, -20.0) == (0.0, -20.0)


def test_direction_pointing_down_is_unreachable_with_a_clear_message() -> None:
    with pytest.raises(UnreachableDirection, match=r"A limits \[-90, 90\]"):
        solve_orientation([0.3, 0.0, -0.8], GEOM)
    with pytest.raises(UnreachableDirection, match="outside"):
        solve_orientation([0, 0, -1], GEOM)


def test_narrow_a_limits_pick_the_solution_inside() -> None:
    g = MachineGeometry(a_limits=(-10.0, 60.0))
    d = _unit((0.5, 0.2, 0.7))
    a, c = solve_orientation(d, g, current_c=-100.0)
    assert 0 < a <= 60
    assert np.allclose(machine_direction(d, a, c), [0, 0, 1], atol=1e-9)
    with pytest.raises(UnreachableDirection):
        solve_orientation(_unit((1.0, 0.0, 0.2)), g)  # needs 78.5° of tilt


def test_limited_c_axis_stays_within_limits() -> None:
    g = MachineGeometry(c_limits=(0.0, 90.0))
    d = _unit((0.0, -1.0, 1.0))  # azimuth -90°: C = 180 (A>0) or 0 (A<0)
    a, c = solve_orientation(d, g, current_c=80.0)
    assert 0.0 <= c <= 90.0 and a < 0
    assert np.allclose(machine_direction(d, a, c), [0, 0, 1], atol=1e-9)


def _solvable(d: np.ndarray, g: MachineGeometry) -> bool:
    try:
        solve_orientation(d, g)
    except UnreachableDirection:
        return False
    return True


def test_reachable_mask_matches_solver() -> None:
    rng = np.random.default_rng(7)
    dirs = rng.normal(size=(400, 3))
    g = MachineGeometry(a_limits=(-30.0, 75.0))
    mask = reachable_mask(dirs, g.a_limits)
    assert [_solvable(d, g) for d in dirs] == mask.tolist()


@pytest.mark.parametrize("c_limits", [(-10.0, 10.0), (170.0, 200.0), (-400.0, -350.0)])
def test_reachable_mask_with_c_limits_matches_solver(c_limits) -> None:
    rng = np.random.default_rng(8)
    dirs = np.concatenate([rng.normal(size=(600, 3)), [[0, 0, 1], [0, 0, -1], [0, 1, 1]]])
    g = MachineGeometry(a_limits=(-60.0, 90.0), c_limits=c_limits)
    mask = reachable_mask(dirs, g.a_limits, g.c_limits)
    assert [_solvable(d, g) for d in dirs] == mask.tolist()
    assert 0 < mask.sum() < reachable_mask(dirs, g.a_limits).sum()


def test_nearest_reachable_direction_respects_both_limits() -> None:
    rng = np.random.default_rng(9)
    lims = ((-90.0, 90.0), (-10.0, 10.0))
    grid = pose_of(*np.meshgrid(np.linspace(-90, 90, 721), np.linspace(-10, 10, 161),
                                indexing="ij")).reshape(-1, 3)
    for d in rng.normal(size=(40, 3)):
        d /= np.linalg.norm(d)
        near = nearest_reachable_direction(d, *lims)
        assert near is not None and reachable_mask(near[None], *lims)[0]
        # no reachable direction on a fine grid is nearer (to grid resolution)
        assert near @ d >= (grid @ d).max() - 1e-5
    assert nearest_reachable_direction([1.0, 0.0, 1.0], (10.0, 20.0), (5.0, 4.0)) is None


def test_pose_of_inverts_the_solutions_and_needed_pose_names_them() -> None:
    d = _unit((1.0, 0.0, 1.0))
    for a, c in orientation_solutions(d) or ():
        assert np.allclose(pose_of(a, c), d, atol=1e-12)
    assert needed_pose(d) == "A 45.0°, C 90.0° (or A -45.0°, C -90.0°)"


def test_path_follows_c_continuously_through_full_turns() -> None:
    t = np.linspace(0, 4 * np.pi, 200)
    dirs = np.column_stack([np.cos(t), np.sin(t), np.ones_like(t)])
    poses = solve_path(dirs, GEOM)
    assert np.all(np.abs(np.diff(poses[:, 1])) < 10.0)  # no jump, continuous C
    assert abs(poses[-1, 1] - poses[0, 1]) > 700.0  # two full turns accumulated
