"""Thinner layers where the surface overhangs a little past what the layer height holds
(slicer.paths.thin_layers): the cap of one layer, a march through a flared collar, and the
closed loop holding a ball on its stem at 0.2 mm that no lean holds; and thinner layers
through the spots where a try's walls were over air, whatever the slope (a thicker first
layer where a spot lies in a child's first layer on its parent's beads)."""

from __future__ import annotations

import math
from dataclasses import replace

import manifold3d as m3
import numpy as np
import pytest

from kinematics.machine import MachineGeometry
from slicer.advice import THINNEST
from slicer.mesh import to_trimesh
from slicer.mesh.hard_samples import hard_variant
from slicer.paths import Spots, Thinning, any_height
from slicer.paths.layers import MarchSettings, march_layers
from slicer.paths.skeleton import line_curve
from slicer.paths.thin_layers import (
    MARGIN,
    SPOT_SHARE,
    SteepFaces,
    capper,
    first_cap,
    layer_cap,
    on_plane,
    spot_cap,
)
from slicer.pipeline import slice_model
from slicer.planes2d import slicing_solid
from slicer.replay import held_height, held_heights, thickness_step
from slicer.settings import ProcessSettings

W, T = 0.45, 0.2
RULE = Thinning(lambda angles: held_heights(angles, W), THINNEST)
UP = np.array([0.0, 0.0, 1.0])


def collar(flare: float, r: float = 6.0, stem: float = 5.0, rise: float = 3.0,
           top: float = 4.0) -> m3.Manifold:
    """A stem of radius ``r``, a collar widening at ``flare`` degrees off the vertical for
    ``rise`` mm above it, and a straight cylinder on top."""
    r1 = r + rise * math.tan(math.radians(flare))
    parts = [m3.Manifold.cylinder(stem, r, r, 128),
             m3.Manifold.cylinder(rise, r, r1, 128).translate((0.0, 0.0, stem)),
             m3.Manifold.cylinder(top, r1, r1, 128).translate((0.0, 0.0, stem + rise))]
    return m3.Manifold.batch_boolean(parts, m3.OpType.Add)


@pytest.mark.parametrize("seed", range(4))
def test_a_layer_in_a_flare_the_rule_can_hold_is_capped_under_its_held_height(seed: int
                                                                               ) -> None:
    flare = float(np.random.default_rng(seed).uniform(51.5, 58.0))  # held under 0.2 mm
    surface = SteepFaces.of(to_trimesh(collar(flare)))
    z = float(np.random.default_rng(seed + 10).uniform(5.2, 7.5))  # inside the collar
    cap = layer_cap(surface, np.array([0.0, 0.0, z]), UP, T, RULE)
    assert THINNEST <= cap < T
    assert cap == pytest.approx(MARGIN * held_height(flare, W), rel=5e-3)  # a 128-gon cone
    # a layer at the held height steps exactly the rule's 45° plus its slack out per layer;
    # this one steps less, by the margin
    held = cap / MARGIN
    assert held * math.tan(math.radians(flare)) == pytest.approx(held + 0.1 * W, rel=5e-3)
    assert cap * math.tan(math.radians(flare)) < cap + 0.1 * W


@pytest.mark.parametrize(("flare", "z"), [(30.0, 6.0), (48.5, 6.0), (52.0, 2.0), (52.0, 9.5)])
def test_a_layer_the_height_already_holds_keeps_it(flare: float, z: float) -> None:
    """A flare within 45°, or past it by less than 0.2 mm layers hold with the margin (up
    to 49.0° at w = 0.45), or a layer of the stem or the top (away from the collar)."""
    assert MARGIN * held_height(48.5, W) >= T
    surface = SteepFaces.of(to_trimesh(collar(flare)))
    assert layer_cap(surface, np.array([0.0, 0.0, z]), UP, T, RULE) == T


def test_a_surface_no_printable_layer_holds_does_not_thin_the_layer() -> None:
    """The collar's underside at 80° (and a ledge at 90°) would need layers under
    THINNEST: they are left to the decomposition, the layer stays nominal."""
    surface = SteepFaces.of(to_trimesh(collar(80.0, rise=0.5)))
    assert held_height(80.0, W) < THINNEST
    assert layer_cap(surface, np.array([0.0, 0.0, 5.1]), UP, T, RULE) == T


@pytest.mark.parametrize("flare", [52.0, 56.0])
def test_a_march_thins_exactly_the_layers_of_the_collar(flare: float) -> None:
    solid = collar(flare)
    mesh = to_trimesh(solid)
    ms = MarchSettings(T, 0.5, 1.5)
    curve = line_curve(np.zeros(3), UP, 13.0)
    plain = list(march_layers(slicing_solid(mesh), curve, np.zeros(3), UP, ms))
    thin = list(march_layers(slicing_solid(mesh), curve, np.zeros(3), UP, ms,
                             thin=capper(mesh, RULE)))
    held = MARGIN * held_height(flare, W)
    tops = np.array([la.origin[2] for la in thin])
    nominal = np.array([la.nominal for la in thin])
    bottoms = tops - nominal
    in_collar = (bottoms < 8.0 - 1e-6) & (tops > 5.0 + 1e-6)
    assert np.all(nominal[in_collar] == pytest.approx(held, rel=5e-3))
    # away from the collar (a layer's slab reaching one nominal height into it excepted)
    clear = (tops < 5.0 - T) | (bottoms > 8.0)
    assert np.all(nominal[clear] == T)
    top = mesh.bounds[1, 2]  # both end on the top (their last layers fitted to it)
    assert tops[-1] == pytest.approx(top) and plain[-1].origin[2] == pytest.approx(top)
    assert len(thin) - len(plain) == pytest.approx(3.0 / held - 3.0 / T, abs=3)
    # each layer is as thick as marched: its planes stand nominal apart, but for the last
    # two, which share what is left to the top
    gaps = np.diff(np.concatenate([[0.0], tops]))
    assert np.allclose(gaps[:-2], nominal[:-2], atol=1e-6)
    assert np.all(gaps[-2:] <= nominal[-2:] + 1e-9)


def test_the_closed_loop_holds_a_ball_on_its_stem_with_thinner_layers_there(tmp_path) -> None:
    """ball11 of the sweep (a 9.9 mm ball on a 6 mm stem, a ring at 52.7° all round): no
    lean holds the ring at 0.2 mm (refused with ``repair_rounds=0``,
    test_steepness); the closed loop's try with thinner layers there does."""
    variant = hard_variant(11)
    path = tmp_path / f"{variant.name}.stl"
    variant.mesh().export(path)
    res = slice_model(path, ProcessSettings(layer_height=T, line_width=W), MachineGeometry(),
                      repair_rounds=1)
    assert res.replay["unsupported_wall_layers"] == []
    assert res.replay["wall_supported"] >= 0.998
    count, thinnest = res.thinned
    assert 0 < count < res.layers / 2  # only around the ring
    assert THINNEST <= thinnest <= MARGIN * held_height(52.7, W) + 1e-9


@pytest.mark.parametrize("flare", [52.0, 56.0])
def test_the_layers_under_a_thinned_collar_ramp_down_to_it(flare: float) -> None:
    """Over a 45° wall a layer may be ``thickness_step`` thicker than the one on it, no
    more: the march thins the layers under the collar by at most that (with the margin)
    per layer, so no thin layer lands on a thick one."""
    stem = collar(flare, stem=5.0)
    cone = m3.Manifold.cylinder(3.0, 3.0, 6.0, 128)  # a 45° flare under the stem
    solid = m3.Manifold.batch_boolean([cone, stem.translate((0.0, 0.0, 3.0))],
                                      m3.OpType.Add)
    mesh = to_trimesh(solid)
    rule = Thinning(RULE.held, THINNEST, thickness_step(W))
    layers = list(march_layers(slicing_solid(mesh), line_curve(np.zeros(3), UP, 16.0),
                               np.zeros(3), UP, MarchSettings(T, 0.5, 1.5),
                               thin=capper(mesh, rule)))
    nominal = np.array([la.nominal for la in layers])
    tops = np.array([la.origin[2] for la in layers])
    step = MARGIN * thickness_step(W)
    assert np.all(np.diff(nominal) >= -step - 1e-9)  # never thinner by more than a step
    collar_layers = (tops - nominal > 8.0) & (tops < 11.0)  # the flare from z 8 to 11
    assert np.allclose(nominal[collar_layers], MARGIN * held_height(flare, W), rtol=5e-3)
    ramp = (nominal < T) & (tops <= 8.0)
    assert ramp.sum() >= int((T - nominal.min()) / step)  # thinned on the way up to it
    assert np.all(nominal[tops < 8.0 - 3.0] == T)  # and only near it


SPOTS_ONLY = Thinning(any_height, THINNEST, thickness_step(W))


@pytest.mark.parametrize("seed", range(4))
def test_a_spot_in_the_next_layers_slab_halves_it_and_one_above_ramps_to_it(seed: int
                                                                           ) -> None:
    rng = np.random.default_rng(seed)
    t = float(rng.uniform(0.15, 0.3))
    normal = rng.normal(size=3)
    normal /= np.linalg.norm(normal)
    origin = rng.uniform(-5.0, 5.0, 3)
    side = np.cross(normal, rng.normal(size=3))  # spots anywhere across the plane
    target = SPOT_SHARE * t
    ramp = MARGIN * SPOTS_ONLY.step / t

    def at(h: float) -> np.ndarray:
        return (origin + h * normal + 7.0 * side)[None, :]

    assert spot_cap(at(0.6 * t), origin, normal, t, SPOTS_ONLY) == pytest.approx(target)
    h = t + 0.5 * (t - target) / ramp  # above the slab, half-way up the ramp's reach
    assert spot_cap(at(h), origin, normal, t, SPOTS_ONLY) == pytest.approx(
        target + ramp * (h - t))
    for far in (-0.05, t + 1.01 * (t - target) / ramp):  # below the plane, past the reach
        assert spot_cap(at(far), origin, normal, t, SPOTS_ONLY) == t
    both = np.vstack([at(0.6 * t), at(h)])  # the nearest one binds
    assert spot_cap(both, origin, normal, t, SPOTS_ONLY) == pytest.approx(target)


def test_spots_thin_only_their_own_sub_parts_layers() -> None:
    """A capper for sub-part 1 takes the spots found in sub-part 1, not those of 0; a wall
    at 45° thins no layer by its slope when only spots are asked for."""
    mesh = to_trimesh(collar(45.0))
    z = 6.0
    spots = Spots(np.array([[0.0, 6.5, z + 0.1], [0.0, -6.5, z + 0.1]]), np.array([0, 1]))
    rule = replace(SPOTS_ONLY, spots=spots)
    origin = np.array([0.0, 0.0, z])
    assert capper(mesh, rule, 1)(origin, UP, T) == pytest.approx(SPOT_SHARE * T)
    assert capper(mesh, rule, 2)(origin, UP, T) == T
    assert capper(mesh, rule)(origin, UP, T) == T  # no index: no spots
    assert capper(mesh, SPOTS_ONLY, 1)(origin, UP, T) == T


def test_a_march_thins_the_layers_through_a_spot_and_ramps_down_to_them() -> None:
    """A cylinder marched with a spot at z = 6: the layers through it are half as thick,
    those under it ramp down to them a step at most per layer, the rest stay nominal and
    the march still ends on the top."""
    mesh = to_trimesh(m3.Manifold.cylinder(12.0, 6.0, 6.0, 128))
    rule = replace(SPOTS_ONLY, spots=Spots(np.array([[5.5, 0.0, 6.0]]), np.array([0])))
    layers = list(march_layers(slicing_solid(mesh), line_curve(np.zeros(3), UP, 13.0),
                               np.zeros(3), UP, MarchSettings(T, 0.5, 1.5),
                               thin=capper(mesh, rule, 0)))
    nominal = np.array([la.nominal for la in layers])
    tops = np.array([la.origin[2] for la in layers])
    through = (tops - nominal < 6.0) & (tops >= 6.0)
    assert through.sum() == 1 and nominal[through][0] == pytest.approx(SPOT_SHARE * T)
    assert np.all(np.diff(nominal[tops <= 6.0]) >= -MARGIN * thickness_step(W) - 1e-9)
    assert np.all(nominal[(tops < 6.0 - 2.0) | (tops > 6.0 + T)][:-2] == T)
    assert tops[-1] == pytest.approx(12.0)


THICK = replace(SPOTS_ONLY, first=T + thickness_step(W))


@pytest.mark.parametrize("seed", range(4))
def test_a_spot_in_a_childs_first_layer_makes_that_layer_thicker(seed: int) -> None:
    """On the cut a child starts from, a spot within the thicker layer's slab makes the
    first layer ``Thinning.first`` thick; a spot past it or below the cut leaves it
    nominal, and off the first layer the same spot halves the layer as before."""
    rng = np.random.default_rng(seed)
    normal = rng.normal(size=3)
    normal /= np.linalg.norm(normal)
    origin = rng.uniform(-5.0, 5.0, 3)
    side = np.cross(normal, rng.normal(size=3))

    def at(h: float) -> np.ndarray:
        return (origin + h * normal + 4.0 * side)[None, :]

    surface = SteepFaces.of(to_trimesh(m3.Manifold.cylinder(1.0, 0.5, 0.5, 16)
                                       .translate((50.0, 50.0, 50.0))))  # far away
    for h in (0.5 * T, T, THICK.first):
        assert first_cap(at(h), origin, normal, T, THICK) == pytest.approx(THICK.first)
        assert layer_cap(surface, origin, normal, T, THICK, at(h), first=True) == \
            pytest.approx(THICK.first)
        assert layer_cap(surface, origin, normal, T, THICK, at(h)) < T  # not a first layer
    for h in (-0.05, THICK.first + 0.02):
        assert first_cap(at(h), origin, normal, T, THICK) == T
    assert first_cap(at(T), origin, normal, T, SPOTS_ONLY) == T  # no thicker first layer
    # a layer the slope thins stays thin: no first layer thicker over a steep face
    flare = to_trimesh(collar(55.0))
    z = 5.5
    spot = np.array([[6.2, 0.0, z + T]])
    cap = layer_cap(SteepFaces.of(flare), np.array([0.0, 0.0, z]), UP, T,
                    replace(THICK, held=RULE.held), spot, first=True)
    assert cap < T


def test_the_capper_knows_a_childs_first_layer_by_its_base_plane() -> None:
    mesh = to_trimesh(m3.Manifold.cylinder(6.0, 4.0, 4.0, 64))
    base = (np.array([0.0, 0.0, 0.0]), UP)
    rule = replace(THICK, spots=Spots(np.array([[3.5, 0.0, T]]), np.array([0])))
    assert capper(mesh, rule, 0, base)(base[0], UP, T) == pytest.approx(THICK.first)
    assert capper(mesh, rule, 0)(base[0], UP, T) == pytest.approx(SPOT_SHARE * T)  # a root
    assert on_plane(base[0] + 1e-9 * UP, UP, base)
    assert not on_plane(base[0] + 0.01 * UP, UP, base)
    tilted = np.array([0.0, 0.01, 1.0]) / np.linalg.norm([0.0, 0.01, 1.0])
    assert not on_plane(base[0], tilted, base)


def test_a_march_on_a_cut_lays_a_thick_first_layer_then_nominal_ones() -> None:
    """A child (a cylinder on a cut at z = 0) with a spot in its first layer: that layer
    is ``Thinning.first`` thick, every other nominal, and the march still ends on the
    top."""
    mesh = to_trimesh(m3.Manifold.cylinder(6.0, 4.0, 4.0, 128))
    rule = replace(THICK, spots=Spots(np.array([[3.8, 0.0, T]]), np.array([3])))
    layers = list(march_layers(slicing_solid(mesh), line_curve(np.zeros(3), UP, 7.0),
                               np.zeros(3), UP, MarchSettings(T, 0.5, 1.5),
                               thin=capper(mesh, rule, 3, (np.zeros(3), UP))))
    nominal = np.array([la.nominal for la in layers])
    assert nominal[0] == pytest.approx(THICK.first)
    assert layers[0].origin[2] == pytest.approx(THICK.first)
    assert layers[0].thickness == pytest.approx((THICK.first, THICK.first))
    assert np.all(nominal[1:-2] == T)
    assert layers[-1].origin[2] == pytest.approx(6.0)
