"""Solid zones of curved layers: areas exposed within ``solid_layers`` below or above.

Layer i's zone is the part of its region R_i not covered by the layers below it (bottom skin)
or above it (top skin): R_i − ∩_{j ∈ {i−k, i−1, i+1, i+k}} R_j, k = ``solid_layers``. Checking the
adjacent and the k-th neighbours (not all 2k) halves the polygon booleans, which dominate this
stage; it misses only a feature that appears and vanishes again within k layers. A missing
neighbour (past the top; below the root's first layer) makes the whole region solid.
Neighbouring regions live in other (slightly turned) planes; they are projected orthogonally
into layer i's frame with an affine map (:func:`slicer.planes2d.map_between`), exact for
parallel planes and within ρ·(1 − cos Δθ) otherwise.

Only the fill domain D_i (the area inside the perimeters where fill lines go) is ever printed
solid, so the zone is computed as D_i − ∩_j R_j: a layer without a fill domain (a thin wall)
costs nothing, and D_i is an inward offset of R_i, so the booleans never overlay coincident
edges (GEOS's slowest case); a neighbour equal to R_i vertex by vertex (within
:data:`TOL.same`, a prismatic stretch) covers D_i and is skipped.

Solid infill under walls (:func:`under_walls`): where layer i+1's wall band (R_{i+1} less its
inside-the-perimeters area I_{i+1}, mapped into layer i) stands on layer i's fill domain, the
walls would sit on sparse infill (a tube on a disc: a third of its first wall points
unsupported). That part of D_i, without slivers narrower than half a width (the walls of a
sloped or turned stretch, supported within the 45° rule) and grown by one width, is solid:
(I_i ∩ R'_{i+1} − I'_{i+1}) ∘ w/4 ⊕ w ∩ D_i.
"""

from __future__ import annotations

from collections.abc import Sequence

import shapely
from shapely.geometry.base import BaseGeometry

from slicer.paths.layers import LayerPlane
from slicer.planes2d import TOL, map_between, polygonal


def _neighbours(layers: Sequence[LayerPlane], i: int, js: Sequence[int],
                open_end: bool) -> list[BaseGeometry] | None:
    """Regions ``js`` mapped into layer i; None if one is missing (nothing there)."""
    dst = (layers[i].origin, layers[i].frame)
    mapped = []
    for j in js:
        if j < 0 or j >= len(layers):
            if open_end:
                continue
            return None
        mapped.append(map_between(layers[j].region, (layers[j].origin, layers[j].frame), dst))
    return mapped


def exposed(domain: BaseGeometry, region: BaseGeometry,
            neighbours: list[BaseGeometry] | None) -> BaseGeometry:
    """The part of ``domain`` ⊂ ``region`` not covered by every neighbour.

    All of ``domain`` if a neighbour is missing (``None``).
    """
    if neighbours is None or domain.is_empty:
        return domain
    differ = [g for g in neighbours if not shapely.equals_exact(g, region, tolerance=TOL.same)]
    if not differ:
        return shapely.Polygon()
    # D − ∩ g = ∪ (D − g): D is an offset of R, so D − g overlays no coincident edges, while
    # D − (D ∩ g) would overlay D with itself
    return polygonal(shapely.union_all(shapely.difference(domain, differ)), valid=True)


def _wall_footing(inner: BaseGeometry, domain: BaseGeometry, above: BaseGeometry,
                  above_inner: BaseGeometry, width: float) -> BaseGeometry:
    """The part of ``domain`` under the wall band (``above`` − ``above_inner``) of the next
    layer, both mapped into this layer: slivers thinner than ``width``/2 dropped, grown by
    ``width``."""
    if domain.is_empty or above.is_empty:
        return shapely.Polygon()
    if shapely.equals_exact(above_inner, inner, tolerance=TOL.same):
        return shapely.Polygon()  # a prismatic stretch: the walls stand on this layer's walls
    need = shapely.intersection(inner, above)
    if not above_inner.is_empty and not need.is_empty:
        need = shapely.difference(need, above_inner)
    need = need.buffer(-0.25 * width, quad_segs=4)
    if need.is_empty:
        return shapely.Polygon()
    grown = need.buffer(1.25 * width, quad_segs=4)
    return polygonal(shapely.intersection(domain, grown), valid=True)


def wall_footing(layers: Sequence[LayerPlane], i: int, inners: Sequence[BaseGeometry],
                 domains: Sequence[BaseGeometry], width: float) -> BaseGeometry:
    """Layer i's zone of :func:`under_walls` (``inners``/``domains`` are read at i, i + 1)."""
    if i + 1 >= len(layers) or domains[i].is_empty:
        return shapely.Polygon()
    layer, nxt = layers[i], layers[i + 1]
    src, dst = (nxt.origin, nxt.frame), (layer.origin, layer.frame)
    above = map_between(nxt.region, src, dst)
    above_inner = map_between(inners[i + 1], src, dst)
    return _wall_footing(inners[i], domains[i], above, above_inner, width)


def under_walls(layers: Sequence[LayerPlane], inners: Sequence[BaseGeometry],
                domains: Sequence[BaseGeometry], width: float) -> list[BaseGeometry]:
    """Per layer, the part of its fill domain to print solid because the next layer's walls
    stand on it ("solid infill under walls").

    Parameters
    ----------
    layers : sequence of LayerPlane
        One sub-part's layers in order.
    inners : sequence of shapely geometry
        Per layer, the region inside its perimeters (:attr:`slicer.paths.toolpaths.Shell.inner`);
        the wall band is the region less this.
    domains : sequence of shapely geometry
        Per layer, where fill goes.
    width : float
        Line width w.

    Returns
    -------
    list of shapely geometry
        Zone i ⊂ ``domains[i]``; empty for the last layer (nothing stands on it here).
    """
    return [wall_footing(layers, i, inners, domains, width) for i in range(len(layers))]


def solid_zone(layers: Sequence[LayerPlane], i: int, k: int, grounded: bool,
               domain: BaseGeometry | None = None) -> BaseGeometry:
    """Layer i's zone of :func:`solid_zones` (``domain``: its fill domain, default the
    region)."""
    layer = layers[i]
    domain = layer.region if domain is None else domain
    if k <= 0 or domain.is_empty:
        return shapely.Polygon()
    below = _neighbours(layers, i, sorted({i - k, i - 1}), open_end=not grounded)
    above = _neighbours(layers, i, sorted({i + 1, i + k}), open_end=False)
    both = None if below is None or above is None else below + above
    return exposed(domain, layer.region, both)


def solid_zones(layers: Sequence[LayerPlane], k: int, grounded: bool,
                domains: Sequence[BaseGeometry] | None = None) -> list[BaseGeometry]:
    """Per layer, the area to print 100 % solid (within its fill domain).

    Parameters
    ----------
    layers : sequence of LayerPlane
        One sub-part's layers in order.
    k : int
        ``solid_layers``.
    grounded : bool
        True when nothing lies under the first layer (the root on the platform); a child's first
        layers sit on its parent and get no bottom skin.
    domains : sequence of shapely geometry, optional
        Per layer, where fill goes (:func:`slicer.paths.toolpaths.fill_domain`); the whole region
        when omitted.

    Returns
    -------
    list of shapely geometry
        Zone i ⊂ ``domains[i]``.
    """
    return [solid_zone(layers, i, k, grounded, None if domains is None else domains[i])
            for i in range(len(layers))]
