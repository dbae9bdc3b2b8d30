"""Toolpath invariants on seeded random polygons."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from slicer.toolpaths import (
    QUAD_SEGS,
    FillSpec,
    Path2D,
    hatch,
    layer_paths,
    order_paths,
    perimeters,
)

W = 0.45
SPEC = FillSpec(W, 2, 0.2, 45.0)


def _random_polygon(seed: int) -> shapely.Polygon:
    """A star-shaped polygon of 5–14 vertices, radius 6–15 mm, sometimes with a hole."""
    rng = np.random.default_rng(seed)
    k = int(rng.integers(5, 15))
    ang = np.sort(rng.uniform(0, 2 * np.pi, k))
    r = rng.uniform(6.0, 15.0, k)
    poly = shapely.Polygon(np.column_stack([r * np.cos(ang), r * np.sin(ang)])).buffer(0)
    if seed % 2:
        poly = poly.difference(shapely.Point(rng.uniform(-1, 1, 2)).buffer(2.5))
    return poly


def _segments(paths: list[Path2D]) -> shapely.MultiLineString:
    lines = [np.vstack([p.xy, p.xy[:1]]) if p.closed else p.xy for p in paths]
    return shapely.MultiLineString(lines)


@pytest.mark.parametrize("seed", range(12))
def test_paths_stay_inside_the_section(seed: int) -> None:
    poly = _random_polygon(seed)
    paths = layer_paths(poly, shapely.Polygon(), shapely.Polygon(), SPEC, seed)
    assert paths
    assert poly.buffer(1e-6).contains(_segments(paths))
    for p in paths:  # the whole bead stays in too
        bead = _segments([p]).buffer(0.5 * p.width * 0.999)
        assert bead.difference(poly).area < 1e-3 * max(bead.area, 1.0)


@pytest.mark.parametrize("seed", range(6))
def test_perimeter_offsets_are_exact(seed: int) -> None:
    poly = _random_polygon(seed)
    loops, inner = perimeters(poly, W, 3)
    boundary = poly.boundary
    by_offset = {}
    for p in loops:
        d = shapely.distance(shapely.points(p.xy), boundary)
        k = int(np.round(d.min() / W - 0.5))
        by_offset.setdefault(k, []).append(d)
        # GEOS simplifies offset curves by 1 % of the distance; nothing else is inexact
        assert np.allclose(d, (k + 0.5) * W, atol=0.01 * (k + 0.5) * W), (k, d.min(), d.max())
    assert set(by_offset) == {0, 1, 2}
    assert inner.area == pytest.approx(poly.buffer(-3 * W, quad_segs=QUAD_SEGS).area, rel=1e-9)


def test_infill_spacing_matches_density() -> None:
    sq = shapely.box(-20, -20, 20, 20)
    for density, angle in ((0.2, 45.0), (0.5, 0.0), (1.0, 90.0)):
        lines = hatch(sq, W / density, angle, W, "infill")
        d = np.radians(angle)
        normal = np.array([-np.sin(d), np.cos(d)])
        offsets = np.sort([p.xy[0] @ normal for p in lines])
        assert np.allclose(np.diff(offsets), W / density, atol=1e-9)
        for p in lines:  # each line runs along the fill direction
            v = p.xy[-1] - p.xy[0]
            assert abs(v @ normal) < 1e-9


def test_solid_layer_covers_the_section() -> None:
    poly = _random_polygon(3)
    paths = layer_paths(poly, poly, shapely.Polygon(), SPEC, 0)
    kinds = {p.kind for p in paths}
    assert kinds <= {"perimeter", "solid"} and "solid" in kinds
    beads = shapely.union_all([_segments([p]).buffer(0.5 * p.width) for p in paths])
    assert beads.intersection(poly).area > 0.97 * poly.area
    sparse = layer_paths(poly, shapely.Polygon(), shapely.Polygon(), SPEC, 0)
    assert sum(len(p.xy) for p in sparse) < sum(len(p.xy) for p in paths)


def test_interface_zone_gets_its_own_kind_and_alternates_direction() -> None:
    sq = shapely.box(-10, -10, 10, 10)
    zone = shapely.box(0, -10, 10, 10)
    even = layer_paths(sq, zone, zone, SPEC, 0)
    odd = layer_paths(sq, zone, zone, SPEC, 1)
    iface = [p for p in even if p.kind == "interface"]
    assert iface and all(p.xy[:, 0].min() > -W for p in iface)
    de = iface[0].xy[-1] - iface[0].xy[0]
    do = next(p for p in odd if p.kind == "interface").xy
    assert abs(de @ (do[-1] - do[0])) < 1e-6  # perpendicular on the next layer


def test_gap_fill_fills_a_thin_wall() -> None:
    ring = shapely.Point(0, 0).buffer(10, 64).difference(shapely.Point(0, 0).buffer(8, 64))
    paths = layer_paths(ring, shapely.Polygon(), shapely.Polygon(), SPEC, 0)
    deposited = sum(p.width * _segments([p]).length for p in paths)
    assert deposited == pytest.approx(ring.area, rel=0.02)


def test_order_is_nearest_neighbour() -> None:
    a = Path2D("infill", np.array([[10.0, 0], [11, 0]]), False, W)
    b = Path2D("infill", np.array([[3.0, 0], [1, 0]]), False, W)
    out = order_paths([a, b], np.zeros(2))
    assert np.allclose(out[0].xy[0], [1, 0])  # b first, reversed
    assert np.allclose(out[1].xy[0], [10, 0])
