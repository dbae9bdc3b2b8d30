"""Dynamic slicing: curved-layer planes along a skeleton curve with a wedge-thickness bound.

Paper §2.2.4 (2)–(3) slices at s = i·t with the plane normal to the tangent τ(s). Consecutive
planes are then not parallel and the layers are wedges whose thickness the paper does not
control: across a section of radius ρ a turn of Δθ changes the thickness by about ρ·tan Δθ.
Here the planes are *marched*:

* layer i's plane passes through the curve point whose height above plane i−1 (along its
  normal) is exactly t, so the thickness on the skeleton is t (but see lopsided bounds);
* its normal turns from n_{i−1} towards τ(s_i) by at most
  Δθ_max = atan(m·min(1 − f_min, f_max − 1)·t / ρ), ρ the extent of the previous section
  around its origin, m = :data:`TOL.turn_margin`; the exact local thickness over the new
  section is then measured and the turn halved until it lies in [f_min·t, f_max·t];
* when the bounds are lopsided (f_max − 1 < 1 − f_min: a thickness cap at a large t) and the
  curve needs more turn than that allows, the plane sits (f_min + f_max)/2·t above the one
  below instead, with m·(f_max − f_min)/2·t to turn by (:func:`_step`);
* a caller's ``accept`` hook (reachable A, no collision) may reject a plane: the turn is
  halved down to zero (the previous normal) before :class:`SlicingError` is raised;
* the first layer is parallel to the base plane (a child starts flat on its parent);
* the last layers end on a flat far end: when the part reaches at most two layers above
  the plane below and stands within a quarter layer of its top over at least half the area
  of the layer below (a cap parallel to the layers), the layers left share that height
  (:func:`fit_end`), parallel to the layer below (not turned: a wedge of a thin layer would
  be thinner than the bounds allow a full one). A march of whole layers stops at the first
  empty mid-layer section, so its top stood up to half a layer above such an end (a trunk's
  top: at 0.3 mm 0.1 mm of bead over the surface, ball15 of the sweep 98.97 % inside) or up
  to half a layer short of it. Elsewhere (a dome, the sliver under a tilted cut) the end is
  left as marched: a thinner layer on a full one there steps out over an overhanging wall
  (the first try fitted every end and lost hard/pipe3_15 and tee_low at 0.2 mm a layer
  each, under a lean's cut).

Regions are cut at the middle of each layer (plane parallel to layer i, t/2 below it) so no
plane hits a face of the model exactly; paths later lie on layer i's plane (its top).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace

import manifold3d as m3
import numpy as np
import shapely
from numpy.typing import ArrayLike
from shapely.geometry.base import BaseGeometry

from slicer.paths.skeleton import SkeletonCurve
from slicer.planes2d import TOL, from_plane, plane_frame, section, transport_frame, unit

MAX_HALVINGS = 8  # turn halvings before giving up on a turn (then the previous normal)
NEWTON_STEPS = 4  # iterations finding the curve point t above the previous plane
FLAT_END = 0.5  # a far end whose top FLAT_DEPTH layer holds this share of the layer below ...
FLAT_DEPTH = 0.25  # ... is flat (a share of t)

#: ``accept(origin (3,), frame (3, 3), region) -> None`` if the plane is usable, else the name
#: of what is in the way (e.g. "printed part", "platform", "A limits").
Accept = Callable[[np.ndarray, np.ndarray, BaseGeometry], "str | None"]

#: ``direction(s (n,)) -> (n, 3)``: the normal the layers turn towards at arc lengths ``s``
#: (default: the curve's tangent; :mod:`slicer.paths.lean` leans them off it).
Direction = Callable[[np.ndarray], np.ndarray]

#: ``thin(origin (3,), normal (3,), t) -> float``: the nominal thickness of the layer above
#: the plane (origin, normal) (:func:`slicer.paths.thin_layers.layer_cap`): at most ``t``,
#: but for a first layer on a parent's beads.
Thin = Callable[[np.ndarray, np.ndarray, float], float]


class SlicingError(ValueError):
    """A sub-part that cannot be sliced; the message names sub-part, layer and obstacle.

    ``subpart`` and ``obstacle`` ("printed part", "platform", "the A/C limits", ...) are set
    when a layer had no acceptable plane (None otherwise)."""

    def __init__(self, message: str, subpart: int | None = None,
                 obstacle: str | None = None) -> None:
        super().__init__(message)
        self.subpart, self.obstacle = subpart, obstacle


@dataclass
class LayerPlane:
    """One marched layer.

    Attributes
    ----------
    index : int
    s : float
        Arc length of the origin on the skeleton curve, mm.
    origin : (3,) float
        Point of the layer plane (its top surface) on the skeleton.
    frame : (3, 3) float
        Rows u, v, normal.
    region : shapely Polygon or MultiPolygon
        Mid-layer cross-section in the frame's 2D coordinates.
    below : tuple of ((3,) float, (3,) float)
        Origin and normal of the surface the layer is printed on (previous plane or base).
    thickness : (2,) float
        Smallest and largest local thickness over the region, mm.
    turn : float
        Angle between this normal and the one below, degrees.
    nominal : float
        The layer height it was marched at, mm: the settings', or less where the march
        thinned it (:mod:`slicer.paths.thin_layers`), more for a first layer on a parent's
        beads through a spot; 0 unknown. The last layers, fitted to
        the part's far end (:func:`fit_end`), keep the height they would have had:
        ``thickness`` says how thick they are.
    """

    index: int
    s: float
    origin: np.ndarray
    frame: np.ndarray
    region: BaseGeometry
    below: tuple[np.ndarray, np.ndarray]
    thickness: tuple[float, float]
    turn: float
    nominal: float = 0.0

    @property
    def normal(self) -> np.ndarray:
        """Unit normal (build direction), (3,) float."""
        return self.frame[2]


def local_thickness(points: ArrayLike, normal: ArrayLike, below: tuple[np.ndarray, np.ndarray]
                    ) -> np.ndarray:
    """Thickness under points of a layer plane, measured along its normal to the plane below.

    Parameters
    ----------
    points : (n, 3) float
        Points on the layer plane.
    normal : (3,) float
        Unit normal of the layer.
    below : ((3,) float, (3,) float)
        Origin and unit normal of the plane below.

    Returns
    -------
    (n,) float
        ``((x − o_b)·n_b) / (n·n_b)``; +inf where the planes are perpendicular.
    """
    ob, nb = below
    den = float(np.dot(normal, nb))
    h = (np.asarray(points, dtype=float).reshape(-1, 3) - ob) @ nb
    return h / den if abs(den) > TOL.unit else np.full(len(h), np.inf)


def turn_toward(a: np.ndarray, b: np.ndarray, max_deg: float) -> tuple[np.ndarray, float]:
    """Rotate unit ``a`` towards unit ``b`` by at most ``max_deg``; returns (vector, angle°)."""
    ang = float(np.degrees(np.arccos(np.clip(a @ b, -1.0, 1.0))))
    if ang <= max_deg or ang < 1e-12:
        return (b.copy() if ang <= max_deg else a.copy()), min(ang, max_deg)
    axis, ok = unit(np.cross(a, b))
    if not ok[0]:  # antiparallel: any perpendicular axis
        axis = unit(np.cross(a, plane_frame(a)[0]))[0]
    k, th = axis[0], np.radians(max_deg)
    r = a * np.cos(th) + np.cross(k, a) * np.sin(th) + k * (k @ a) * (1 - np.cos(th))
    return unit(r)[0][0], max_deg


def region_radius(region: BaseGeometry) -> float:
    """Largest distance of the region's vertices from the frame origin, mm (0 if empty)."""
    xy = shapely.get_coordinates(region)
    return float(np.linalg.norm(xy, axis=1).max()) if len(xy) else 0.0


def _advance(curve: SkeletonCurve, s0: float, below: tuple[np.ndarray, np.ndarray],
             t: float) -> float:
    """Arc length whose curve point lies t above the plane ``below`` (Newton, clamped)."""
    ob, nb = below
    s = s0 + t
    for _ in range(NEWTON_STEPS):
        h = float((curve.point(s)[0] - ob) @ nb)
        slope = max(float(curve.tangent(s)[0] @ nb), 0.2)
        s = float(np.clip(s + (t - h) / slope, s0 + 0.5 * t, s0 + 5.0 * t))
    return s


@dataclass(frozen=True)
class MarchSettings:
    """What plane marching needs from :class:`slicer.settings.ProcessSettings`."""

    t: float
    f_min: float
    f_max: float
    max_layers: int = 100000


def _try_plane(solid: m3.Manifold, origin: np.ndarray, frame: np.ndarray,
               below: tuple[np.ndarray, np.ndarray], ms: MarchSettings,
               t_here: float | None = None) -> tuple[BaseGeometry, tuple[float, float]]:
    """Mid-layer region and its thickness range for one candidate plane, ``t_here`` (else
    t) above the one below on the skeleton."""
    t = ms.t if t_here is None else t_here
    region = section(solid, origin - 0.5 * t * frame[2], frame)
    xy = shapely.get_coordinates(region)
    if len(xy) == 0:
        return region, (t, t)
    h = local_thickness(from_plane(xy, origin, frame), frame[2], below)
    return region, (float(h.min()), float(h.max()))


def march_layers(solid: m3.Manifold, curve: SkeletonCurve, base_origin: ArrayLike,
                 base_normal: ArrayLike, ms: MarchSettings, accept: Accept | None = None,
                 subpart: int = 0, direction: Direction | None = None,
                 thin: Thin | None = None) -> Iterator[LayerPlane]:
    """March layer planes along ``curve`` from the base plane until the sections run out.

    A generator: each layer is yielded as soon as it is accepted, so the caller can update
    the state its ``accept`` hook reads (table C, printed material) before the next plane.

    Parameters
    ----------
    solid : manifold3d.Manifold
        The sub-part.
    curve : SkeletonCurve
        Its skeleton from the base centre.
    base_origin, base_normal : (3,) float
        The base plane (normal into the part); the first layer is parallel to it.
    ms : MarchSettings
    accept : Accept, optional
        Veto hook per candidate plane (orientation limits, collisions).
    subpart : int
        Index used in error messages.
    direction : Direction, optional
        The normals to turn towards (default: the curve's tangent).
    thin : Thin, optional
        The next layer's nominal thickness from the plane below and ``ms.t``
        (:func:`slicer.paths.thin_layers.layer_cap`); default ``ms.t`` throughout. A thinner
        one scales its thickness bounds and turn with it.

    Raises
    ------
    SlicingError
        When even an unturned plane is vetoed by ``accept``.
    """
    below = (np.asarray(base_origin, dtype=float), unit(base_normal)[0][0])
    frame = plane_frame(below[1])
    s_prev, radius = 0.0, 0.0
    hull = solid.hull().to_mesh().vert_properties[:, :3].astype(float)
    area = 0.0  # of the layer below
    for i in range(ms.max_layers):
        t_i = ms.t if thin is None else thin(below[0], below[1], ms.t)
        end = _end_height(solid, hull, below, frame, t_i, area)
        here = _thinned(ms, t_i) if end == t_i else replace(ms, t=end, f_min=1.0, f_max=1.0)
        s, origin, target, max_turn, t_here = _step(curve, s_prev, below, radius, here, i,
                                                    direction)
        layer = _choose(solid, origin, frame, below, target, max_turn, here, accept, subpart,
                        i, t_here)
        if layer is None:
            break
        layer.s, layer.nominal = s, t_i
        area = layer.region.area
        yield layer
        below, frame, s_prev = (origin, layer.frame[2]), layer.frame, s
        radius = region_radius(layer.region) + 2.0 * ms.t


def fit_end(points: np.ndarray, below: tuple[np.ndarray, np.ndarray], t: float) -> float:
    """Thickness of the next layer so that the last layers end on the part's far end.

    Parameters
    ----------
    points : (n, 3) float
        The part's vertices (its hull's suffice).
    below : ((3,) float, (3,) float)
        Origin and unit normal of the plane below.
    t : float
        The layer's nominal thickness, mm.

    Returns
    -------
    float
        ``t`` while the part reaches more than ``2 t`` above the plane, or less than
        ``TOL.end_share · t`` (the march stops there, short of the end by less than half a
        layer: the mid-layer section is empty); otherwise that height ``h`` shared by the
        fewest layers no thicker than ``t``: ``h / ceil(h / t)`` (at least half a layer).
    """
    h = float(((points - below[0]) @ below[1]).max()) if len(points) else 0.0
    if not TOL.end_share * t <= h <= 2.0 * t:
        return t
    return h / math.ceil(h / t - 1e-9)


def _end_height(solid: m3.Manifold, hull: np.ndarray, below: tuple[np.ndarray, np.ndarray],
                frame: np.ndarray, t: float, area: float) -> float:
    """The next layer's thickness: :func:`fit_end` where the part's far end is flat (its
    section a quarter layer under its top at least half ``area``, the layer below's), else
    ``t``."""
    fitted = fit_end(hull, below, t)
    if fitted == t:
        return t
    top = float(((hull - below[0]) @ below[1]).max())
    cap = section(solid, below[0] + (top - FLAT_DEPTH * t) * below[1], frame)
    return fitted if cap.area >= FLAT_END * area else t


def _thinned(ms: MarchSettings, t: float) -> MarchSettings:
    """``ms`` for a layer of nominal thickness ``t``: thinner than ``ms.t`` its bounds and
    turn scale with it; thicker (a first layer on a parent's beads,
    :func:`slicer.paths.thin_layers.first_cap`) it is exactly that thick."""
    if t > ms.t:
        return replace(ms, t=t, f_min=1.0, f_max=1.0)
    return ms if t == ms.t else replace(ms, t=t)


def _step(curve: SkeletonCurve, s_prev: float, below: tuple[np.ndarray, np.ndarray],
          radius: float, ms: MarchSettings, index: int, direction: Direction | None = None
          ) -> tuple[float, np.ndarray, np.ndarray, float, float]:
    """The next plane's arc length, origin, target normal, largest turn (degrees) and its
    thickness on the skeleton.

    That thickness is t, and the turn may use ``m·min(1 − f_min, f_max − 1)·t`` of it across
    the section, unless the bounds are lopsided (f_max − 1 < 1 − f_min: the thickness cap of
    :meth:`~slicer.settings.ProcessSettings.max_layer_share` at a large t) and the target
    needs more turn than that: then the plane sits at the middle of the bounds,
    (f_min + f_max)/2·t above the one below, and may use ``m·(f_max − f_min)/2·t`` (a thinner
    layer on the skeleton while it turns, rather than a turn that lags behind the curve)."""
    sym = min(1.0 - ms.f_min, ms.f_max - 1.0)
    half_span = 0.5 * (ms.f_max - ms.f_min)
    t_here, slack = ms.t, sym
    for _ in range(2):
        s = _advance(curve, s_prev, below, t_here)
        origin = curve.point(s)[0]
        origin = origin + (t_here - (origin - below[0]) @ below[1]) * below[1]  # t_here above
        aim = curve.tangent if direction is None else direction
        target = aim(np.array([s]))[0] if index else below[1]
        max_turn = _max_turn(TOL.turn_margin * slack * ms.t, radius)
        need = float(np.degrees(np.arccos(np.clip(target @ below[1], -1.0, 1.0))))
        lopsided = ms.f_max - 1.0 < 1.0 - ms.f_min  # the cap binds: thinner, not thicker
        if t_here != ms.t or not lopsided or need <= max_turn or radius <= 0:
            break
        t_here, slack = 0.5 * (ms.f_min + ms.f_max) * ms.t, half_span
    return s, origin, target, max_turn, t_here


def _max_turn(slack: float, radius: float) -> float:
    """Degrees a plane may turn so that ``slack`` mm of thickness spans ``radius``."""
    return float(np.degrees(np.arctan2(slack, radius))) if radius > 0 else 0.0


def _choose(solid: m3.Manifold, origin: np.ndarray, frame: np.ndarray,
            below: tuple[np.ndarray, np.ndarray], target: np.ndarray, max_turn: float,
            ms: MarchSettings, accept: Accept | None, subpart: int, index: int,
            t_here: float | None = None) -> LayerPlane | None:
    """The most-turned acceptable plane at ``origin`` (None once the part has ended)."""
    turn = max_turn if index else 0.0
    reason = None
    for k in range(MAX_HALVINGS + 2):
        n, ang = turn_toward(below[1], target, turn)
        f = transport_frame(frame, n)
        region, (lo, hi) = _try_plane(solid, origin, f, below, ms, t_here)
        if region.is_empty:
            return None
        ok_thick = ms.f_min * ms.t - 1e-9 <= lo and hi <= ms.f_max * ms.t + 1e-9
        reason = None if not ok_thick or accept is None else accept(origin, f, region)
        if ok_thick and reason is None:
            return LayerPlane(index, 0.0, origin, f, region, below, (lo, hi), ang, ms.t)
        turn = 0.0 if k >= MAX_HALVINGS else 0.5 * turn
        if ang == 0.0:
            break
    what = reason or "the layer-thickness bound"
    raise SlicingError(f"sub-part {subpart}, layer {index}: no plane clears {what}", subpart,
                       what)
