"""Marched layer planes: thickness bound, continuity, sections."""

from __future__ import annotations

import manifold3d as m3
import numpy as np
import pytest
import shapely

from slicer.mesh.samples import to_trimesh
from slicer.paths.layers import (
    MarchSettings,
    SlicingError,
    fit_end,
    local_thickness,
    march_layers,
    turn_toward,
)
from slicer.paths.skeleton import fit_curve, line_curve
from slicer.planes2d import TOL, from_plane, map_between, plane_frame, section, to_plane

MS = MarchSettings(0.2, 0.5, 1.5)


def _bent_rod(radius: float = 6.0, bend: float = 25.0, deg: float = 90.0) -> m3.Manifold:
    ring = m3.CrossSection.circle(radius, 48).translate((bend, 0.0))
    mat = np.array([[-1.0, 0.0, 0.0, bend], [0.0, 0.0, 1.0, 0.0], [0.0, 1.0, 0.0, 0.0]])
    return m3.Manifold.revolve(ring, 96, deg).transform(mat)


def _arc_curve(bend: float = 25.0, deg: float = 90.0):
    th = np.radians(np.linspace(0.0, deg, 60))
    return fit_curve(np.column_stack([bend - bend * np.cos(th), 0 * th, bend * np.sin(th)]))


def test_frames_round_trip_and_map() -> None:
    f = plane_frame([0.3, -0.2, 0.9])
    assert np.allclose(f @ f.T, np.eye(3))
    o = np.array([1.0, 2.0, 3.0])
    p = np.random.default_rng(0).normal(size=(20, 3))
    assert np.allclose(from_plane(to_plane(p, o, f), o, f), p)
    sq = shapely.box(0, 0, 1, 1)
    assert map_between(sq, (o, f), (o, f)).equals_exact(sq, tolerance=1e-12)
    g = plane_frame([0, 0, 1])
    moved = map_between(sq, (o + g[2] * 5.0, g), (o, g))  # parallel planes: a pure projection
    assert moved.equals_exact(sq, tolerance=1e-12)


def test_section_of_cylinder_is_its_disc() -> None:
    solid = m3.Manifold.cylinder(10.0, 4.0, 4.0, 64)
    region = section(solid, np.array([0.0, 0.0, 5.0]), plane_frame([0, 0, 1]))
    disc = shapely.Polygon(4.0 * np.c_[np.cos(np.arange(64) * np.pi / 32),
                                       np.sin(np.arange(64) * np.pi / 32)])
    assert disc.area == pytest.approx(solid.volume() / 10.0, rel=1e-9)
    # simplified by at most the tolerance: never outside the disc, nowhere farther inside
    assert region.difference(disc).area < 1e-6  # rounding slivers of coincident edges
    assert disc.hausdorff_distance(region) <= TOL.simplify + 1e-9
    assert disc.area - region.area <= disc.length * TOL.simplify
    assert section(solid, np.array([0.0, 0.0, 11.0]), plane_frame([0, 0, 1])).is_empty


def test_straight_part_gives_parallel_layers_of_exact_thickness() -> None:
    solid = m3.Manifold.cylinder(10.0, 4.0, 4.0, 64)
    layers = list(march_layers(solid, line_curve([0, 0, 0], [0, 0, 1], 10.0), [0, 0, 0],
                               [0, 0, 1], MS))
    assert len(layers) == 50
    z = np.array([la.origin[2] for la in layers])
    assert np.allclose(z, 0.2 * np.arange(1, 51))
    assert all(la.thickness == pytest.approx((0.2, 0.2)) for la in layers)


@pytest.mark.parametrize("seed", range(6))
def test_the_last_layers_end_on_the_top_of_any_height(seed: int) -> None:
    """A height that is no multiple of t: the march's top lies on the part's top (not up to
    t/2 above or below it); the last two layers share what whole layers leave (from two
    layers up: none thinner than t/2), none thicker than t, all others t."""
    rng = np.random.default_rng(seed)
    t, height = float(rng.choice([0.2, 0.3])), float(rng.uniform(3.0, 12.0))
    solid = m3.Manifold.cylinder(height, 4.0, 4.0, 64)
    ms = MarchSettings(t, 0.5, 1.5)
    layers = list(march_layers(solid, line_curve([0, 0, 0], [0, 0, 1], height + 1.0),
                               [0, 0, 0], [0, 0, 1], ms))
    tops = np.array([la.origin[2] for la in layers])
    assert tops[-1] == pytest.approx(height, abs=1e-5)  # the cylinder's float32 top
    gaps = np.diff(np.concatenate([[0.0], tops]))
    assert np.allclose(gaps[:-2], t)
    assert np.all(gaps >= 0.5 * t - 1e-9) and np.all(gaps <= t + 1e-9)
    assert all(la.nominal == t for la in layers)  # fitted, not thinned
    assert all(la.thickness == pytest.approx((g, g)) for la, g in zip(layers, gaps, strict=True))


@pytest.mark.parametrize("end", ["tilted cut", "dome"])
def test_an_end_that_is_not_flat_keeps_whole_layers(end: str) -> None:
    """Under a tilted cut (a crescent that shrinks layer by layer) or a dome a thinner layer
    on a full one would step out over the wall: every layer stays t thick."""
    rod = m3.Manifold.cylinder(12.0, 4.0, 4.0, 64)
    if end == "tilted cut":
        solid = rod.trim_by_plane((np.sin(np.radians(20.0)), 0.0, -np.cos(np.radians(20.0))),
                                  -9.0)
    else:
        solid = rod + m3.Manifold.sphere(4.0, 64).translate((0.0, 0.0, 12.0))
    layers = list(march_layers(solid, line_curve([0, 0, 0], [0, 0, 1], 20.0), [0, 0, 0],
                               [0, 0, 1], MS))
    assert all(la.thickness == pytest.approx((0.2, 0.2)) for la in layers)
    top = solid.bounding_box()[5]
    assert top - 0.5 * 0.2 - 1e-6 <= layers[-1].origin[2] <= top + 0.5 * 0.2 + 1e-6


def test_fit_end_shares_the_last_two_layers_heights() -> None:
    below = (np.zeros(3), np.array([0.0, 0.0, 1.0]))
    top = np.array([[0.0, 0.0, -1.0], [3.0, 1.0, 0.0]])
    for h, want in ((0.9, 0.3), (0.6, 0.3), (0.5, 0.25), (0.3, 0.3), (0.15, 0.15), (0.1, 0.3)):
        pts = np.vstack([top, [[1.0, 2.0, h]]])
        assert fit_end(pts, below, 0.3) == pytest.approx(want)
    assert fit_end(np.zeros((0, 3)), below, 0.3) == 0.3


def test_bend_keeps_thickness_bounded_and_normals_continuous() -> None:
    solid = _bent_rod()
    layers = list(march_layers(solid, _arc_curve(), [0, 0, 0], [0, 0, 1], MS))
    lo = min(la.thickness[0] for la in layers)
    hi = max(la.thickness[1] for la in layers)
    assert 0.5 * 0.2 - 1e-9 <= lo and hi <= 1.5 * 0.2 + 1e-9
    n = np.array([la.normal for la in layers])
    turns = np.degrees(np.arccos(np.clip(np.sum(n[1:] * n[:-1], axis=1), -1, 1)))
    assert turns.max() < 2.0
    assert n[-1][0] > 0.95  # the planes followed the bend to +X
    for la in layers[::7]:  # measured thickness agrees with the reported range
        xy = shapely.get_coordinates(la.region)
        h = local_thickness(from_plane(xy, la.origin, la.frame), la.normal, la.below)
        assert la.thickness[0] - 1e-9 <= h.min() and h.max() <= la.thickness[1] + 1e-9


def test_turn_limit_unlimited_thickness_follows_tangent() -> None:
    """Without the thickness bound the same bend is cut by the paper's tangent planes."""
    solid, curve = _bent_rod(bend=9.0), _arc_curve(bend=9.0)
    loose = list(march_layers(solid, curve, [0, 0, 0], [0, 0, 1], MarchSettings(0.2, 0.0, 1e6)))
    tight = list(march_layers(solid, curve, [0, 0, 0], [0, 0, 1], MS))
    assert max(la.thickness[1] for la in loose) > 1.5 * 0.2  # wedges the bound prevents
    assert max(la.thickness[1] for la in tight) <= 1.5 * 0.2 + 1e-9
    assert max(la.turn for la in tight) < max(la.turn for la in loose)


def test_turn_toward_limits_angle() -> None:
    a, b = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    v, ang = turn_toward(a, b, 10.0)
    assert ang == 10.0
    assert np.degrees(np.arccos(v @ a)) == pytest.approx(10.0)
    assert np.allclose(turn_toward(a, b, 120.0)[0], b)


def test_veto_on_every_plane_raises_naming_layer_and_obstacle() -> None:
    solid = m3.Manifold.cylinder(10.0, 4.0, 4.0, 64)
    curve = line_curve([0, 0, 0], [0, 0, 1], 10.0)

    def veto(origin, frame, region):
        return "printed part" if origin[2] > 1.0 else None

    with pytest.raises(SlicingError, match=r"sub-part 3, layer 5: .*printed part"):
        list(march_layers(solid, curve, [0, 0, 0], [0, 0, 1], MS, veto, subpart=3))


def test_hollow_mesh_conversion() -> None:
    tube = m3.Manifold.cylinder(10, 5, 5, 48) - m3.Manifold.cylinder(12, 3, 3, 48).translate(
        (0, 0, -1))
    region = section(tube, np.array([0, 0, 5.0]), plane_frame([0, 0, 1]))
    assert len(region.interiors) == 1
    assert to_trimesh(tube).is_watertight
