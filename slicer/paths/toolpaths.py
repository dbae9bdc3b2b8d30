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
* **Zigzag**: consecutive fill lines are joined end to end (right end to right end, then left
  to left) into one polyline wherever a connector of at most :data:`MAX_LINK` spacings lies
  inside the fill domain: straight, or along the domain's boundary where the straight one
  would cut a hole or a concave corner. The nozzle then neither retracts nor travels between
  lines.
* **Interface walls**: in a parent's interface zone (under a child's base) the wall loops are
  split and the pieces whose bead reaches into the zone get kind "interface": on a thin wall
  the perimeters *are* the solid material the child bonds to. What their beads leave of the
  zone (slivers too thin for a perimeter) gets centre loops of kind "interface".
* **Order**: greedy nearest neighbour from the current nozzle position; loops start at their
  vertex nearest the nozzle, open lines may be reversed.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import shapely
import shapely.affinity
from shapely.geometry.base import BaseGeometry

from slicer.planes2d import TOL, polygonal

OVERLAP = 0.15  # infill/perimeter overlap, fraction of the line width
QUAD_SEGS = 4  # arc segments per quarter circle in offsets
MIN_GAP = 0.25  # thinnest gap (fraction of a width) worth filling
MAX_LINK = 3.0  # longest zigzag connector, in line spacings


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
    """Every ring (exterior and holes) of a valid polygonal geometry, without the closing
    vertex."""
    polys = shapely.get_parts(polygonal(geom, valid=True))
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
    inner = polygonal(region.buffer(-count * width, quad_segs=QUAD_SEGS), valid=True)
    return paths, inner


def fill_domain(inner: BaseGeometry, width: float) -> BaseGeometry:
    """Where fill line centres may go: ``inner`` shrunk by half a width less the overlap."""
    return polygonal(inner.buffer(-(0.5 - OVERLAP) * width, quad_segs=QUAD_SEGS), valid=True)


def gap_fill(inner: BaseGeometry, domain: BaseGeometry, width: float) -> list[Path2D]:
    """Centre loops of the bands of ``inner`` too thin for fill lines.

    Each thin band (what the fill lines' reach ``domain ⊕ w/2`` misses) gets one loop along
    its middle whose width is the band's mean width (2·area / boundary length).
    """
    reach = domain.buffer((0.5 - OVERLAP) * width, quad_segs=QUAD_SEGS)
    return _centre_loops(polygonal(inner.difference(reach), valid=True), width, "perimeter")


def _centre_loops(bands: BaseGeometry, width: float, kind: str) -> list[Path2D]:
    """One loop along the middle of each band, as wide as the band (at most 1.5·width)."""
    paths = []
    for band in shapely.get_parts(bands):
        w = 2.0 * band.area / max(band.length, TOL.min_path)
        if w < MIN_GAP * width or band.area < (MIN_GAP * width) ** 2:
            continue
        core = polygonal(band.buffer(-0.45 * min(w, width), quad_segs=QUAD_SEGS), valid=True)
        for poly in shapely.get_parts(core):
            xy = shapely.get_coordinates(poly.exterior)[:-1]
            if len(xy) >= 3:
                paths.append(Path2D(kind, xy, True, float(min(w, 1.5 * width))))
    return paths


def interface_gaps(walls: list[Path2D], zone: BaseGeometry, domain: BaseGeometry,
                   width: float) -> list[Path2D]:
    """Loops of kind "interface" in what the wall beads and the fill of ``domain`` leave of
    ``zone``.

    Slivers of a section thinner than a line get no perimeter, and the band between the
    perimeters and the gap fill is not always closed; under a child's base everything must
    be solid.
    """
    if zone.is_empty:
        return []
    marked = [p for p in walls if p.kind == "interface"]
    lines = np.array([shapely.LineString(np.vstack([p.xy, p.xy[:1]]) if p.closed else p.xy)
                      for p in marked], dtype=object)
    beads = shapely.union_all(np.r_[shapely.buffer(lines, [0.5 * p.width for p in marked],
                                                   quad_segs=QUAD_SEGS),
                                    domain.buffer(0.5 * width, quad_segs=QUAD_SEGS)])
    rest = zone if beads.is_empty else polygonal(zone.difference(beads), valid=True)
    return _centre_loops(rest, width, "interface")


def _rotation(angle: float) -> np.ndarray:
    """(2, 2) float: row vectors times it turn the frame by −``angle``° (fill lines along x)."""
    c, s = np.cos(np.radians(angle)), np.sin(np.radians(angle))
    return np.array([[c, -s], [s, c]])


def _scanlines(domain: BaseGeometry, spacing: float, fwd: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Lines y' = (k + ½)·spacing of the turned frame (``xy @ fwd``) clipped to ``domain``.

    The lines are turned into the domain's frame, not the domain into theirs: turning a
    polygon whose parts nearly touch can make it invalid, and GEOS then clips garbage.

    Returns
    -------
    lo, hi, y : (m,) float
        Left end, right end and height of each piece in the turned frame, sorted by (row, lo).
    row : (m,) int
        Grid index k of each piece.
    """
    turned = shapely.get_coordinates(domain) @ fwd
    (x0, y0), (x1, y1) = turned.min(axis=0), turned.max(axis=0)
    k = np.arange(np.floor(y0 / spacing - 0.5), np.ceil(y1 / spacing - 0.5) + 1)
    y = (k + 0.5) * spacing
    coords = np.stack([np.column_stack([np.full_like(y, x0 - 1), y]),
                       np.column_stack([np.full_like(y, x1 + 1), y])], axis=1) @ fwd.T
    # one overlay of all lines at once (not one per line over the whole polygon)
    parts = shapely.get_parts(shapely.intersection(shapely.multilinestrings(coords), domain))
    parts = parts[(shapely.get_type_id(parts) == 1) & (shapely.length(parts) > TOL.min_path)]
    if not len(parts):
        empty = np.zeros(0)
        return empty, empty, empty, np.zeros(0, dtype=int)
    xy, idx = shapely.get_coordinates(parts, return_index=True)
    xy = xy @ fwd
    first = np.r_[0, np.flatnonzero(np.diff(idx)) + 1]
    lo, hi = np.minimum.reduceat(xy[:, 0], first), np.maximum.reduceat(xy[:, 0], first)
    row = np.rint(xy[first, 1] / spacing - 0.5).astype(int)
    yy = (row + 0.5) * spacing
    order = np.lexsort((lo, row))
    return lo[order], hi[order], yy[order], row[order]


def _successors(ends: np.ndarray, row: np.ndarray) -> np.ndarray:
    """Per piece and side (0 left, 1 right): the piece of the next row whose same-side end is
    nearest, (m, 2) int (−1 when the next row is empty)."""
    m = len(row)
    out = np.full((m, 2), -1)
    if m == 0:
        return out
    span = float(ends.max() - ends.min()) + 1.0
    for side in (0, 1):
        x = ends[:, side] - ends.min()
        keys = row * span + x  # sorted: rows ascending, pieces left to right within a row
        pos = np.searchsorted(keys, (row + 1) * span + x)
        cand = np.stack([np.clip(pos - 1, 0, m - 1), np.clip(pos, 0, m - 1)], axis=1)
        gap = np.where(row[cand] == (row + 1)[:, None], np.abs(x[cand] - x[:, None]), np.inf)
        best = cand[np.arange(m), np.argmin(gap, axis=1)]
        out[:, side] = np.where(np.isfinite(gap.min(axis=1)), best, -1)
    return out


@dataclass(frozen=True)
class _Rings:
    """The boundary rings of a fill domain as flat segment arrays (turned frame)."""

    rings: list[np.ndarray]  # (n_r + 1, 2) closed rings
    start: np.ndarray  # (S, 2) segment starts of all rings
    vec: np.ndarray  # (S, 2) segment vectors
    ring: np.ndarray  # (S,) ring of each segment
    pos: np.ndarray  # (S,) arc length of each segment start along its ring

    @classmethod
    def of(cls, rings: list[np.ndarray]) -> _Rings:
        vec = [np.diff(r, axis=0) for r in rings]
        pos = [np.r_[0.0, np.cumsum(np.linalg.norm(v, axis=1))[:-1]] for v in vec]
        return cls(rings, np.concatenate([r[:-1] for r in rings]), np.concatenate(vec),
                   np.repeat(np.arange(len(rings)), [len(v) for v in vec]), np.concatenate(pos))

    def locate(self, p: np.ndarray) -> tuple[int, float] | None:
        """(ring, arc length) of the boundary point ``p``; None if ``p`` is off the boundary."""
        t = np.clip(np.einsum("ij,ij->i", p - self.start, self.vec)
                    / np.maximum(np.einsum("ij,ij->i", self.vec, self.vec), TOL.unit), 0.0, 1.0)
        d = np.linalg.norm(self.start + t[:, None] * self.vec - p, axis=1)
        k = int(np.argmin(d))
        if d[k] > 1e3 * TOL.contain:
            return None
        return int(self.ring[k]), float(self.pos[k] + t[k] * np.linalg.norm(self.vec[k]))


def _around(rings: _Rings, a: np.ndarray, b: np.ndarray, limit: float) -> np.ndarray | None:
    """The shorter way from ``a`` to ``b`` along the boundary ring through both, (k, 2) float
    without the ends; None if they lie on different rings or it is longer than ``limit``, or if
    it strays past the rows of ``a`` and ``b`` (it would run over other fill lines)."""
    pa, pb = rings.locate(a), rings.locate(b)
    if pa is None or pb is None or pa[0] != pb[0]:
        return None
    ring = rings.rings[pa[0]]
    s = rings.pos[rings.ring == pa[0]]
    total = s[-1] + float(np.linalg.norm(ring[-1] - ring[-2]))
    fwd = (pb[1] - pa[1]) % total
    step = fwd if fwd <= total - fwd else fwd - total  # signed arc length, shorter way
    if abs(step) > limit:
        return None
    u = (s - pa[1]) % total  # each vertex's distance ahead of a
    if step < 0:
        u = (total - u) % total
    pick = np.flatnonzero((u > 0) & (u < abs(step)))
    via = ring[:-1][pick[np.argsort(u[pick])]]
    lo, hi = sorted((a[1], b[1]))
    if len(via) and (via[:, 1].min() < lo - TOL.contain or via[:, 1].max() > hi + TOL.contain):
        return None
    return via


def _links(domain: BaseGeometry, fwd: np.ndarray, lo: np.ndarray, hi: np.ndarray, y: np.ndarray,
           row: np.ndarray, spacing: float
           ) -> tuple[np.ndarray, dict[tuple[int, int], np.ndarray]]:
    """Usable connectors to the next row (coordinates in the turned frame ``xy @ fwd``).

    Returns
    -------
    nxt : (m, 2) int
        The successor per piece and side, −1 where no connector of at most :data:`MAX_LINK`
        spacings stays inside the domain.
    via : dict
        (piece, side) → (k, 2) float: vertices of connectors that follow the boundary (where
        the straight one would cut a concave corner or a hole).
    """
    ends = np.column_stack([lo, hi])
    nxt = _successors(ends, row)
    i, side = np.nonzero(nxt >= 0)
    j = nxt[i, side]
    a = np.column_stack([ends[i, side], y[i]])
    b = np.column_stack([ends[j, side], y[j]])
    limit = MAX_LINK * spacing
    ok = np.linalg.norm(b - a, axis=1) <= limit
    if ok.any():
        room = domain.buffer(TOL.contain)
        shapely.prepare(room)
        segs = np.stack([a[ok], b[ok]], axis=1) @ fwd.T
        ok[ok] = shapely.covers(room, shapely.linestrings(segs))
    via = {}
    rings = None
    for k in np.flatnonzero(~ok):
        rings = rings or _Rings.of([shapely.get_coordinates(r) @ fwd
                                    for r in shapely.get_rings(shapely.get_parts(domain))])
        path = _around(rings, a[k], b[k], limit)
        if path is not None:
            ok[k], via[(int(i[k]), int(side[k]))] = True, path
    out = np.full_like(nxt, -1)
    out[i[ok], side[ok]] = j[ok]
    return out, via


def _zigzag(lo: np.ndarray, hi: np.ndarray, y: np.ndarray, links: np.ndarray,
            via: dict[tuple[int, int], np.ndarray]) -> list[np.ndarray]:
    """Chain pieces through ``links`` (greedy, bottom row first), (n, 2) polylines."""
    used = np.zeros(len(lo), dtype=bool)
    chains = []
    for start in range(len(lo)):
        if used[start]:
            continue
        i, side = start, 1
        pts = [np.array([[lo[i], y[i]], [hi[i], y[i]]])]
        used[i] = True
        while links[i, side] >= 0 and not used[links[i, side]]:
            pts.append(via.get((i, side), np.zeros((0, 2))))
            i = int(links[i, side])
            used[i] = True
            ends = np.array([[hi[i], y[i]], [lo[i], y[i]]])
            pts.append(ends if side == 1 else ends[::-1])
            side = 1 - side
        chains.append(np.vstack(pts))
    return chains


def hatch(domain: BaseGeometry, spacing: float, angle: float, width: float,
          kind: str, link: bool = True) -> list[Path2D]:
    """Parallel lines ``spacing`` apart at ``angle``° clipped to ``domain``.

    Line k is the line y' = (k + ½)·spacing of the frame rotated by ``angle`` (a grid fixed to
    the plane origin). With ``link`` consecutive lines are joined into zigzag polylines where
    the connector stays inside ``domain`` (see :data:`MAX_LINK`); otherwise every piece is an
    open path of two vertices.
    """
    if domain.is_empty or spacing <= 0:
        return []
    fwd = _rotation(angle)
    lo, hi, y, row = _scanlines(domain, spacing, fwd)
    if not len(lo):
        return []
    if link:
        chains = _zigzag(lo, hi, y, *_links(domain, fwd, lo, hi, y, row, spacing))
    else:
        chains = list(np.stack([np.column_stack([lo, y]), np.column_stack([hi, y])], axis=1))
    return [Path2D(kind, xy @ fwd.T, False, width) for xy in chains]


def mark_interface(paths: list[Path2D], zone: BaseGeometry, width: float) -> list[Path2D]:
    """Split wall paths where their bead enters ``zone``; the pieces inside become "interface".

    Every path is cut into segments of at most half a width; a segment whose midpoint lies
    within half its path's width of ``zone`` belongs to the zone. Runs of equal membership are
    emitted in path order (a closed loop becomes consecutive open pieces that end where the
    loop started), so the nozzle never leaves the loop.
    """
    if zone.is_empty:
        return paths
    near = zone.buffer(0.5 * width, quad_segs=QUAD_SEGS)
    shapely.prepare(near)
    out = []
    for p in paths:
        xy = np.vstack([p.xy, p.xy[:1]]) if p.closed else p.xy
        dense = shapely.get_coordinates(shapely.segmentize(shapely.linestrings(xy), 0.5 * width))
        mid = 0.5 * (dense[1:] + dense[:-1])
        inside = shapely.contains_xy(near, mid[:, 0], mid[:, 1])
        if not inside.any():
            out.append(p)
            continue
        cuts = np.r_[0, np.flatnonzero(np.diff(inside)) + 1, len(inside)]
        for a, b in itertools.pairwise(cuts):
            kind = "interface" if inside[a] else p.kind
            out.append(Path2D(kind, dense[a:b + 1], False, p.width))
    return out


def order_paths(paths: list[Path2D], start: np.ndarray) -> list[Path2D]:
    """Greedy nearest-neighbour order from ``start`` (2,), reversing/rotating paths to suit.

    The next path is the one with an end nearest the nozzle (loops: their first vertex; ties:
    the earliest path); a loop then starts at its vertex nearest the nozzle, an open path
    whose far end is nearer is reversed.
    """
    if not paths:
        return []
    heads = np.array([p.xy[0] for p in paths])
    tails = np.array([p.xy[-1] for p in paths])
    closed = np.array([p.closed for p in paths])
    left = np.ones(len(paths), dtype=bool)
    out, here = [], np.asarray(start, dtype=float)
    for _ in range(len(paths)):
        dh = np.linalg.norm(heads - here, axis=1)
        dt = np.where(closed, np.inf, np.linalg.norm(tails - here, axis=1))
        j = int(np.argmin(np.where(left, np.minimum(dh, dt), np.inf)))
        left[j] = False
        p = paths[j]
        if p.closed:
            k = int(np.argmin(np.linalg.norm(p.xy - here, axis=1)))
            p = Path2D(p.kind, np.roll(p.xy, -k, axis=0), True, p.width)
        elif dt[j] < dh[j]:
            p = Path2D(p.kind, p.xy[::-1].copy(), False, p.width)
        out.append(p)
        here = _end(p)
    return out


@dataclass
class Shell:
    """What a layer's fill does not depend on: its walls and the area left inside them.

    Attributes
    ----------
    walls : list of Path2D
        Perimeter loops (outermost first) and gap-fill loops, unordered.
    inner : shapely geometry
        The region shrunk by the perimeters.
    domain : shapely geometry
        Where fill line centres go (:func:`fill_domain`).
    """

    walls: list[Path2D]
    inner: BaseGeometry
    domain: BaseGeometry


def shell(region: BaseGeometry, spec: FillSpec) -> Shell:
    """Perimeters, gap fill and fill domain of one layer's section."""
    loops, inner = perimeters(region, spec.width, spec.perimeters)
    domain = fill_domain(inner, spec.width)
    return Shell(loops + gap_fill(inner, domain, spec.width), inner, domain)


def fill_paths(domain: BaseGeometry, solid: BaseGeometry, interface: BaseGeometry,
               spec: FillSpec, layer_index: int) -> list[Path2D]:
    """Zigzag fill of ``domain``: "interface", "solid" (100 %) and sparse "infill" zones."""
    w = spec.width
    angle = spec.angle + 90.0 * (layer_index % 2)
    iface = (polygonal(domain.intersection(interface), valid=True) if not interface.is_empty
             else interface)
    dense = polygonal(domain.intersection(solid), valid=True) if not solid.is_empty else solid
    if not iface.is_empty and not dense.is_empty:
        dense = polygonal(dense.difference(iface), valid=True)
    fill = hatch(iface, w, angle, w, "interface") + hatch(dense, w, angle, w, "solid")
    if spec.density > 0:
        taken = polygonal(shapely.union(dense, iface), valid=True)
        sparse = polygonal(domain.difference(taken), valid=True) if not taken.is_empty else domain
        fill += hatch(sparse, w / max(spec.density, 1e-3), angle, w, "infill")
    return fill


def _end(p: Path2D) -> np.ndarray:
    return p.xy[0] if p.closed else p.xy[-1]


def layer_paths(region: BaseGeometry, solid: BaseGeometry, interface: BaseGeometry,
                spec: FillSpec, layer_index: int, start: np.ndarray | None = None,
                walls: Shell | None = None, fill: list[Path2D] | None = None
                ) -> list[Path2D]:
    """All paths of one layer, ordered.

    Parameters
    ----------
    region : shapely geometry
        The layer's section.
    solid, interface : shapely geometry
        Zones printed at 100 % ("interface" ⊂ solid gets its own kind, on fill and on the wall
        pieces in it).
    spec : FillSpec
    layer_index : int
        Alternates the fill direction.
    start : (2,) float, optional
        Nozzle position before the layer.
    walls : Shell, optional
        ``shell(region, spec)`` if already computed.
    fill : list of Path2D, optional
        ``fill_paths(walls.domain, solid, interface, spec, layer_index)`` if already computed
        (in any order: it is ordered here).
    """
    sh = shell(region, spec) if walls is None else walls
    here = np.zeros(2) if start is None else start
    ordered = mark_interface(order_paths(sh.walls, here), interface, spec.width)
    here = _end(ordered[-1]) if ordered else here
    ordered += order_paths(interface_gaps(ordered, interface, sh.domain, spec.width), here)
    here = _end(ordered[-1]) if ordered else here
    if fill is None:
        fill = fill_paths(sh.domain, solid, interface, spec, layer_index)
    return ordered + order_paths(fill, here)
