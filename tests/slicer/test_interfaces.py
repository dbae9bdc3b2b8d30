"""Interface zones: the bounding-box shortcut skips only layers whose zone is empty."""

from __future__ import annotations

import numpy as np
import shapely

from slicer.paths import interfaces
from slicer.paths.interfaces import ChildBase, interface_zone
from slicer.paths.layers import LayerPlane
from slicer.planes2d import plane_frame

T, WIDTH = 0.2, 0.45


def _unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def _blob(rng: np.random.Generator, centre: np.ndarray, size: float) -> shapely.Geometry:
    """A random region: a few discs around ``centre`` (2D), some overlapping."""
    pts = centre + rng.normal(scale=size, size=(4, 2))
    return shapely.union_all([shapely.Point(p).buffer(size * rng.uniform(0.3, 1.0))
                              for p in pts])


def _case(rng: np.random.Generator, depth: float) -> tuple[LayerPlane, ChildBase]:
    """A layer plane and a tilted child base whose plane passes near a vertex of the layer's
    region: in half the cases within a millimetre of the band the zone is cut from (the
    shortcut's edge cases), else within ten."""
    origin = rng.uniform(-5.0, 5.0, size=3)
    frame = plane_frame(_unit(rng))
    region = _blob(rng, rng.uniform(-3.0, 3.0, size=2), rng.uniform(1.0, 6.0))
    layer = LayerPlane(0, 0.0, origin, frame, region, (origin - T * frame[2], frame[2]),
                       (T, T), 0.0)
    base_frame = plane_frame(_unit(rng))
    ring = shapely.get_coordinates(region.boundary)
    vertex = origin + ring[rng.integers(len(ring))] @ frame[:2]
    reach = 1.0 if rng.random() < 0.5 else 10.0
    offset = rng.uniform(-T - reach, depth + reach)  # the vertex is in the band: [-t, depth]
    base_origin = vertex - offset * base_frame[2] + rng.normal(size=2) @ base_frame[:2]
    section = _blob(rng, np.zeros(2), rng.uniform(1.0, 4.0))
    return layer, ChildBase(1, base_origin, base_frame, section)


def test_the_bounding_box_shortcut_gives_the_same_zones(monkeypatch) -> None:
    """Seeded random layers and bases: the zone with the shortcut is the zone without it,
    and every layer the shortcut skips has an empty zone."""
    rng = np.random.default_rng(20261202)
    depth = 3 * T
    cases = [_case(rng, depth) for _ in range(400)]
    fast = [interface_zone(layer, base, depth, T, WIDTH) for layer, base in cases]
    skipped = [interfaces._strip_misses(layer, base, -depth, T) for layer, base in cases]
    monkeypatch.setattr(interfaces, "_strip_misses", lambda *args: False)
    slow = [interface_zone(layer, base, depth, T, WIDTH) for layer, base in cases]
    assert 50 <= sum(skipped) <= 350  # both branches are exercised
    assert sum(not z.is_empty for z in slow) >= 20
    for a, b, skip in zip(fast, slow, skipped, strict=True):
        assert a.equals(b) or (a.is_empty and b.is_empty)
        assert not skip or b.is_empty
