"""Evasive leaning (slicer.paths.evade): a sub-part the head cannot finish along its skeleton
is marched again with its layers leaning away from what is in the way."""

from __future__ import annotations

from types import SimpleNamespace

import manifold3d as m3
import numpy as np
import pytest
import trimesh
from handmade_plans import two_part_decomposition

from kinematics.machine import MachineGeometry
from slicer.paths import evade, planner
from slicer.paths.layers import SlicingError
from slicer.paths.planner import plan_print
from slicer.paths.skeleton import fit_curve
from slicer.printhead import Printhead
from slicer.settings import ProcessSettings

S = ProcessSettings()
G = MachineGeometry()
HEAD = Printhead.default()


@pytest.mark.parametrize("seed", range(5))
def test_tilted_directions_are_unit_and_the_asked_angle_off_the_tangent(seed: int) -> None:
    rng = np.random.default_rng(seed)
    curve = fit_curve(np.cumsum(rng.normal(size=(12, 3)) + np.array([0.0, 0.0, 3.0]), axis=0))
    away = rng.normal(size=3)
    deg = float(rng.uniform(5.0, 40.0))
    s = np.linspace(0.0, curve.length, 50)
    d, tau = evade.tilted(curve, away, deg)(s), curve.tangent(s)
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0)
    angle = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", d, tau), -1.0, 1.0)))
    side = away - (tau @ away)[:, None] * tau  # the part of away square to the tangent
    ok = np.linalg.norm(side, axis=1) > 1e-3
    assert np.allclose(angle[ok], deg, atol=1e-6)
    # the lean lies in the plane of the tangent and that part, on its side
    lean = d - np.einsum("ij,ij->i", d, tau)[:, None] * tau
    assert (np.einsum("ij,ij->i", lean[ok], side[ok]) > 0).all()
    assert np.allclose(np.cross(lean[ok], side[ok]), 0.0, atol=1e-9)


def test_a_tilt_along_the_tangent_keeps_the_tangent() -> None:
    curve = fit_curve(np.column_stack([np.zeros(10), np.zeros(10), np.arange(10.0)]))
    d = evade.tilted(curve, np.array([0.0, 0.0, 1.0]), 30.0)(np.array([1.0, 4.0]))
    assert np.allclose(d, [[0.0, 0.0, 1.0]] * 2)


def test_away_points_from_the_material_above_the_base_to_the_sub_part() -> None:
    rod = trimesh.creation.cylinder(radius=4.0, height=20.0)
    rod.apply_translation((0.0, 0.0, 10.0))  # base on z = 0
    base = (np.zeros(3), np.array([0.0, 0.0, 1.0]))
    wall = np.array([[x, y, z] for x in (-14.0,) for y in np.linspace(-5, 5, 6)
                     for z in np.linspace(2.0, 30.0, 8)])
    floor = np.array([[x, y, -0.5] for x in np.linspace(-20, 20, 9)
                      for y in np.linspace(-20, 20, 9)])  # under the base: never in the way
    away = evade.away_from_obstacles(rod, base, np.vstack([wall, floor]), HEAD.reach)
    assert away is not None and np.isclose(np.linalg.norm(away), 1.0)
    assert away[0] > 0.9  # from the wall at x = -14 towards the rod
    assert evade.away_from_obstacles(rod, base, floor, HEAD.reach) is None
    far = wall + np.array([200.0, 0.0, 0.0])
    assert evade.away_from_obstacles(rod, base, far, HEAD.reach) is None


def test_candidates_try_away_from_the_obstacle_named_first() -> None:
    rod = trimesh.creation.cylinder(radius=4.0, height=20.0)
    rod.apply_translation((0.0, 0.0, 10.0))
    base = (np.zeros(3), np.array([0.0, 0.0, 1.0]))
    wall = np.array([[-14.0, y, z] for y in (-3.0, 0.0, 3.0) for z in (5.0, 15.0, 25.0)])
    part = evade.candidates("printed part", rod, base, wall, HEAD.reach)
    flat = evade.candidates("platform", rod, base, wall, HEAD.reach)
    assert [deg for _, deg in part] == [*evade.TILTS, *evade.TILTS]
    assert part[0][0][0] > 0.9 and np.allclose(part[-1][0], evade.UP)
    assert np.allclose(flat[0][0], evade.UP) and flat[-1][0][0] > 0.9
    assert [deg for _, deg in evade.candidates("platform", rod, base, wall[:0], HEAD.reach)
            ] == list(evade.TILTS)  # nothing printed: up only


def _pillar_scene(pillar_x: float) -> SimpleNamespace:
    """A disc with a stump R8 × 20 and a pillar R3 × 60 at x = ``pillar_x``; on the stump a
    rod R5 leaning 30° towards the pillar: turning its layers towards the rod's axis swings
    the head's carriage into the pillar."""
    tilt = np.radians(30.0)
    root = (m3.Manifold.cylinder(3.0, 34.0, 34.0, 64)
            + m3.Manifold.cylinder(20.0, 8.0, 8.0, 48)
            + m3.Manifold.cylinder(60.0, 3.0, 3.0, 24).translate((pillar_x, 0.0, 0.0)))
    mat = np.eye(4)[:3]
    c, s = np.cos(tilt), np.sin(tilt)
    mat[:, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    rod = m3.Manifold.cylinder(20.0, 5.0, 5.0, 48).translate((0, 0, -5)).transform(mat)
    child = rod.translate((0, 0, 20.0)).trim_by_plane((0, 0, 1.0), 20.0)
    return two_part_decomposition(root, child, [0.0, 0.0, 20.0], [0.0, 0.0, 1.0])


def test_a_rod_turning_into_a_pillar_is_leaned_away_and_printed_after_the_root(
        monkeypatch: pytest.MonkeyPatch) -> None:
    scene = _pillar_scene(33.0)
    root = scene.subparts[0].mesh
    with monkeypatch.context() as m:  # the march alone: blocked, the root cut around it
        m.setattr(planner, "candidates", lambda *a, **k: [])
        try:
            plain = plan_print(scene, S, G, HEAD)
        except SlicingError as exc:
            assert "sub-part 1" in str(exc) and "printed part" in str(exc)
        else:
            assert len(plain.subparts) > 2  # only by printing the rod before the pillar's top
    plan = plan_print(scene, S, G, HEAD)
    assert [s.index for s in plan.subparts] == [0, 1]  # the root whole, then the rod
    rod = plan.subparts[1].layers
    assert len(rod) > 40
    normals = np.array([la.normal for la in rod])
    assert normals[:, 0].max() < 0.1  # never turned towards the pillar (the axis: sin 30°)
    pillar = root.vertices[root.vertices[:, 0] > 25.0]
    for la in (la for la in rod if la.paths):  # and no layer puts the head into the root
        tips = np.vstack([p.points for p in la.paths])
        assert not HEAD.collisions(pillar, tips, la.normal).any()
        assert not HEAD.collisions(root.vertices, tips, la.normal).any()
