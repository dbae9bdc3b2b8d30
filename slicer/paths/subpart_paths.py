"""Toolpaths of one sub-part's marched layers, with the per-layer work on a thread pool.

What a layer's paths need splits in three:

1. its shell (perimeters, gap fill, fill domain) needs only its own region;
2. its solid, wall-footing and interface zones and its fill lines need the shells and regions
   of a few neighbours;
3. the order of its paths (greedy from where the nozzle is) needs the previous layer's last
   point, and so do the wall pieces split at an interface and what they leave of it.

Stages 1 and 2 are independent per layer and run on a thread pool (shapely releases the GIL
while GEOS works, so two cores offset most of the polygon booleans); stage 3 runs in layer
order. Every layer is computed by the same calls on the same inputs as in a plain loop, and
results are collected in layer order, so the plan does not depend on the pool or on timing.

The planner marches every sub-part first and builds their paths on threads afterwards:
running the pool beside the marching made the marching wait for the GIL after each numpy or
GEOS call (manifold3d and CGAL keep it while they work), which cost more than the overlap
gained.

A sub-part of many layers (the root of a branched part holds most of them) has its stages 1
and 2 computed in worker processes instead (:mod:`slicer.paths.layer_workers`), started as soon as
it is marched; :func:`build_layers` then reads them layer by layer in stage 3.

Stage timings are CPU seconds of the threads doing the work (:func:`time.thread_time`),
summed over tasks: on two cores they add up to more than the wall time.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from concurrent.futures import Executor, Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Protocol, TypeVar, overload

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from slicer.cores import free_cores
from slicer.paths.interfaces import ChildBase, layer_interface
from slicer.paths.layers import LayerPlane, local_thickness
from slicer.paths.toolpaths import FillSpec, Path2D, Shell, fill_paths, layer_paths, shell
from slicer.paths.zones import solid_zone, wall_footing
from slicer.plan import Layer, Path
from slicer.planes2d import from_plane, polygonal
from slicer.settings import ProcessSettings

T = TypeVar("T")
T_co = TypeVar("T_co", covariant=True)
MAX_WORKERS = 4


class Pending(Protocol[T_co]):
    """A result to come: a future, or a layer's part of a chunk computed by the workers."""

    def result(self) -> T_co: ...


class InlineExecutor(Executor):
    """Runs each task when it is submitted, in the caller's thread (no pool)."""

    def submit(self, fn: Callable[..., T], /, *args: object, **kwargs: object) -> Future[T]:
        done: Future[T] = Future()
        try:
            done.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # delivered by result(), as a pool would
            done.set_exception(exc)
        return done


def workers() -> int:
    """Threads for the per-layer polygon work: one per core not busy with other work (by the
    1-min load average, less the one thread of this slice), at most :data:`MAX_WORKERS`;
    1 means inline. On a busy machine two threads only fight for the GIL and one core."""
    return min(MAX_WORKERS, free_cores())


def pool(threads: int) -> Executor:
    """A thread pool of ``threads``, or an :class:`InlineExecutor` for one."""
    return ThreadPoolExecutor(threads) if threads > 1 else InlineExecutor()


def fill_spec(settings: ProcessSettings) -> FillSpec:
    """The fill parameters of the process settings."""
    return FillSpec(settings.line_width, settings.perimeters, settings.infill_density,
                    settings.infill_angle)


def timed(fn: Callable[..., T], *args: object) -> tuple[T, float]:
    """``fn(*args)`` and the CPU seconds of the calling thread it took."""
    t = time.thread_time()
    out = fn(*args)
    return out, time.thread_time() - t


@dataclass
class Zones:
    """A layer's stage-2 results."""

    solid: BaseGeometry
    interface: BaseGeometry
    owner: int | None
    fill: list[Path2D]


Staged = tuple[list[tuple[Shell, float]], list[tuple[Zones, float, float]]]  # of a chunk
Stages = tuple[Sequence[Pending[tuple[Shell, float]]],  # shells and zones of every layer
                Sequence[Pending[tuple[Zones, float, float]]]]


def _union(a: BaseGeometry, b: BaseGeometry) -> BaseGeometry:
    """a ∪ b, without a boolean when either is empty."""
    if b.is_empty:
        return a
    return b if a.is_empty else polygonal(shapely.union(a, b), valid=True)


class _Shells(Sequence[BaseGeometry]):
    """One attribute ("domain", "inner") of the layers' shells, read from their futures."""

    def __init__(self, shells: Sequence[Pending[tuple[Shell, float]]], attr: str) -> None:
        self.shells, self.attr = shells, attr

    def __len__(self) -> int:
        return len(self.shells)

    @overload
    def __getitem__(self, i: int) -> BaseGeometry: ...

    @overload
    def __getitem__(self, i: slice) -> list[BaseGeometry]: ...

    def __getitem__(self, i: int | slice) -> BaseGeometry | list[BaseGeometry]:
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(len(self)))]
        return getattr(self.shells[i].result()[0], self.attr)


@dataclass
class LayerJob:
    """What every layer of one sub-part shares in stage 2 (shells as futures: a layer's
    stage 2 reads only its own shell and the next one's)."""

    layers: Sequence[LayerPlane]
    shells: Sequence[Pending[tuple[Shell, float]]]
    settings: ProcessSettings
    grounded: bool
    bases: list[ChildBase]

    def zones(self, i: int) -> tuple[BaseGeometry, BaseGeometry, int | None]:
        """Layer i's solid zone (skins and wall footing), interface zone and its child."""
        s = self.settings
        domains, inners = _Shells(self.shells, "domain"), _Shells(self.shells, "inner")
        solid = _union(solid_zone(self.layers, i, s.skin_layers(), self.grounded, domains[i]),
                       wall_footing(self.layers, i, inners, domains, s.line_width))
        t = s.layer_height
        izone, owner = layer_interface(self.layers[i], self.bases, s.interface_layers * t, t,
                                       s.line_width)
        if not izone.is_empty:
            solid = polygonal(shapely.union(solid, izone), valid=True)
        return solid, izone, owner

    def layer(self, i: int) -> tuple[Zones, float, float]:
        """Stage 2 of layer i with its zone and fill CPU seconds."""
        (solid, izone, owner), t_zone = timed(self.zones, i)
        fill, t_fill = timed(fill_paths, self.shells[i].result()[0].domain, solid, izone,
                             fill_spec(self.settings), i)
        return Zones(solid, izone, owner, fill), t_zone, t_fill


def _lift(paths: Sequence[Path2D], layer: LayerPlane, settings: ProcessSettings,
          speed_factor: float, flow: float, first: bool) -> list[Path]:
    """2D paths → plan Paths in the platform frame with per-vertex local height (all paths of
    the layer mapped at once)."""
    if not paths:
        return []
    cut = np.cumsum([len(p.xy) for p in paths])[:-1]
    pts = from_plane(np.concatenate([p.xy for p in paths]), layer.origin, layer.frame)
    h = local_thickness(pts, layer.frame[2], layer.below)
    out = []
    for p, xyz, hp in zip(paths, np.split(pts, cut), np.split(h, cut), strict=True):
        base = settings.perimeter_speed if p.kind == "perimeter" else settings.print_speed
        speed = (settings.first_layer_speed if first else base) * speed_factor
        out.append(Path(p.kind, xyz, hp, p.width, speed, flow, p.closed))
    return out


def done(value: T) -> Future[T]:
    out: Future[T] = Future()
    out.set_result(value)
    return out


def _on_threads(layers: list[LayerPlane], settings: ProcessSettings, grounded: bool,
                bases: list[ChildBase], pool: Executor) -> Stages:
    """Stages 1 and 2 of every layer on ``pool``."""
    spec = fill_spec(settings)
    shells = [pool.submit(timed, shell, lp.region, spec) for lp in layers]
    job = LayerJob(layers, shells, settings, grounded, bases)
    # every stage-2 task is queued after all the shells it waits for: no pool deadlock
    return shells, [pool.submit(job.layer, i) for i in range(len(layers))]


def build_layers(index: int, layers: list[LayerPlane], poses: list[tuple[float, float]],
                 settings: ProcessSettings, grounded: bool, bases: list[ChildBase],
                 pool: Executor, staged: Stages | None = None
                 ) -> tuple[list[Layer], dict[str, float]]:
    """Zones, toolpaths and plan Layers of one sub-part.

    Parameters
    ----------
    index : int
        The sub-part.
    layers, poses : list
        Its marched layers and their table angles (A, C).
    settings : ProcessSettings
    grounded : bool
        The sub-part stands on the platform (bottom skin, first-layer speed).
    bases : list of ChildBase
        Its children's bases (interface zones).
    pool : Executor
        Runs stages 1 and 2 unless ``staged``; its tasks never wait on each other.
    staged : optional
        Stages 1 and 2 already started in worker processes
        (:func:`slicer.paths.layer_workers.start_stages`).

    Returns
    -------
    layers : list of Layer
    seconds : dict
        CPU seconds of "toolpaths" (shells, fill, order, lift) and "zones".
    """
    shells, zones = (staged if staged is not None
                     else _on_threads(layers, settings, grounded, bases, pool))
    job = LayerJob(layers, shells, settings, grounded, bases)
    seconds = {"toolpaths": 0.0, "zones": 0.0}
    out, t = timed(_order_and_lift, index, job, zones, poses, seconds)
    seconds["toolpaths"] += t + sum(f.result()[1] for f in shells)
    return out, seconds


def _order_and_lift(index: int, job: LayerJob,
                    staged: Sequence[Pending[tuple[Zones, float, float]]],
                    poses: list[tuple[float, float]], seconds: dict[str, float]) -> list[Layer]:
    """Stage 3, layer by layer as stage 2 delivers: paths ordered from the previous layer's
    end, lifted into the platform frame. Stage 2's CPU seconds are added to ``seconds``."""
    s, spec = job.settings, fill_spec(job.settings)
    out, here = [], np.zeros(2)
    for i, (lp, (a, c), task) in enumerate(zip(job.layers, poses, staged, strict=True)):
        z, t_zone, t_fill = task.result()
        seconds["zones"] += t_zone
        seconds["toolpaths"] += t_fill
        paths2d = layer_paths(lp.region, z.solid, z.interface, spec, i, here,
                              job.shells[i].result()[0], z.fill)
        if paths2d:
            here = paths2d[-1].xy[-1]
        first_child = i == 0 and not job.grounded
        factor = s.interface_speed_factor if first_child else 1.0
        flow = s.interface_flow if first_child else 1.0
        paths = _lift(paths2d, lp, s, factor, flow, first=(i == 0 and job.grounded))
        out.append(Layer(index, i, lp.origin.copy(), lp.normal.copy(), float(a), float(c),
                         lp.thickness, paths, z.owner, first_child, lp.nominal))
    return out
