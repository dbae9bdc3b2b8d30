"""Bonded interfaces (issue 8.2): the parent is solid under every child's base section.

For a child with base plane (b, n_b) and base section S (in the base plane), a parent layer's
interface zone is the set of its points x with

* −D ≤ (x − b)·n_b ≤ t (at most D = ``interface_layers``·t under the base plane), and
* x projected along n_b onto the base plane inside S grown by one line width.

Both conditions are affine in the layer's 2D coordinates, so the zone is the layer region
clipped by a strip and by S mapped into the layer frame (projection along n_b). Layers whose
plane is nearly parallel to n_b (within :data:`MIN_COS`) have no interface.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
import shapely.affinity
from shapely.geometry.base import BaseGeometry

from slicer.paths.layers import LayerPlane
from slicer.planes2d import polygonal

MIN_COS = 0.2  # |n_layer · n_base| below which a layer gets no interface zone
MIN_AREA = 0.05  # interface zones smaller than this (mm²) are ignored


@dataclass(frozen=True)
class ChildBase:
    """A child's base: plane point, unit normal (into the child), frame and 2D section."""

    child: int
    origin: np.ndarray
    frame: np.ndarray
    section: BaseGeometry


def _height(layer: LayerPlane, base: ChildBase) -> tuple[float, float, float]:
    """(x − b)·n_b over the layer plane as ``d0 + gx·x + gy·y`` of its 2D coordinates:
    (gx, gy, d0)."""
    nb = base.frame[2]
    return (float(layer.frame[0] @ nb), float(layer.frame[1] @ nb),
            float((layer.origin - base.origin) @ nb))


def _strip(layer: LayerPlane, base: ChildBase, lo: float, hi: float) -> BaseGeometry:
    """Points of the layer plane (2D) with lo ≤ (x − b)·n_b ≤ hi."""
    gx, gy, d0 = _height(layer, base)
    g = np.hypot(gx, gy)
    x0, y0, x1, y1 = layer.region.bounds
    big = 2.0 * (abs(x0) + abs(x1) + abs(y0) + abs(y1)) + 10.0
    if g < 1e-12:
        return shapely.box(-big, -big, big, big) if lo <= d0 <= hi else shapely.Polygon()
    ex, ey = gx / g, gy / g  # gradient direction in the plane
    a, b = (lo - d0) / g, (hi - d0) / g  # distances along it
    corners = [(a, -big), (b, -big), (b, big), (a, big)]
    return shapely.Polygon([(p * ex - q * ey, p * ey + q * ex) for p, q in corners])


def _projected_section(layer: LayerPlane, base: ChildBase) -> BaseGeometry:
    """The base section moved along n_b onto the layer plane, in the layer's 2D frame."""
    nb, n = base.frame[2], layer.frame[2]
    cos = float(nb @ n)
    # q (base 2D) -> Q = b + q·(u_b, v_b) -> Q + λ n_b on the layer plane -> layer 2D
    m = np.zeros((2, 3))
    for k, q in enumerate(((1.0, 0.0), (0.0, 1.0), (0.0, 0.0))):
        q3 = base.origin + q[0] * base.frame[0] + q[1] * base.frame[1]
        p3 = q3 + (((layer.origin - q3) @ n) / cos) * nb - layer.origin
        m[:, k] = layer.frame[:2] @ p3
    m[:, :2] -= m[:, 2:3]
    return shapely.affinity.affine_transform(
        base.section, [m[0, 0], m[0, 1], m[1, 0], m[1, 1], m[0, 2], m[1, 2]])


def _strip_misses(layer: LayerPlane, base: ChildBase, lo: float, hi: float) -> bool:
    """Whether the layer region's bounding box lies wholly outside lo ≤ (x − b)·n_b ≤ hi (so
    the region does too): most layers of a parent are far from its children's bases."""
    gx, gy, d0 = _height(layer, base)
    x0, y0, x1, y1 = layer.region.bounds
    low = d0 + min(gx * x0, gx * x1) + min(gy * y0, gy * y1)
    high = d0 + max(gx * x0, gx * x1) + max(gy * y0, gy * y1)
    return high < lo or low > hi


def interface_zone(layer: LayerPlane, base: ChildBase, depth: float, t: float,
                   width: float) -> BaseGeometry:
    """The solid zone of a parent layer under one child's base (possibly empty)."""
    if abs(float(base.frame[2] @ layer.frame[2])) < MIN_COS or layer.region.is_empty:
        return shapely.Polygon()
    if _strip_misses(layer, base, -depth, t):
        return shapely.Polygon()
    strip = _strip(layer, base, -depth, t)
    if not strip.intersects(layer.region):
        return shapely.Polygon()
    foot = _projected_section(layer, base).buffer(width)
    zone = polygonal(layer.region.intersection(strip).intersection(foot))
    return zone if zone.area >= MIN_AREA else shapely.Polygon()


def layer_interface(layer: LayerPlane, bases: list[ChildBase], depth: float, t: float,
                    width: float) -> tuple[BaseGeometry, int | None]:
    """One parent layer's :func:`interface_zones` entry: (zone, child or None)."""
    parts = [(interface_zone(layer, b, depth, t, width), b.child) for b in bases]
    parts = [(z, c) for z, c in parts if not z.is_empty]
    if not parts:
        return shapely.Polygon(), None
    return (polygonal(shapely.union_all([z for z, _ in parts])),
            max(parts, key=lambda zc: zc[0].area)[1])


def interface_zones(layers: list[LayerPlane], bases: list[ChildBase], depth: float, t: float,
                    width: float) -> tuple[list[BaseGeometry], list[int | None]]:
    """Per parent layer: the union of its interface zones and the child it serves first.

    Returns
    -------
    zones : list of shapely geometry
    child : list of int or None
        The child of the largest zone on that layer (``Layer.interface_child``).
    """
    pairs = [layer_interface(layer, bases, depth, t, width) for layer in layers]
    return [z for z, _ in pairs], [c for _, c in pairs]
