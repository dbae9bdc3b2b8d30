"""Thinner layers for walls a little steeper than 45°: the surface's overhang where the walls
failed (slicer.replay.steepness), the height the support rule holds it at, and the
refusal that suggests it (a ball meeting its stem in a ring no lean can hold)."""

from __future__ import annotations

import math
import re

import manifold3d as m3
import numpy as np
import pytest

from kinematics.machine import MachineGeometry
from slicer.advice import SLICE_OPTIONS, THINNEST, thinner_layers
from slicer.mesh import to_trimesh
from slicer.mesh.hard_samples import hard_variant
from slicer.pipeline import UnsupportedWallsError, slice_model
from slicer.replay import held_height, overhang_deg
from slicer.replay.support import LATERAL_SLACK
from slicer.settings import ProcessSettings

W = 0.45


@pytest.mark.parametrize("angle", [45.5, 48.0, 52.7, 60.0, 75.0])
def test_the_held_height_is_where_a_layers_step_meets_the_rules_cone(angle: float) -> None:
    t = held_height(angle, W)
    assert t * math.tan(math.radians(angle)) == pytest.approx(t + LATERAL_SLACK * W)
    assert held_height(angle + 1.0, W) < t  # steeper: thinner


def test_a_wall_within_45_degrees_is_held_at_any_height() -> None:
    assert held_height(45.0, W) == math.inf and held_height(30.0, W) == math.inf


@pytest.mark.parametrize("seed", range(4))
def test_the_overhang_around_points_on_a_flaring_cone_is_its_flare(seed: int) -> None:
    rng = np.random.default_rng(seed)
    flare = float(rng.uniform(40.0, 70.0))  # degrees off the vertical, widening upwards
    h, r0 = 10.0, 5.0
    cone = to_trimesh(m3.Manifold.cylinder(h, r0, r0 + h * math.tan(math.radians(flare)), 256))
    side = np.abs(cone.face_normals[:, 2]) < 0.99
    pick = rng.choice(np.flatnonzero(side), 20)
    points = cone.triangles_center[pick]
    up = np.tile([0.0, 0.0, 1.0], (len(points), 1))
    assert overhang_deg(points, up, cone) == pytest.approx(flare, abs=0.5)
    # layers leaning with the flare see it less
    lean = math.radians(15.0)
    tilted = np.tile([math.sin(lean), 0.0, math.cos(lean)], (len(points), 1))
    assert overhang_deg(points, tilted, cone) <= flare + 15.0 + 0.5


def test_no_thinner_layer_is_suggested_where_none_worth_printing_holds() -> None:
    assert thinner_layers(80.0, 0.2, W) is None  # under THINNEST
    assert thinner_layers(40.0, 0.2, W) is None  # held already
    assert thinner_layers(math.nan, 0.2, W) is None
    assert thinner_layers(50.0, 0.1, W) is None  # held at 0.23: not thinner than 0.1
    got = thinner_layers(52.7, 0.2, W)
    assert got is not None and THINNEST <= got[0] < 0.2
    assert got[0] <= held_height(52.7, W) < got[0] + 0.01  # rounded down to 0.01 mm


def test_a_ball_on_its_stem_is_refused_with_a_layer_height_that_then_holds_it(tmp_path
                                                                               ) -> None:
    """ball11 of the sweep (a 9.9 mm ball on a 6 mm stem: a ring overhanging 52.7° all
    round): over air at 0.2 mm whatever the lean; the refusal's layer height holds it."""
    variant = hard_variant(11)
    assert variant.name.startswith("ball")
    path = tmp_path / f"{variant.name}.stl"
    variant.mesh().export(path)
    with pytest.raises(UnsupportedWallsError) as err:
        slice_model(path, ProcessSettings(layer_height=0.2), MachineGeometry(),
                    knobs=SLICE_OPTIONS, repair_rounds=0)
    found = re.search(r"try --layer-height (\d\.\d\d) or thinner", str(err.value))
    assert found, str(err.value)
    t = float(found.group(1))
    res = slice_model(path, ProcessSettings(layer_height=t), MachineGeometry(),
                      knobs=SLICE_OPTIONS, repair_rounds=0)
    assert res.replay["unsupported_wall_layers"] == []
