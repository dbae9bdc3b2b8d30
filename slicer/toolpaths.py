"""Toolpaths of one layer in its plane's 2D frame: perimeters, gap fill, infill, solid fill.

* **Perimeters** are exact inward offsets of the section (shapely ``buffer``, round joins): the
  k-th centreline lies (k + ½)·w inside the boundary, so the outer wall sits w/2 inside the
  model and every wall line is stacked on the same offset of the layer below.
* **Gap fill**: where the band left inside the perimeters is thinner than one line (a 2 mm
  tube wall holds 4 lines of 0.45 mm and a 0.2 mm gap), a single loop along the band's centre
  with the band's width, so the wall is filled without over-extrusion.
* **Fill**: parallel lines clipped to the area inside the perimeters (overlapping the innermost
  perimeter by :data:`OVERLAP` of a width); spacing w for solid and interface zones, w/density
  for sparse infill; direction alternates by 90° from layer to layer and the line grid is
  anchored at the frame origin so alternate layers line up.
* **Order**: greedy nearest neighbour from the current nozzle position; loops start at their
  vertex nearest the nozzle, open lines may be reversed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
import shapely.affinity
from shapely.geometry.base import BaseGeometry

from slicer.planes2d import TOL, polygonal

OVERLAP = 0.15  # infill/perimeter overlap, fraction of the line width
QUAD_SEGS = 4  # arc segments per quarter circle in offsets
MIN_GAP = 0.25  # thinnest gap (fraction of a width) worth filling


@dataclass
class Path2D:
    """A path in a layer's 2D frame.

    Attributes
    ----------
    kind : str
        "perimeter", "infill", "solid" or "interface".
    xy : (n, 2) float
    closed : bool
    width : float
        Extrusion width, mm.
    """

    kind: str
    xy: np.ndarray
    closed: bool
    width: float


@dataclass(frozen=True)
class FillSpec:
    """Line width, perimeter count, infill density and angle (degrees) of a layer."""

    width: float
    perimeters: int
    density: float
    angle: float


def _rings(geom: BaseGeometry) -> list[np.ndarray]:
    """Every ring (exterior and holes) of a polygonal geometry, without the closing vertex."""
    polys = shapely.get_parts(polygonal(geom))
    rings = shapely.get_rings(polys) if len(polys) else np.array([])
    out = []
    for ring in np.atleast_1d(rings):
        xy = shapely.get_coordinates(ring)[:-1]
        if len(xy) >= 3 and ring.length > TOL.min_path:
            out.append(xy)
    return out


def perimeters(region: BaseGeometry, width: float, count: int
               ) -> tuple[list[Path2D], BaseGeometry]:
    """Offset loops (k + ½)·width inside ``region`` and the area left inside them.

    Returns
    -------
    paths : list of Path2D
        Closed "perimeter" loops, outermost first.
    inner : shapely geometry
        ``region`` shrunk by ``count·width`` (the area for gap fill and infill).
    """
    paths = []
    for k in range(count):
        loop = region.buffer(-(k + 0.5) * width, quad_segs=QUAD_SEGS)
        paths += [Path2D("perimeter", xy, True, width) for xy in _rings(loop)]
    inner = polygonal(region.buffer(-count * width, quad_segs=QUAD_SEGS))
    return paths, inner


def fill_domain(inner: BaseGeometry, width: float) -> BaseGeometry:
    """Where fill line centres may go: ``inner`` shrunk by half a width less the overlap."""
    return polygonal(inner.buffer(-(0.5 - OVERLAP) * width, quad_segs=QUAD_SEGS))


def gap_fill(inner: BaseGeometry, domain: BaseGeometry, width: float) -> list[Path2D]:
    """Centre loops of the bands of ``inner`` too thin for fill lines.

    Each thin band (what the fill lines' reach ``domain ⊕ w/2`` misses) gets one loop along
    its middle whose width is the band's mean width (2·area / boundary length).
    """
    reach = domain.buffer((0.5 - OVERLAP) * width, quad_segs=QUAD_SEGS)
    rest = shapely.get_parts(polygonal(inner.difference(reach)))
    paths = []
    for band in rest:
        w = 2.0 * band.area / max(band.length, TOL.min_path)
        if w < MIN_GAP * width or band.area < (MIN_GAP * width) ** 2:
            continue
        core = polygonal(band.buffer(-0.45 * min(w, width), quad_segs=QUAD_SEGS))
        for poly in shapely.get_parts(core):
            xy = shapely.get_coordinates(poly.exterior)[:-1]
            if len(xy) >= 3:
                paths.append(Path2D("perimeter", xy, True, float(min(w, 1.5 * width))))
    return paths


def hatch(domain: BaseGeometry, spacing: float, angle: float, width: float,
          kind: str) -> list[Path2D]:
    """Parallel lines ``spacing`` apart at ``angle``° clipped to ``domain``.

    Line k is the line y' = (k + ½)·spacing of the frame rotated by ``angle`` (a grid fixed to
    the plane origin). Returns open paths of two vertices.
    """
    if domain.is_empty or spacing <= 0:
        return []
    rot = shapely.affinity.rotate(domain, -angle, origin=(0.0, 0.0))
    x0, y0, x1, y1 = rot.bounds
    k = np.arange(np.floor(y0 / spacing - 0.5), np.ceil(y1 / spacing - 0.5) + 1)
    y = (k + 0.5) * spacing
    coords = np.stack([np.column_stack([np.full_like(y, x0 - 1), y]),
                       np.column_stack([np.full_like(y, x1 + 1), y])], axis=1)
    parts = shapely.get_parts(shapely.intersection(shapely.linestrings(coords), rot))
    parts = parts[(shapely.get_type_id(parts) == 1) & (shapely.length(parts) > TOL.min_path)]
    if not len(parts):
        return []
    xy, idx = shapely.get_coordinates(parts, return_index=True)
    c, s = np.cos(np.radians(angle)), np.sin(np.radians(angle))
    xy = xy @ np.array([[c, s], [-s, c]])
    splits = np.flatnonzero(np.diff(idx)) + 1
    return [Path2D(kind, seg, False, width) for seg in np.split(xy, splits)]


def order_paths(paths: list[Path2D], start: np.ndarray) -> list[Path2D]:
    """Greedy nearest-neighbour order from ``start`` (2,), reversing/rotating paths to suit."""
    left = list(paths)
    out, here = [], np.asarray(start, dtype=float)
    while left:
        heads = np.array([p.xy[0] for p in left])
        tails = np.array([p.xy[-1] for p in left])
        dh = np.linalg.norm(heads - here, axis=1)
        dt = np.where([p.closed for p in left], np.inf, np.linalg.norm(tails - here, axis=1))
        j = int(np.argmin(np.minimum(dh, dt)))
        p = left.pop(j)
        if p.closed:
            k = int(np.argmin(np.linalg.norm(p.xy - here, axis=1)))
            p = Path2D(p.kind, np.roll(p.xy, -k, axis=0), True, p.width)
        elif dt[j] < dh[j]:
            p = Path2D(p.kind, p.xy[::-1].copy(), False, p.width)
        out.append(p)
        here = p.xy[0] if p.closed else p.xy[-1]
    return out


def layer_paths(region: BaseGeometry, solid: BaseGeometry, interface: BaseGeometry,
                spec: FillSpec, layer_index: int, start: np.ndarray | None = None
                ) -> list[Path2D]:
    """All paths of one layer, ordered.

    Parameters
    ----------
    region : shapely geometry
        The layer's section.
    solid, interface : shapely geometry
        Zones printed at 100 % ("interface" ⊂ solid gets its own kind).
    spec : FillSpec
    layer_index : int
        Alternates the fill direction.
    start : (2,) float, optional
        Nozzle position before the layer.
    """
    w = spec.width
    loops, inner = perimeters(region, w, spec.perimeters)
    domain = fill_domain(inner, w)
    angle = spec.angle + 90.0 * (layer_index % 2)
    iface = polygonal(domain.intersection(interface)) if not interface.is_empty else interface
    dense = polygonal(domain.intersection(solid).difference(iface))
    sparse = polygonal(domain.difference(solid).difference(iface))
    fill = (hatch(iface, w, angle, w, "interface") + hatch(dense, w, angle, w, "solid")
            + hatch(sparse, w / max(spec.density, 1e-3), angle, w, "infill")
            if spec.density > 0 else hatch(iface, w, angle, w, "interface")
            + hatch(dense, w, angle, w, "solid"))
    here = np.zeros(2) if start is None else start
    walls = order_paths(loops + gap_fill(inner, domain, w), here)
    here = walls[-1].xy[0] if walls else here
    return walls + order_paths(fill, here)
