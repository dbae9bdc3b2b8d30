"""Thinner layers where a sub-part's surface overhangs a little past the limit.

A wall that overhangs θ below a layer's plane steps ``t · tan θ`` outwards per layer, and
the caller's rule (the replay's, :func:`slicer.replay.held_heights`) holds it up to a height
that falls with θ: a ball wider than its stem meets it in a ring at 51–53° that no direction
of planar layers holds all round at 0.2 mm, but layers of 0.14 mm there do. Far steeper
surfaces (a bore's arch, a cut's underside) would need layers too thin to print
(``thinnest``): they are left to the decomposition and the lean, and do not thin a layer.

:func:`layer_cap` is the thickness of the next layer of a march: the nominal one, or (with
a margin, :data:`MARGIN`) the largest height that holds every face of the sub-part in the
slab one nominal layer above the plane below that such a height can hold at all. Only the
faces facing down across the layer count, each by the steepness of its own plane; the slab
is taken along the plane below's normal (a layer turns a few degrees at most). The layers
under a thinned one ramp down to it (``Thinning.step`` thicker a layer at most: each
layer's outline is its mid-height section, and a thin layer on a thick one would step out
over air even where the wall below is at 45°), so a face above the slab caps a layer too,
at its own height plus the ramp's rise to it.

:class:`Spots` thin layers by place instead of by slope: where a try's replay found walls
over air on a surface the rule holds at the nominal height (a wall at 45° whose layers turn
under it, a branch's first layers on its parent's flank), the layers through those points
are made again at :data:`SPOT_SHARE` of the height, the layers under them ramping down as
above; but a spot in the first layer of a sub-part printed on another makes that layer
*thicker* (``Thinning.first``): it stands on the parent's beads where their layers meet the
cut at an angle, in rows ``t / sin θ`` apart on the cut face, and the rule finds them within
a cone that widens with the layer's own height (a thinner first layer misses more of the
points between two rows; pipe12 and pipe32 of the sweep at 0.2 mm: parent's layers at 34°,
rows 0.36 mm apart). Beyond the paper, which prints every layer at one height.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import trimesh

from slicer.planes2d import TOL

MARGIN = 0.8
"""A thinned layer takes this share of the height the rule holds its steepest face at: the
bound is exact for a straight wall, and a curved one (a ball's underside between two
layers' sections), its faceting and the beads' corners take the rest (ball27 at 0.3 mm:
a layer at 0.237 mm where the rule held 0.239 left 8 % of its wall points over air)."""

SPOT_SHARE = 0.5
"""A layer through a spot (:class:`Spots`) takes this share of the nominal height (no less
than ``Thinning.thinnest``). Measured on the sweep's slices that kept one or two wall layers
over air at 0.2 and 0.3 mm: four of six held every wall sliced at 0.15 mm throughout
(``bench/hard_sweep.py``); half the height halves what a turning layer's edge steps out."""

HeldHeights = Callable[[np.ndarray], np.ndarray]
"""Overhang angles (k,) degrees → the layer heights (k,) mm the support rule holds them at
(inf where it holds them at any height)."""


@dataclass(frozen=True)
class Spots:
    """Where a try's walls were over air: points (k, 3), placed frame, and the sub-part
    (k,) int each was printed in (the plan's index)."""

    points: np.ndarray
    subpart: np.ndarray

    def of(self, index: int | None) -> np.ndarray:
        """The points (j, 3) of sub-part ``index`` (none for None)."""
        if index is None:
            return self.points[:0]
        return self.points[self.subpart == index]


NO_SPOTS = Spots(np.zeros((0, 3)), np.zeros(0, dtype=np.int64))


def any_height(angles: np.ndarray) -> np.ndarray:
    """A :data:`HeldHeights` that holds every surface at any height: thinning by
    :class:`Spots` only."""
    return np.full(len(np.atleast_1d(angles)), math.inf)


@dataclass(frozen=True)
class Thinning:
    """How a march thins its layers: the support rule's ``held`` heights, the thinnest
    layer worth printing and how much thicker a layer may be than the one on it (``step``,
    :func:`slicer.replay.thickness_step`), mm; and the ``spots`` whose layers are thinned
    whatever the slope there."""

    held: HeldHeights
    thinnest: float
    step: float = math.inf
    spots: Spots = NO_SPOTS
    first: float = 0.0
    """The first layer of a sub-part printed on another, through a spot, is this thick, mm
    (no thicker than a nominal layer plus ``step``: the next one, nominal, must not step
    out over a 45° wall); 0 (or no more than the nominal height): thinned like any other."""


@dataclass(frozen=True)
class SteepFaces:
    """A sub-part's surface for :func:`layer_cap`: vertices (v, 3), faces (f, 3) int and
    their unit normals (f, 3)."""

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray

    @classmethod
    def of(cls, mesh: trimesh.Trimesh) -> SteepFaces:
        """The faces of ``mesh`` (degenerate ones, without a normal, left out)."""
        normals = np.asarray(mesh.face_normals, dtype=float)
        keep = np.linalg.norm(normals, axis=1) > 0.5
        return cls(np.asarray(mesh.vertices, dtype=float),
                   np.asarray(mesh.faces, dtype=np.int64)[keep], normals[keep])


def layer_cap(surface: SteepFaces, origin: np.ndarray, normal: np.ndarray, t: float,
              thinning: Thinning, spots: np.ndarray | None = None, first: bool = False
              ) -> float:
    """The next layer's thickness above the plane (``origin``, unit ``normal``) below it,
    mm: ``t``, or less where a face of ``surface`` overhangs past what ``t`` holds and a
    layer no thinner than ``thinning.thinnest`` holds it: :data:`MARGIN` of the height that
    holds the steepest such face within ``t`` above that plane, or of one farther up plus
    the ramp's rise to it (``thinning.step`` a nominal layer height); no more than
    :func:`spot_cap` of ``spots`` (j, 3). The ``first`` layer of a sub-part printed on
    another may be thicker (:func:`first_cap`) where no face asks for a thinner one."""
    slopes = _slope_cap(surface, origin, normal, t, thinning)
    if spots is None:
        return slopes
    if first and slopes >= t:
        thick = first_cap(spots, origin, normal, t, thinning)
        if thick > t:
            return thick
    return min(slopes, spot_cap(spots, origin, normal, t, thinning))


def first_cap(spots: np.ndarray, origin: np.ndarray, normal: np.ndarray, t: float,
              thinning: Thinning) -> float:
    """The thickness of a first layer on a parent's cut (``origin``, unit ``normal``) for
    the ``spots`` (j, 3): ``thinning.first`` when one lies in the slab that thick above the
    cut, else ``t``."""
    if thinning.first <= t or not len(spots):
        return t
    h = (np.asarray(spots, dtype=float) - np.asarray(origin, dtype=float)) @ normal
    inside = (h > 0.0) & (h <= thinning.first + 1e-6)
    return float(thinning.first) if inside.any() else t


def _ramp(thinning: Thinning, t: float) -> float:
    """mm of thickness a layer may gain per mm below a thinned one."""
    return MARGIN * thinning.step / t


def spot_cap(spots: np.ndarray, origin: np.ndarray, normal: np.ndarray, t: float,
             thinning: Thinning) -> float:
    """The next layer's thickness above the plane (``origin``, unit ``normal``) for the
    ``spots`` (j, 3): :data:`SPOT_SHARE` of ``t`` (no less than ``thinning.thinnest``) when
    one lies in the slab ``t`` above the plane, the ramp's rise more for one above it, else
    ``t``."""
    target = max(SPOT_SHARE * t, thinning.thinnest)
    if not len(spots) or target >= t:
        return t
    h = (np.asarray(spots, dtype=float) - np.asarray(origin, dtype=float)) @ normal
    ramp = _ramp(thinning, t)
    reach = t + (t - target) / ramp if ramp > 0 else t
    ahead = h[(h > 0.0) & (h < reach)]
    if not len(ahead):
        return t
    return float(min(target + ramp * np.maximum(ahead - t, 0.0).min(), t))


def _slope_cap(surface: SteepFaces, origin: np.ndarray, normal: np.ndarray, t: float,
               thinning: Thinning) -> float:
    """:func:`layer_cap` by the faces' slopes alone."""
    height = (surface.vertices - np.asarray(origin, dtype=float)) @ normal
    h = height[surface.faces]
    lowest = h.min(axis=1)
    ramp = _ramp(thinning, t)
    reach = t + (t - thinning.thinnest) / ramp if ramp > 0 else t
    near = (lowest < reach) & (h.max(axis=1) > 0.0)
    down = -(surface.normals[near] @ normal)
    steep = down > np.sin(np.radians(45.0))  # held at any height up to 45° (``held``: inf)
    if not steep.any():
        return t
    angles = np.degrees(np.arcsin(np.clip(down[steep], -1.0, 1.0)))
    held = MARGIN * thinning.held(angles)
    # a face above this layer's slab: the layers up to it ramp down to its height
    above = lowest[near][steep] - t
    rise = np.zeros(len(above))
    rise[above > 0.0] = ramp * above[above > 0.0]
    fixable = (held >= thinning.thinnest) & (held < t)
    caps = held[fixable] + rise[fixable]
    return float(min(caps.min(), t)) if len(caps) else t


def capper(mesh: trimesh.Trimesh, thinning: Thinning, index: int | None = None,
           base: tuple[np.ndarray, np.ndarray] | None = None
           ) -> Callable[[np.ndarray, np.ndarray, float], float]:
    """:func:`layer_cap` over the surface of ``mesh``, sub-part ``index`` (its spots), as a
    march takes it (``thin(origin, normal, t)``); ``base`` (point, unit normal): the plane a
    sub-part printed on another starts on (its first layer is the one above it)."""
    surface = SteepFaces.of(mesh)
    spots = thinning.spots.of(index)

    def thin(origin: np.ndarray, normal: np.ndarray, t: float) -> float:
        first = base is not None and on_plane(origin, normal, base)
        return layer_cap(surface, origin, normal, t, thinning, spots, first)

    return thin


def on_plane(origin: np.ndarray, normal: np.ndarray,
             plane: tuple[np.ndarray, np.ndarray]) -> bool:
    """Whether the plane (``origin``, unit ``normal``) is ``plane`` (point, unit normal),
    to ``TOL.same``: a march's first plane is its base itself."""
    across = abs(float((np.asarray(origin, dtype=float) - plane[0]) @ plane[1]))
    return (across < TOL.same
            and float(np.asarray(normal, dtype=float) @ plane[1]) > 1.0 - TOL.same)
