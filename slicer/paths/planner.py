"""Print planning: decomposition → skeleton curves → marched layers → toolpaths → PrintPlan.

:func:`plan_print` slices every sub-part in build order along its skeleton curve
(:mod:`slicer.paths.skeleton`, :mod:`slicer.paths.layers`), choosing A/C per layer with
:func:`kinematics.orient.solve_orientation` (C continuity) and vetoing planes whose A is out of
range or whose printhead would hold printed material or cross the platform (the turn is then
limited; :class:`SlicingError` names sub-part, layer and obstacle when even an unturned plane
fails). :func:`plan_planar` is the 3-axis control: one sub-part, horizontal layers, A = C = 0.

Paper §2.2.5 turns the table once per sub-part by the base normal (eqs. 7–8, whose arctan loses
the quadrant); here every layer has its own A/C from the two-solution solver.
"""

from __future__ import annotations

import contextlib
import logging
import time
from concurrent.futures import Executor, Future
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import manifold3d as m3
import numpy as np
import shapely
import trimesh
from scipy.spatial import cKDTree
from shapely.geometry.base import BaseGeometry

from kinematics.errors import UnreachableDirection
from kinematics.machine import MachineGeometry
from kinematics.orient import solve_orientation
from slicer.paths.child_tilt import cheapest_direction
from slicer.paths.evade import OBSTACLES, candidates, tilted
from slicer.paths.interfaces import ChildBase
from slicer.paths.layer_workers import layer_processes, start_stages
from slicer.paths.layers import (
    Direction,
    LayerPlane,
    MarchSettings,
    SlicingError,
    march_layers,
)
from slicer.paths.lean import LeanPlan
from slicer.paths.lean_costs import LEAN, LeanSettings
from slicer.paths.skeleton import SkeletonCurve, line_curve, skeleton_curve
from slicer.paths.subpart_paths import build_layers, pool, workers
from slicer.paths.thin_layers import Thinning, capper
from slicer.paths.upright import NO_HINTS, Leaned, LeanHints, lean_upright, turning_of
from slicer.plan import Layer, PrintPlan, SubpartPlan
from slicer.planes2d import from_plane, plane_frame, section, slicing_solid, unit
from slicer.printhead import Printhead
from slicer.settings import ProcessSettings

if TYPE_CHECKING:
    from slicer.decompose import Decomposition, Subpart

__all__ = ["SlicingError", "plan_planar", "plan_print"]

log = logging.getLogger(__name__)

OBSTACLE_SPACING = 1.0  # mm between obstacle samples (printed surfaces and outlines)
TIP_SPACING = 2.0  # mm between nozzle positions checked per layer
CANDIDATE_SLACK = 1e-6  # mm: margin of the pre-filter of obstacle heights (≫ rounding)
UP = np.array([0.0, 0.0, 1.0])
FAR_END = 2.0  # layer heights of a sub-part a fixed-direction march may leave above its last

_CURVES: dict[tuple, SkeletonCurve] = {}  # skeleton cache: (mesh hash, start, normal) → curve
_SOLIDS: dict[int, tuple[trimesh.Trimesh, m3.Manifold]] = {}  # id(mesh) → (mesh, solid)


@dataclass
class _Machine:
    """Per-plan state of the collision/orientation veto."""

    geometry: MachineGeometry
    head: Printhead | None
    subpart: int = 0
    c: float = 0.0
    pose: tuple[float, float] = (0.0, 0.0)
    fixed: bool = False  # planar control: A = C = 0 always
    parts: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # earlier sub-parts
    _outlines: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # grown by doubling
    _count: int = 0  # rows of _outlines in use

    @property
    def own(self) -> np.ndarray:
        """Outline samples of this sub-part's printed layers in print order, (n, 3) float."""
        return self._outlines[:self._count]

    def start(self, subpart: int) -> None:
        """Begin a sub-part: nothing of it printed yet."""
        self.subpart, self._count = subpart, 0

    def printed(self, outline: np.ndarray) -> None:
        """Add a printed layer's outline samples to the obstacles."""
        need = self._count + len(outline)
        if need > len(self._outlines):
            grown = np.empty((max(need, 2 * len(self._outlines), 1024), 3))
            grown[:self._count] = self.own
            self._outlines = grown
        self._outlines[self._count:need] = outline
        self._count = need

    def accept(self, origin: np.ndarray, frame: np.ndarray, region: BaseGeometry) -> str | None:
        """None if the plane can be printed, else the name of what is in the way."""
        n = frame[2]
        if self.fixed:
            self.pose = (0.0, 0.0)
        else:
            try:
                self.pose = solve_orientation(n, self.geometry, self.c)
            except UnreachableDirection:
                return "the A/C limits"
        if self.head is None:
            return None
        tips = _outline_xy(region, TIP_SPACING)
        if not len(tips):
            return None
        drop = self.head.lowest_point(origin, n) - origin[2]
        if from_plane(tips, origin, frame)[:, 2].min() + drop < -1e-9:
            return "platform"
        for obstacles in (self.parts, self.own):
            if _head_hits(self.head, obstacles, origin, frame, tips):
                return "printed part"
        return None


def _head_hits(head: Printhead, obstacles: np.ndarray, origin: np.ndarray, frame: np.ndarray,
               tips: np.ndarray) -> bool:
    """Whether the head, standing on any of the ``tips`` (k, 2) of the plane (origin, frame)
    along its normal, holds one of the ``obstacles`` (n, 3).

    All tips lie in one plane, so a point at height h above it is inside the head at some tip
    exactly when its in-plane distance to the nearest tip is below the head's radius at h:
    one nearest-neighbour query per point on a tree of the few tips (this is
    ``head.collisions(obstacles, tips, n).any()`` without the all-pairs search).
    """
    # candidates first, from a cheaper height with a margin far above its rounding error
    rough = obstacles @ frame[2] - float(origin @ frame[2])
    near = np.flatnonzero((rough > -CANDIDATE_SLACK) & (rough <= head.height + CANDIDATE_SLACK))
    rel = obstacles[near] - origin
    h = rel @ frame[2]
    keep = (h > 1e-9) & (h <= head.height)
    if not keep.any():
        return False
    q = rel[keep] @ frame[:2].T
    radius = head.radius_at(h[keep])
    d, _ = cKDTree(tips).query(q, distance_upper_bound=head.max_radius)
    return bool((d < radius).any())


def _outline_xy(region: BaseGeometry, spacing: float) -> np.ndarray:
    """Boundary samples of a 2D region, about one per ``spacing`` mm, (n, 2) float."""
    if region.is_empty:
        return np.zeros((0, 2))
    xy = shapely.get_coordinates(shapely.segmentize(region.boundary, spacing))
    step = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    keep = np.r_[0, np.flatnonzero(np.diff(np.floor(np.cumsum(step) / spacing))) + 1]
    return xy[keep]


def _outline(region: BaseGeometry, origin: np.ndarray, frame: np.ndarray,
             spacing: float) -> np.ndarray:
    """Boundary samples of a 2D region lifted to its plane, (n, 3) float."""
    return from_plane(_outline_xy(region, spacing), origin, frame)


def _surface_samples(mesh: trimesh.Trimesh, spacing: float) -> np.ndarray:
    """Vertices plus seeded area samples of a mesh surface, (n, 3) float."""
    count = int(mesh.area / spacing**2) + 1
    pts, _ = trimesh.sample.sample_surface(mesh, count, seed=0)
    return np.vstack([mesh.vertices, pts])


def _solid(mesh: trimesh.Trimesh) -> m3.Manifold:
    """The slicing solid of a sub-part mesh, built once per plan (a parent asks for its
    children's base sections before the children are sliced)."""
    key = id(mesh)
    if key not in _SOLIDS or _SOLIDS[key][0] is not mesh:
        if len(_SOLIDS) > 16:
            _SOLIDS.clear()
        _SOLIDS[key] = (mesh, slicing_solid(mesh))
    return _SOLIDS[key][1]


def _curve(mesh: trimesh.Trimesh, start: np.ndarray, normal: np.ndarray) -> SkeletonCurve:
    key = (mesh.identifier_hash, tuple(np.round(start, 6)), tuple(np.round(normal, 9)))
    if key not in _CURVES:
        if len(_CURVES) > 256:  # a long-lived slicing worker: keep the cache bounded
            _CURVES.clear()
        _CURVES[key] = skeleton_curve(mesh, start, normal)
    return _CURVES[key]


def clear_caches() -> None:
    """Forget the skeleton curves and slicing solids kept between plans of the same mesh
    (a benchmark that repeats a slice times it cold by calling this first)."""
    _CURVES.clear()
    _SOLIDS.clear()


def _base_centre(solid: m3.Manifold, point: np.ndarray, normal: np.ndarray,
                 t: float) -> tuple[np.ndarray, BaseGeometry, np.ndarray]:
    """Centre of the base section (on the base plane), the section and its frame."""
    frame = plane_frame(normal)
    sec = section(solid, point + 0.5 * t * frame[2], frame)
    if sec.is_empty:
        raise SlicingError(f"the base plane through {np.round(point, 2).tolist()} misses the part")
    c = shapely.centroid(sec)
    return from_plane([[c.x, c.y]], point, frame)[0], sec, frame


def _march(settings: ProcessSettings) -> MarchSettings:
    return MarchSettings(settings.layer_height, settings.min_layer_factor,
                         settings.max_layer_share())


@dataclass
class _Timer:
    laps: dict[str, float] = field(default_factory=dict)
    t: float = field(default_factory=time.perf_counter)

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.laps[name] = self.laps.get(name, 0.0) + now - self.t
        self.t = now


def _slice_subpart(index: int, mesh: trimesh.Trimesh, base: tuple[np.ndarray, np.ndarray, bool],
                   settings: ProcessSettings, machine: _Machine, timer: _Timer,
                   lean: LeanPlan | None = None, evade: tuple[np.ndarray, float] | None = None,
                   fixed: np.ndarray | None = None, thin: Thinning | None = None
                   ) -> tuple[list[LayerPlane], list[tuple[float, float]]]:
    """March one sub-part's layers; returns them with their (A, C).

    ``base`` is (point, normal, upright): an upright part (the root, the planar control) is
    sliced along the vertical through its base centre; others along their skeleton curve,
    their layers aimed ``evade = (away, degrees)`` off its tangent when given
    (:mod:`slicer.paths.evade`), or turned to the ``fixed`` normal (3,) when given
    (:mod:`slicer.paths.child_tilt`). A piece of the root with a ``lean`` plan is sliced along the
    root's axis from its base, its layers turning towards the plan's directions
    (:mod:`slicer.paths.lean`). With ``thin``, layers are thinner where the surface
    overhangs a little past what the nominal height holds (:mod:`slicer.paths.thin_layers`).
    """
    solid = _solid(mesh)
    centre, _, _ = _base_centre(solid, base[0], base[1], settings.layer_height)
    timer.lap("sections")
    direction: Direction | None = None
    if lean is not None:
        curve = line_curve(centre, lean.axis, float(np.ptp(mesh.vertices @ lean.axis)) + 1.0,
                           "axis")
        start = float((centre - lean.origin) @ lean.axis)

        def leaning(s: np.ndarray) -> np.ndarray:
            return lean.direction(np.asarray(s) + start)

        direction = leaning
    elif base[2]:
        curve = line_curve(centre, UP, float(np.ptp(mesh.vertices[:, 2])) + 1.0, "axis")
    else:
        curve = _curve(mesh, centre, base[1])
        if evade is not None:
            direction = tilted(curve, *evade)
        elif fixed is not None:
            direction = _constant(fixed)
    timer.lap("skeleton")
    poses: list[tuple[float, float]] = []
    machine.start(index)

    def accept(origin: np.ndarray, frame: np.ndarray, region: BaseGeometry) -> str | None:
        return machine.accept(origin, frame, region)

    layers = []
    cap = None if thin is None else capper(mesh, thin, index,
                                           None if base[2] else (centre, unit(base[1])[0][0]))
    for layer in march_layers(solid, curve, centre, base[1], _march(settings), accept, index,
                              direction, cap):
        layers.append(layer)
        poses.append(machine.pose)
        machine.c = machine.pose[1]
        machine.printed(_outline(layer.region, layer.origin, layer.frame, OBSTACLE_SPACING))
    timer.lap("layers")
    return layers, poses


def _reaches_the_end(mesh: trimesh.Trimesh, layers: list[LayerPlane], t: float) -> bool:
    """Whether the last of ``layers`` leaves at most ``FAR_END`` layer heights of ``mesh``
    above its plane (a march stops at the first empty section: across a gap in the part
    along its layers' normal, the rest would never be printed)."""
    if not layers:
        return False
    last = layers[-1]
    beyond = (np.asarray(mesh.vertices, dtype=float) - last.origin) @ last.frame[2]
    return float(beyond.max()) <= FAR_END * t


def _constant(normal: np.ndarray) -> Direction:
    """Layer normals that are ``normal`` (3,) at every arc length."""
    n = np.asarray(normal, dtype=float)

    def direction(arc: np.ndarray) -> np.ndarray:
        return np.tile(n, (len(np.atleast_1d(arc)), 1))

    return direction


def _child_base(index: int, mesh: trimesh.Trimesh, point: np.ndarray, normal: np.ndarray,
                t: float) -> ChildBase:
    _, sec, frame = _base_centre(_solid(mesh), point, normal, t)
    return ChildBase(index, np.asarray(point, dtype=float), frame, sec)


def plan_print(decomposition: Decomposition, settings: ProcessSettings, geometry: MachineGeometry,
               head: Printhead | None = None, lean: LeanSettings | None = None,
               hints: LeanHints = NO_HINTS, thin: Thinning | None = None) -> PrintPlan:
    """Slice a decomposition into a five-axis print plan.

    Parameters
    ----------
    decomposition : slicer.decompose.decomposition.Decomposition
        Sub-parts (``index``, ``parent``, ``mesh``, ``base_plane`` with ``point``/``normal``)
        and their build ``order``.
    settings : ProcessSettings
    geometry : MachineGeometry
    head : Printhead, optional
        Collision model (default :meth:`Printhead.default`); ``None`` disables nothing —
        pass ``Printhead.default()`` explicitly to be clear.
    lean : LeanSettings, optional
        How the root's layers lean against its overhangs (:mod:`slicer.paths.upright`);
        ``None`` (the first try of :func:`slicer.pipeline.slice_model`) keeps them square to
        the vertical, the paper's slicing.
    hints : LeanHints
        Where earlier tries printed walls in the air.
    thin : Thinning, optional
        Thinner layers where the surface overhangs a little too far for the layer height
        (:mod:`slicer.paths.thin_layers`); ``None``: every layer nominal.

    Returns
    -------
    PrintPlan
        Sub-parts in build order (the root possibly cut into stacked pieces where its lean
        jumps); ``timings`` has seconds per stage.

    Raises
    ------
    SlicingError
        A layer has no reachable, collision-free plane (names sub-part, layer, obstacle).
    """
    head = Printhead.default() if head is None else head
    try:
        return _plan(decomposition, settings, geometry, head, lean, hints, frozenset(), thin)
    except _Blocked as blocked:
        log.info("%s; printing sub-part %d before the root above it", blocked.error,
                 blocked.child)
        try:
            return _plan(decomposition, settings, geometry, head, lean or LEAN, hints,
                         frozenset({blocked.child}), thin)
        except SlicingError:
            raise blocked.error from None


class _Blocked(Exception):
    """The head could not reach a sub-part printed on the root past the finished root."""

    def __init__(self, error: SlicingError, child: int) -> None:
        super().__init__(str(error))
        self.error, self.child = error, child


def _plan(decomposition: Decomposition, settings: ProcessSettings, geometry: MachineGeometry,
          head: Printhead, lean: LeanSettings | None, hints: LeanHints, defer: frozenset[int],
          thin: Thinning | None = None) -> PrintPlan:
    """:func:`plan_print` with the root's children ``defer`` printed before the root above
    their base; raises :class:`_Blocked` when a sub-part on the root hit the printed root
    and nothing was deferred yet."""
    timer = _Timer()
    machine = _Machine(geometry, head)
    source = decomposition
    leaned = _leaned(decomposition, settings, head, lean, hints, defer)
    decomposition = leaned.decomposition
    timer.lap("lean")
    timer.laps.update(leaned.seconds)  # within "lean"
    subs = {s.index: s for s in decomposition.subparts}
    t = settings.layer_height
    threads = workers()
    with pool(threads) as leaf, pool(min(threads, len(subs))) as builder, \
            contextlib.ExitStack() as forks:
        procs: Executor | None = None
        marched = []
        for k in decomposition.order:  # marching reads the printed state: in build order
            sp = subs[k]
            base = _base_of(sp)
            fixed = None if k in leaned.plans else _child_direction(sp, decomposition,
                                                                    settings, lean, hints)
            try:
                layers, poses = _slice_evading(k, sp, base, settings, machine, timer,
                                               leaned.plans.get(k), fixed, thin)
            except SlicingError as exc:
                child = _blocked_child(exc, leaned, defer)
                if child is None:
                    raise
                raise _Blocked(exc, child) from exc
            kids = [_child_base(c.index, c.mesh, c.base_plane.point, c.base_plane.normal, t)
                    for c in decomposition.subparts
                    if c.parent == k and c.base_plane is not None]
            timer.lap("sections")
            if procs is None:  # forked for the first long sub-part, before any pool thread
                procs = forks.enter_context(layer_processes(len(layers)))
            # a long sub-part's stages 1-2 run in the workers while the others are marched
            staged = start_stages(layers, settings, sp.parent is None, kids, procs)
            marched.append((sp, base, layers, poses, kids, staged))
            machine.parts = np.vstack([machine.parts,
                                       _surface_samples(sp.mesh, OBSTACLE_SPACING)])
            timer.lap("obstacles")
        jobs = [builder.submit(build_layers, sp.index, layers, poses, settings,
                               sp.parent is None, kids, leaf, staged)
                for sp, _, layers, poses, kids, staged in marched]
        plans = [SubpartPlan(sp.index, sp.parent, None if sp.parent is None else base[0],
                             None if sp.parent is None else base[1],
                             np.asarray(sp.build_direction, dtype=float), _built(job, timer))
                 for (sp, base, *_), job in zip(marched, jobs, strict=True)]
    timer.lap("paths")
    volume = float(getattr(decomposition, "volume", sum(s.mesh.volume for s in subs.values())))
    return PrintPlan(np.asarray(decomposition.placement, dtype=float), plans, volume,
                     dict(timer.laps), getattr(decomposition, "base", None), source)


def _child_direction(sp: Subpart, decomposition: Decomposition, settings: ProcessSettings,
                     lean: LeanSettings | None, hints: LeanHints) -> np.ndarray | None:
    """The fixed layer normal a sub-part printed on another takes instead of its skeleton's
    against its overhang (:mod:`slicer.paths.child_tilt`), on a leaning try (``lean``)
    only: the paper's try slices along the skeleton."""
    if lean is None or sp.parent is None or sp.base_plane is None:
        return None
    point, normal = _base_of(sp)
    centre, _, _ = _base_centre(_solid(sp.mesh), point, normal, settings.layer_height)
    cuts = [sp.base_plane, *(c.base_plane for c in decomposition.subparts
                             if c.parent == sp.index and c.base_plane is not None)]
    return cheapest_direction(sp.mesh, _curve(sp.mesh, centre, normal), normal, cuts, lean,
                              hints.weights(sp.mesh))


def _slice_evading(k: int, sp: Subpart, base: tuple[np.ndarray, np.ndarray],
                   settings: ProcessSettings, machine: _Machine, timer: _Timer,
                   lean: LeanPlan | None, fixed: np.ndarray | None = None,
                   thin: Thinning | None = None
                   ) -> tuple[list[LayerPlane], list[tuple[float, float]]]:
    """:func:`_slice_subpart`, its layers first turned to the ``fixed`` normal when given
    (:mod:`slicer.paths.child_tilt`; along its skeleton when that march fails), and when
    the head meets printed material or the platform on a sub-part printed on another, again
    with its layers leaning away from it (:mod:`slicer.paths.evade`); the first error when
    no lean marches through."""
    c0 = machine.c
    if fixed is not None:
        try:
            out = _slice_subpart(k, sp.mesh, (*base, False), settings, machine, timer,
                                 fixed=fixed, thin=thin)
        except SlicingError as exc:
            log.info("sub-part %d with its layers square to %s: %s; along its skeleton "
                     "instead", k, np.round(fixed, 2).tolist(), exc)
        else:
            if _reaches_the_end(sp.mesh, out[0], settings.layer_height):
                log.info("sub-part %d: layers square to %s, not its skeleton (less "
                         "overhang)", k, np.round(fixed, 2).tolist())
                return out
            log.info("sub-part %d with its layers square to %s ends short of its far end; "
                     "along its skeleton instead", k, np.round(fixed, 2).tolist())
        machine.c = c0
    try:
        return _slice_subpart(k, sp.mesh, (*base, sp.parent is None), settings, machine,
                              timer, lean, thin=thin)
    except SlicingError as exc:
        if sp.parent is None or lean is not None or exc.obstacle not in OBSTACLES \
                or machine.head is None:
            raise
        first = exc
    for away, deg in candidates(str(first.obstacle), sp.mesh, base, machine.parts,
                                machine.head.reach):
        machine.c = c0
        try:
            out = _slice_subpart(k, sp.mesh, (*base, False), settings, machine, timer,
                                 evade=(away, deg), thin=thin)
        except SlicingError:
            continue
        log.info("%s; leaning its layers %.0f° towards %s instead", first, deg,
                 np.round(away, 2).tolist())
        return out
    machine.c = c0
    raise first


def _blocked_child(exc: SlicingError, leaned: Leaned, defer: frozenset[int]) -> int | None:
    """The root's child (original index) to print before the root above it, when ``exc``
    is a sub-part printed on the root that hit printed material and nothing is deferred."""
    if defer or exc.obstacle != "printed part" or exc.subpart is None:
        return None
    return leaned.child_of_root(exc.subpart)


def _leaned(decomposition: Decomposition, settings: ProcessSettings, head: Printhead,
            lean: LeanSettings | None, hints: LeanHints, defer: frozenset[int] = frozenset()
            ) -> Leaned:
    """The root's lean plan and stacked pieces (:func:`slicer.paths.upright.lean_upright`)."""
    subs = {s.index: s for s in decomposition.subparts}
    root = subs.get(decomposition.order[0]) if decomposition.order else None
    if lean is None or root is None or root.parent is not None:
        return Leaned(decomposition)
    t = settings.layer_height

    def centre(mesh: trimesh.Trimesh, point: np.ndarray, normal: np.ndarray) -> np.ndarray:
        return _base_centre(_solid(mesh), point, normal, t)[0]

    turning = turning_of(t, settings.min_layer_factor, settings.max_layer_share())
    return lean_upright(decomposition, _solid(root.mesh), centre, turning, head, lean, hints,
                        defer)


def _built(job: Future, timer: _Timer) -> list[Layer]:
    """A sub-part's layers from its build job, less the last ones without a path (a sliver
    of a section, narrower than a line); its CPU seconds go to the timer."""
    layers, seconds = job.result()
    for name, s in seconds.items():
        timer.laps[name] = timer.laps.get(name, 0.0) + s
    end = len(layers)
    while end > 1 and not layers[end - 1].paths:
        end -= 1
    return layers[:end]


def _base_of(sp: Subpart) -> tuple[np.ndarray, np.ndarray]:
    """Base plane (point, unit normal) of a sub-part; the platform z = 0 for the root."""
    if sp.base_plane is None:
        lo = sp.mesh.bounds[0]
        return np.array([0.0, 0.0, float(lo[2])]), UP.copy()
    n = np.asarray(sp.base_plane.normal, dtype=float)
    return np.asarray(sp.base_plane.point, dtype=float), n / np.linalg.norm(n)


def plan_planar(mesh: trimesh.Trimesh, settings: ProcessSettings,
                geometry: MachineGeometry, placement: np.ndarray | None = None) -> PrintPlan:
    """The 3-axis control: the whole part as one sub-part, horizontal layers, A = C = 0.

    No collision veto (a 3-axis print never tilts); ``mesh`` must already stand on z = 0.
    """
    timer = _Timer()
    machine = _Machine(geometry, None, fixed=True)
    base = (np.array([0.0, 0.0, float(mesh.bounds[0][2])]), UP.copy(), True)
    layers, poses = _slice_subpart(0, mesh, base, settings, machine, timer)
    with pool(workers()) as leaf, layer_processes(len(layers)) as procs:
        staged = start_stages(layers, settings, True, [], procs)
        plan_layers, seconds = build_layers(0, layers, poses, settings, True, [], leaf, staged)
    timer.lap("paths")
    timer.laps.update({k: timer.laps.get(k, 0.0) + v for k, v in seconds.items()})
    sub = SubpartPlan(0, None, None, None, UP.copy(), plan_layers)
    return PrintPlan(np.eye(4) if placement is None else np.asarray(placement, dtype=float),
                     [sub], float(mesh.volume), dict(timer.laps))
