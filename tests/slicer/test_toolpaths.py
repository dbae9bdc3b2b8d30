"""Toolpath invariants on seeded random polygons."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from slicer.paths.toolpaths import (
    MAX_LINK,
    QUAD_SEGS,
    FillSpec,
    Path2D,
    hatch,
    layer_paths,
    mark_interface,
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
        lines = hatch(sq, W / density, angle, W, "infill", link=False)
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

    def lines(paths: list[Path2D]) -> np.ndarray:
        """Unit directions of the fill lines (steps longer than connectors and wall pieces)."""
        steps = np.concatenate([np.diff(p.xy, axis=0) for p in paths if p.kind == "interface"])
        steps = steps[np.linalg.norm(steps, axis=1) > 2 * W]
        return steps / np.linalg.norm(steps, axis=1, keepdims=True)

    de, do = lines(even), lines(odd)
    assert len(de) and len(do)
    assert np.abs(de @ do.T).max() < 1e-6  # perpendicular on the next layer


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


def _hatch_length(domain: shapely.Geometry, spacing: float, angle: float) -> float:
    """Total length of the unlinked hatch lines."""
    return sum(float(np.linalg.norm(p.xy[-1] - p.xy[0]))
               for p in hatch(domain, spacing, angle, W, "solid", link=False))


@pytest.mark.parametrize("seed", range(8))
def test_zigzag_links_lines_inside_the_domain(seed: int) -> None:
    rng = np.random.default_rng(seed)
    square = shapely.box(-15, -15, 15, 15)
    annulus = shapely.Point(0, 0).buffer(15, 64).difference(shapely.Point(0, 0).buffer(6, 64))
    domain = [square, annulus, _random_polygon(seed)][seed % 3]
    spacing, angle = float(rng.uniform(W, 5 * W)), float(rng.uniform(0, 180))
    lines = hatch(domain, spacing, angle, W, "solid", link=False)
    zigzag = hatch(domain, spacing, angle, W, "solid")
    most = [1, 4, max(2, len(lines) // 3)][seed % 3]  # square: one chain; annulus: 2 sides
    assert len(zigzag) <= most < len(lines)  # a handful of chains, not one per line
    room = domain.buffer(1e-6)
    for p in zigzag:
        assert p.kind == "solid" and not p.closed
        assert room.contains(shapely.LineString(p.xy))
    # every line, plus one connector per link, each at least one spacing (the next row) and at
    # most MAX_LINK spacings long
    total = sum(shapely.LineString(p.xy).length for p in zigzag)
    base, links = _hatch_length(domain, spacing, angle), len(lines) - len(zigzag)
    assert base + links * spacing - 1e-6 <= total <= base + links * MAX_LINK * spacing + 1e-6
    d = np.radians(angle)
    across = np.concatenate([p.xy for p in zigzag]) @ np.array([-np.sin(d), np.cos(d)])
    assert np.all(np.diff(np.sort(across)) >= -1e-9)
    rows = np.unique(np.round(np.concatenate([p.xy[[0, -1]] for p in lines])
                              @ np.array([-np.sin(d), np.cos(d)]), 6))
    for p in zigzag:  # rows are visited in order, one after the other
        r = np.round(p.xy @ np.array([-np.sin(d), np.cos(d)]), 6)
        on = r[np.isin(r, rows)]
        steps = np.diff(np.searchsorted(rows, on))
        assert set(steps.tolist()) <= {0, 1}


def test_zigzag_breaks_where_the_connector_would_leave() -> None:
    comb = shapely.box(0, 0, 20, 2).union(shapely.box(0, 0, 2, 20)).union(shapely.box(18, 0, 20,
                                                                                       20))
    paths = hatch(comb, W, 0.0, W, "solid")
    room = comb.buffer(1e-6)
    assert all(room.contains(shapely.LineString(p.xy)) for p in paths)
    assert len(paths) >= 2  # the two prongs above the base are separate chains


def test_interface_marks_wall_pieces_in_the_zone() -> None:
    ring = shapely.Point(0, 0).buffer(10, 64).difference(shapely.Point(0, 0).buffer(8, 64))
    zone = ring.intersection(shapely.box(0, -3, 20, 3))
    paths = layer_paths(ring, zone, zone, SPEC, 0)
    iface = [p for p in paths if p.kind == "interface"]
    assert iface and all(not p.closed for p in iface)
    beads = shapely.union_all([_segments([p]).buffer(0.5 * p.width) for p in iface])
    assert beads.intersection(zone).area >= 0.95 * zone.area
    far = shapely.box(-20, -20, -1, 20)  # nothing on the other side of the ring is marked
    assert not any(far.intersects(shapely.LineString(p.xy)) for p in iface)
    # the pieces of each loop follow each other: every piece starts where the previous ended
    walls = [p for p in paths if p.kind in ("perimeter", "interface")]
    ends = np.array([p.xy[-1] for p in walls[:-1] if not p.closed])
    assert len(ends)
    plain = mark_interface([Path2D("perimeter", np.array([[0.0, 0], [1, 0], [1, 1]]), True, W)],
                           shapely.Polygon(), W)
    assert plain[0].closed and plain[0].kind == "perimeter"
