"""What each candidate layer direction costs along an upright sub-part, band by band.

The layers of an upright sub-part (the root, standing on the platform) march along a straight
axis; :mod:`~slicer.paths.lean` lets their normals *lean* off it where that keeps the part's
surface within the overhang limit. This module prices the candidates. The axis is cut into
bands of ``band`` mm; a candidate is a unit direction ``d`` within ``max_tilt`` of the axis,
on a grid of the tangent plane (:class:`DirectionGrid`).

* **Overhang**: a face prints in the layer whose plane (normal ``d``, through an axis point)
  holds it, so it counts in the band where that plane crosses the axis,
  ``s = (c · d) / (a · d)`` (c the face centre from the origin, a the axis). It costs its area
  times a hinge of how far its normal points below that layer: nothing up to ``soft_deg``
  below the layer's plane, its whole area from ``hard_deg``. Faces the retry hints at
  (:class:`Column` ``margins``) start and end that many degrees sooner.
* **Flat tops**: a large flat face square to the axis (a base disc's top) printed in tilted
  layers turns into a staircase of thin slivers over sparse infill; tilting in its band costs
  its area.
* **Jumps**: a jump at band ``b`` to ``d`` cuts the part there by the plane square to ``d``
  (:mod:`~slicer.paths.columns`); what lies below that plane but above band ``b`` along the
  axis is printed by the piece below, in its last direction, which the price of a jump cannot
  know: every face there that faces down costs its area (:attr:`LeanCosts.jump_penalty`). A
  jump may not cut a child's base (:attr:`LeanCosts.jump_ok`).
* **Platform**: a direction whose layer, reaching as far down as the part's extent allows,
  would put the head below the platform is not allowed (:attr:`LeanCosts.allowed`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import trimesh

from slicer.decompose import Plane, overhanging_faces
from slicer.printhead import Printhead

CHUNK = 96  # candidate directions priced at once: (faces, CHUNK) temporaries


@dataclass(frozen=True)
class LeanSettings:
    """Knobs of the lean plan, in one place.

    Attributes
    ----------
    band : float
        mm of the axis per decision.
    step_deg : float
        Spacing of the candidate directions on the tangent plane, degrees.
    max_tilt : float
        Largest lean off the axis, degrees.
    soft_deg, hard_deg : float
        Overhang below a layer's plane at which a face starts to cost, and costs its area.
        The replay holds a bead whose offset from the one under it is at most
        ``t·tan 45° + 0.1 w`` (:mod:`slicer.replay.support`): 51° at 0.2 mm, 49° at
        0.3 mm (w 0.45 mm). The hinge spans 44–49°, up to that limit: a narrower one (35–45°, before
        2026-12-06) priced a 45° lean at a bore's arch as a full overhang, so the plan chose
        less lean there to spare the far wall and left the arch over air (the sweep of
        unseen variants, ``bench/hard_sweep.py --variants 16``: 3 of 16 support-free with
        35–45°, 7 of 16 with 44–49°). A face the replay still finds over air is priced
        sooner on the retry (:class:`Column` ``margins``).
    wall_deg, wall_slack : float
        Faces within ``wall_deg`` of parallel to the axis (plain walls, which a lean tilts
        evenly) take ``wall_slack`` degrees more on both limits: their beads stack with the
        full slack of the replay's cone.
    jump_cost : float
        mm² of overhang a jump (another stacked piece, one more table turn) is worth.
    tilt_cost, turn_cost : float
        mm² per degree of lean per band, and per degree of turn: a lean that saves nothing is
        not taken.
    rate_margin : float
        Share of the march's largest turn per layer the plan counts on.
    flat_area, flat_deg : float
        Flat faces at least this large (mm²) and this square to the axis keep their band's
        layers parallel to them.
    clearance : float
        mm the head stays above the platform.
    """

    band: float = 2.0
    step_deg: float = 2.0
    max_tilt: float = 50.0
    soft_deg: float = 44.0
    hard_deg: float = 49.0
    wall_deg: float = 15.0
    wall_slack: float = 2.0
    jump_cost: float = 5.0
    tilt_cost: float = 0.002
    turn_cost: float = 0.005
    rate_margin: float = 0.85
    flat_area: float = 10.0
    flat_deg: float = 2.0
    clearance: float = 0.3


LEAN = LeanSettings()  # the defaults


@dataclass(frozen=True)
class DirectionGrid:
    """Candidate directions: a square grid of the plane tangent to the axis at its tip.

    Attributes
    ----------
    local : (n, n, 3) float
        Unit directions in the axis frame (z along the axis); cell ``(k, k)`` is the axis.
    inside : (n, n) bool
        Cells within the largest tilt.
    step : float
        Grid spacing on the tangent plane (tangent of the angle).
    """

    local: np.ndarray
    inside: np.ndarray
    step: float

    @classmethod
    def make(cls, max_tilt: float, step_deg: float) -> DirectionGrid:
        """The grid out to ``max_tilt`` degrees with spacing ``step_deg`` degrees."""
        step = math.radians(step_deg)
        reach = math.tan(math.radians(max_tilt))
        k = math.ceil(reach / step)
        ax = np.arange(-k, k + 1) * step
        gx, gy = np.meshgrid(ax, ax, indexing="ij")
        d = np.stack([gx, gy, np.ones_like(gx)], axis=-1)
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        return cls(d, gx * gx + gy * gy <= reach * reach + 1e-12, step)

    @property
    def centre(self) -> int:
        """Index ``k`` of the axis cell ``(k, k)``."""
        return self.inside.shape[0] // 2

    @property
    def tilt(self) -> np.ndarray:
        """Angle of every cell off the axis, degrees, (n, n)."""
        return np.degrees(np.arccos(np.clip(self.local[..., 2], -1.0, 1.0)))

    def world(self, frame: np.ndarray) -> np.ndarray:
        """The directions in the part's frame, (n, n, 3); ``frame`` rows are u, v, axis."""
        return self.local @ np.asarray(frame, dtype=float)


@dataclass
class LeanCosts:
    """The priced candidates of one sub-part (``nb`` bands, an (n, n) grid).

    Attributes
    ----------
    overhang : (nb, n, n) float
        mm² of weighted overhang (and flat tops) of leaning so in each band.
    allowed : (nb, n, n) bool
        The head clears the platform.
    jump_penalty : (nb, n, n) float
        What a jump there leaves to the piece below.
    jump_ok : (nb, n, n) bool
        A jump there cuts no child's base and is allowed.
    upright : float
        Overhang cost of printing the whole sub-part along the axis.
    forced : (nb,) bool
        Bands where the plan must jump (a cut the build order needs).
    stranded : Stranded or None
        The faces a jump leaves to the piece below, priced once the piece's last direction
        is known (the plan's dynamic programme asks); None: ``jump_penalty`` alone.
    """

    overhang: np.ndarray
    allowed: np.ndarray
    jump_penalty: np.ndarray
    jump_ok: np.ndarray
    upright: float
    forced: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    stranded: Stranded | None = None

    def __post_init__(self) -> None:
        if len(self.forced) != len(self.overhang):
            self.forced = np.zeros(len(self.overhang), dtype=bool)


@dataclass(frozen=True)
class Column:
    """An upright sub-part as the lean plan sees it.

    Attributes
    ----------
    mesh : trimesh.Trimesh
        The sub-part (platform frame).
    origin : (3,) float
        Where its axis starts (the centre of its base).
    frame : (3, 3) float
        Rows u, v, axis.
    cuts : sequence of Plane
        Its children's base planes (faces on them are not its surface).
    child_bases : sequence of (k, 3) float
        Points of each child's base section, which no jump may cut.
    profile : ((m,) float, (m,) float)
        Heights along the axis and the part's largest distance from the axis there.
    weights : (f,) float or None
        Extra weight of each face (the retry's unsupported walls).
    margins : (f,) float or None
        Degrees by which each face's overhang limits are stricter (the retry's hints).
    """

    mesh: trimesh.Trimesh
    origin: np.ndarray
    frame: np.ndarray
    cuts: Sequence[Plane]
    child_bases: Sequence[np.ndarray]
    profile: tuple[np.ndarray, np.ndarray]
    weights: np.ndarray | None = None
    margins: np.ndarray | None = None

    @property
    def axis(self) -> np.ndarray:
        """Unit axis, (3,)."""
        return np.asarray(self.frame[2], dtype=float)


def hinge(ndot: np.ndarray, soft_deg: float | np.ndarray, hard_deg: float | np.ndarray
          ) -> np.ndarray:
    """Share of a face's area that counts, from ``n · d`` (its normal on the layer's):
    0 up to ``soft_deg`` below the layer's plane, 1 from ``hard_deg``, linear in the sine
    between (the limits may be per face, broadcast against ``ndot``)."""
    lo, hi = np.sin(np.radians(soft_deg)), np.sin(np.radians(hard_deg))
    return np.clip((-ndot - lo) / (hi - lo), 0.0, 1.0)


def lean_costs(column: Column, n_bands: int, grid: DirectionGrid, head: Printhead,
               settings: LeanSettings) -> LeanCosts:
    """Price every candidate of ``grid`` in every band of ``column``.

    Parameters
    ----------
    column : Column
    n_bands : int
        Bands of ``settings.band`` mm from the origin along the axis.
    grid : DirectionGrid
    head : Printhead
        For the platform clearance.
    settings : LeanSettings

    Returns
    -------
    LeanCosts
    """
    dirs = grid.world(column.frame)
    faces = _faces(column, settings)
    over, penalty = _overhang(faces, dirs, grid.inside, n_bands, column.axis, settings)
    over += _flat_tops(column, n_bands, settings)[:, None, None] * np.clip(
        grid.tilt / max(settings.flat_deg, 1e-9), 0.0, 1.0)[None]
    allowed = _platform(column, dirs, grid, n_bands, head, settings) & grid.inside[None]
    jump_ok = allowed & _unbroken(column, dirs, n_bands, settings)
    k = grid.centre
    return LeanCosts(over, allowed, penalty, jump_ok, float(over[:, k, k].sum()),
                     stranded=Stranded(faces, dirs.reshape(-1, 3), column.axis,
                                       settings.band, grid.inside.shape))


@dataclass(frozen=True)
class Stranded:
    """What a jump leaves to the piece below it, priced in that piece's last direction.

    A jump at band ``b`` cuts the part by the plane square to the new direction ``d``
    through the axis at the band's middle. A face under that cut is printed by the piece
    below; if its layer in the piece's last direction ``e`` crosses the axis at band ``b``
    or later (``s(e) >= b · band``: the piece's bands before the jump never reached it), the
    piece prints it in ``e`` past its last band (:meth:`~slicer.paths.lean.LeanPlan.piece`),
    and it costs its overhang on ``e``. The per-band price (:func:`_overhang`) sees such a
    face in no band, and ``jump_penalty`` guesses without ``e``: a bore's arch just under a
    cut went unpriced, and unhinted (pipe3_15 at 0.2 mm). ``e`` is known only while the plan
    is solved (the cell a jump leaves from), so the plan asks (:meth:`penalty`).
    """

    faces: _Faces
    dirs: np.ndarray  # (m, 3) every grid cell's world direction
    axis: np.ndarray
    band: float
    shape: tuple[int, int]

    def penalty(self, b: int, cell: tuple[int, int]) -> np.ndarray:
        """Weighted overhang left below a jump at band ``b`` to each direction, from the
        grid ``cell`` (the piece's last direction), (n, n)."""
        f = self.faces
        e = self.dirs.reshape(*self.shape, 3)[cell]
        s_low = (f.centre @ e) / float(e @ self.axis)
        w = f.cost((f.normal @ e)[:, None])[:, 0]
        sel = np.flatnonzero((s_low >= b * self.band) & (w > 0.0))
        out = np.zeros(len(self.dirs))
        cut = (b + 0.5) * self.band
        along = self.dirs @ self.axis
        for lo in range(0, len(sel), CHUNK * 8):  # (faces, m) temporaries stay bounded
            rows = sel[lo:lo + CHUNK * 8]
            under = (f.centre[rows] @ self.dirs.T) / along[None, :] < cut
            out += w[rows] @ under
        return out.reshape(self.shape)


@dataclass(frozen=True)
class _Faces:
    """The faces that may cost: centres from the origin (f, 3), normals (f, 3), weighted
    areas (f,), heights along the axis (f,), their overhang limits (f,) each, their cost
    printed along the axis (f,) and left below a jump's cut (f,)."""

    centre: np.ndarray
    normal: np.ndarray
    area: np.ndarray
    height: np.ndarray
    soft: np.ndarray
    hard: np.ndarray
    upright: np.ndarray
    stranded: np.ndarray

    def cost(self, ndot: np.ndarray) -> np.ndarray:
        """Weighted overhang of the faces at ``n · d`` (f, m), (f, m)."""
        return hinge(ndot, self.soft[:, None], self.hard[:, None]) * self.area[:, None]


def _faces(column: Column, settings: LeanSettings) -> _Faces:
    """Faces of the column that can overhang for some candidate (a normal within
    ``90 - soft + max_tilt`` degrees of the axis, reversed), cuts and platform excluded."""
    mesh, axis = column.mesh, column.axis
    reach = 90.0 - settings.soft_deg + settings.max_tilt
    keep = overhanging_faces(mesh, axis, column.cuts, on_platform=True,
                             limit_deg=90.0 - reach)
    area = np.asarray(mesh.area_faces, dtype=float)
    if column.weights is not None:
        area = area * column.weights
    c = np.asarray(mesh.triangles_center, dtype=float)[keep] - column.origin
    n = np.asarray(mesh.face_normals, dtype=float)[keep]
    a = area[keep]
    margin = np.zeros(len(a)) if column.margins is None else column.margins[keep]
    plain = np.abs(n @ axis) < np.sin(np.radians(settings.wall_deg))
    margin = margin - np.where(plain, settings.wall_slack, 0.0)
    soft, hard = settings.soft_deg - margin, settings.hard_deg - margin
    up = hinge(n @ axis, soft, hard) * a
    down = hinge(n @ axis, 0.0, 20.0) * a  # facing down: wrong in most directions below a cut
    return _Faces(c, n, a, c @ axis, soft, hard, up, np.maximum(up, down))


def _overhang(faces: _Faces, dirs: np.ndarray, inside: np.ndarray, n_bands: int,
              axis: np.ndarray, settings: LeanSettings) -> tuple[np.ndarray, np.ndarray]:
    """(overhang, jump penalty), each (nb, n, n): every face in the band where its layer
    crosses the axis, and the faces a jump's cut leaves below it.

    Sparse: a face costs in the few directions that leave it past its soft limit (7 % of
    the pairs on pipe3_15 at 50 000 faces) and is left below a cut only if it may cost
    there at all (``stranded``, 37 % of the faces), so only those pairs are banded and
    summed, in the order a dense sum takes them (the sums are the same, bit for bit)."""
    shape = inside.shape
    cells = np.flatnonzero(inside.ravel())
    flat = dirs.reshape(-1, 3)
    over = np.zeros((n_bands, flat.shape[0]))
    penalty = np.zeros((n_bands, flat.shape[0]))
    own = _band(faces.height, n_bands, settings.band)
    lo = np.sin(np.radians(faces.soft))
    left = np.flatnonzero(faces.stranded > 0.0)
    for start in range(0, len(cells), CHUNK):
        idx = cells[start:start + CHUNK]
        d = flat[idx]  # (m, 3)
        along = d @ axis
        centre = faces.centre @ d.T  # (f, m): each layer meets the axis at centre / along
        over[:, idx] = _costly(faces, centre, faces.normal @ d.T, along, lo, n_bands,
                               settings.band)
        penalty[:, idx] = _left_below(faces, centre[left], along, own, left, n_bands,
                                      settings.band)
    return over.reshape((n_bands, *shape)), penalty.reshape((n_bands, *shape))


def _costly(faces: _Faces, centre: np.ndarray, ndot: np.ndarray, along: np.ndarray,
            lo: np.ndarray, n_bands: int, band: float) -> np.ndarray:
    """Overhang per band of ``m`` directions, (nb, m), from every face's ``centre · d`` and
    ``n · d`` (f, m), ``a · d`` (m,) and soft limit's sine ``lo`` (f,): the pairs past the
    soft limit only."""
    rows, col = np.nonzero(ndot < -lo[:, None])  # -n·d past the sine: no (f, m) negation
    w = hinge(ndot[rows, col], faces.soft[rows], faces.hard[rows]) * faces.area[rows]
    b = _band(centre[rows, col] / along[col], n_bands, band)
    return _summed(b, col, w, n_bands, len(along))


def _left_below(faces: _Faces, centre: np.ndarray, along: np.ndarray, own: np.ndarray,
                left: np.ndarray, n_bands: int, band: float) -> np.ndarray:
    """Jump penalty per band of ``m`` directions, (nb, m): the faces ``left`` (k,) (those
    that may cost below a cut; ``centre`` (k, m) theirs) whose layer crosses the axis below
    their own band ``own`` (f,) are left below a jump's cut anywhere between."""
    b = _band(centre / along[None, :], n_bands, band)
    rows, col = np.nonzero(b < own[left, None])
    mine = left[rows]
    w = faces.stranded[mine]
    m = len(along)
    diff = (_summed(b[rows, col] + 1, col, w, n_bands + 1, m)
            - _summed(own[mine] + 1, col, w, n_bands + 1, m))
    return np.cumsum(diff, axis=0)[:n_bands]


def _band(s: np.ndarray, n_bands: int, band: float) -> np.ndarray:
    """Band index of axis positions ``s``, clipped into [0, n_bands)."""
    return np.clip(np.floor(s / band).astype(np.int64), 0, n_bands - 1)


def _summed(b: np.ndarray, col: np.ndarray, w: np.ndarray, n_bands: int, m: int
            ) -> np.ndarray:
    """Sums of ``w`` (k,) by (band ``b`` (k,), column ``col`` (k,)) in their order:
    (n_bands, m); bands past ``n_bands`` are dropped."""
    flat = np.bincount(b * m + col, weights=w, minlength=n_bands * m)
    return flat[:n_bands * m].reshape(n_bands, m)


def _flat_tops(column: Column, n_bands: int, settings: LeanSettings) -> np.ndarray:
    """Area of large flat faces facing along the axis per band (and the band below), (nb,)."""
    mesh, axis = column.mesh, column.axis
    top = np.zeros(len(mesh.faces), dtype=bool)
    cos = math.cos(math.radians(settings.flat_deg))
    for idx, area, normal in zip(mesh.facets, mesh.facets_area, mesh.facets_normal,
                                 strict=True):
        if area >= settings.flat_area and float(normal @ axis) > cos:
            top[idx] = True
    out = np.zeros(n_bands)
    if top.any():
        h = (np.asarray(mesh.triangles_center)[top] - column.origin) @ axis
        out = np.bincount(_band(h, n_bands, settings.band),
                          weights=np.asarray(mesh.area_faces)[top],
                          minlength=n_bands).astype(float)
    return np.maximum(out, np.r_[out[1:], 0.0])


def _platform(column: Column, dirs: np.ndarray, grid: DirectionGrid, n_bands: int,
              head: Printhead, settings: LeanSettings) -> np.ndarray:
    """Which candidates keep the head above the platform in each band, (nb, n, n).

    A layer through the axis at height ``s`` tilted by θ reaches down to the lowest height
    ``z`` where the part's extent ``R(z)`` meets it, ``R(z) ≥ (s − z) / tan θ``; the head
    then reaches ``drop(θ)`` below that (:meth:`Printhead.lowest_point`)."""
    z, radius = column.profile
    tilt = np.radians(grid.tilt).ravel()
    drop = np.array([head.lowest_point(np.zeros(3), d) for d in grid.local.reshape(-1, 3)])
    s = (np.arange(n_bands) + 0.25) * settings.band  # low in the band: conservative
    tilts, of_tilt = np.unique(tilt, return_inverse=True)  # the reach depends on the tilt only
    reach = (s[:, None, None] - z[None, :, None]) / np.maximum(np.tan(tilts), 1e-9)[None, None]
    hit = (radius[None, :, None] >= reach) & (z[None, :, None] <= s[:, None, None])
    low = np.minimum(np.where(hit, z[None, :, None], np.inf).min(axis=1), s[:, None])
    low = low[:, of_tilt.ravel()]
    base = float(column.origin @ np.array([0.0, 0.0, 1.0]))
    ok = (low + base + drop[None, :] >= settings.clearance) | (tilt < 1e-9)[None, :]
    return ok.reshape((n_bands, *grid.inside.shape))


def _unbroken(column: Column, dirs: np.ndarray, n_bands: int,
              settings: LeanSettings) -> np.ndarray:
    """Which (band, direction) cuts keep every child's base on one side, with 1 mm to
    spare, (nb, n, n)."""
    shape = dirs.shape[:2]
    ok = np.ones((n_bands, *shape), dtype=bool)
    flat = dirs.reshape(-1, 3)
    s = (np.arange(n_bands) + 0.5) * settings.band
    for pts in column.child_bases:
        if not len(pts):
            continue
        at = ((np.asarray(pts) - column.origin) @ flat.T) / (flat @ column.axis)[None, :]
        lo, hi = at.min(axis=0) - 1.0, at.max(axis=0) + 1.0
        ok &= ~((s[:, None] >= lo[None, :]) & (s[:, None] <= hi[None, :])).reshape(
            (n_bands, *shape))
    return ok
