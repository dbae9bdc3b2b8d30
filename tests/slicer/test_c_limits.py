"""Build directions respect the C limits too (QA finding 6)."""

from __future__ import annotations

import numpy as np
from shared_models import MODELS

from kinematics.machine import MachineGeometry
from kinematics.orient import reachable_mask, solve_orientation
from slicer.decompose.decomposition import DecomposeSettings, decompose, nearest_reachable
from slicer.decompose.planes import Plane, unreachable_phrase, verify_base
from slicer.mesh.read import load_mesh
from slicer.printhead import Printhead

HEAD = Printhead.default()
NARROW = MachineGeometry(c_limits=(-10.0, 10.0))


def test_narrow_c_limits_give_reachable_build_directions() -> None:
    mesh, placement = load_mesh(MODELS / "pipe3.stl")
    dec = decompose(mesh, DecomposeSettings(), NARROW, HEAD, placement=placement.matrix)
    assert len(dec.subparts) >= 2  # the branches still get their own sub-parts
    for s in dec.subparts:
        _, c = solve_orientation(s.build_direction, NARROW)  # raises when unreachable
        assert -10.0 - 1e-6 <= c <= 10.0 + 1e-6


def test_nearest_reachable_honours_c_limits() -> None:
    axis = np.array([1.0, 0.0, 1.0]) / np.sqrt(2.0)  # 45° towards +X: needs C ±90°
    near = nearest_reachable(axis, NARROW.a_limits, NARROW.c_limits)
    assert reachable_mask(near[None], NARROW.a_limits, NARROW.c_limits)[0]
    assert np.degrees(np.arccos(near @ axis)) < 45.0  # nearer than straight up
    assert np.array_equal(nearest_reachable(axis, NARROW.a_limits), axis)  # continuous C


def test_unreachable_direction_names_the_config_keys_and_the_angles() -> None:
    normal = np.array([1.0, 0.0, 1.0]) / np.sqrt(2.0)
    msg = unreachable_phrase(normal, NARROW.a_limits, NARROW.c_limits)
    assert "machine.a_limits [-90, 90]" in msg and "machine.c_limits [-10, 10]" in msg
    assert "A 45.0°, C 90.0°" in msg and "A -45.0°, C -90.0°" in msg
    mesh, _ = load_mesh(MODELS / "cylinder.stl")
    problem = verify_base(mesh, Plane(np.zeros(3), normal), np.zeros((0, 3)), HEAD,
                          NARROW.a_limits, NARROW.c_limits)
    assert problem == msg
