from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from kinematics.machine import MachineGeometry
from kinematics.transform import forward, inverse, machine_direction, rx, rz

coord = st.floats(-300, 300, allow_nan=False)
angle = st.floats(-720, 720, allow_nan=False)
geometries = st.builds(
    MachineGeometry,
    table_origin=st.tuples(coord, coord, coord),
    a_pivot=st.tuples(coord, coord, coord),
)


@settings(max_examples=200, deadline=None)
@given(geometries, st.lists(st.tuples(coord, coord, coord, angle, angle), min_size=1,
                            max_size=20))
def test_inverse_undoes_forward(geometry: MachineGeometry, rows: list) -> None:
    arr = np.asarray(rows)
    p, a, c = arr[:, :3], arr[:, 3], arr[:, 4]
    m = forward(p, a, c, geometry)
    assert np.allclose(inverse(m, a, c, geometry), p, atol=1e-9)


@settings(max_examples=100, deadline=None)
@given(geometries, coord, coord, coord, angle, angle)
def test_forward_matches_the_stated_formula(geometry: MachineGeometry, x: float, y: float,
                                            z: float, a: float, c: float) -> None:
    p = np.array([x, y, z])
    t, q = np.asarray(geometry.table_origin), np.asarray(geometry.a_pivot)
    ar, cr = np.radians(a), np.radians(c)
    rot_x = np.array([[1, 0, 0], [0, np.cos(ar), -np.sin(ar)], [0, np.sin(ar), np.cos(ar)]])
    rot_z = np.array([[np.cos(cr), -np.sin(cr), 0], [np.sin(cr), np.cos(cr), 0], [0, 0, 1]])
    expected = rot_x @ (rot_z @ p + t - q) + q
    assert np.allclose(forward(p, a, c, geometry), expected, atol=1e-9)


def test_rotations_are_right_handed() -> None:
    assert np.allclose(rz(90.0) @ [1, 0, 0], [0, 1, 0])
    assert np.allclose(rx(90.0) @ [0, 1, 0], [0, 0, 1])


def test_platform_origin_sits_at_table_origin_when_level() -> None:
    g = MachineGeometry(table_origin=(10.0, 20.0, 30.0), a_pivot=(0.0, 20.0, 5.0))
    assert np.allclose(forward([0, 0, 0], 0.0, 123.0, g), [10, 20, 30])


def test_points_on_the_a_axis_do_not_move_with_a() -> None:
    g = MachineGeometry(table_origin=(0.0, 0.0, 0.0), a_pivot=(0.0, 7.0, -3.0))
    # A platform point that sits on the A axis (x arbitrary) stays put for every A.
    p = np.array([5.0, 7.0, -3.0])
    for a in (-90.0, -30.0, 45.0, 90.0):
        assert np.allclose(forward(p, a, 0.0, g), p)


def test_directions_turn_without_translation() -> None:
    d = machine_direction([0.0, 0.0, 1.0], 90.0, 0.0)
    assert np.allclose(d, [0, -1, 0])
