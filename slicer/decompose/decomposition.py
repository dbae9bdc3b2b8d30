"""The decomposition pipeline: STL mesh → support-free sub-parts with a build order.

``decompose`` = repair/placement (:mod:`slicer.mesh`) → k-means coarse partition
(:mod:`slicer.decompose.partition`) → groups and BFS build order
(:mod:`slicer.decompose.buildorder`) → one separating plane per parent→child edge found by the
directed local search (:mod:`slicer.decompose.planes`) → manifold3d split
(:mod:`slicer.decompose.split`) → an independent check of constraints I and II on the final
pieces in build order. It never returns a decomposition that breaks a constraint: it raises
:class:`DecompositionError` instead.
"""

from __future__ import annotations

import contextlib
import functools
import json
import logging
import multiprocessing
import os
import time
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path

import manifold3d as m3
import numpy as np
import trimesh
from scipy.spatial import cKDTree

from kinematics.machine import MachineGeometry
from kinematics.orient import nearest_reachable_direction
from slicer.cores import die_with_parent
from slicer.decompose.ahead import in_order
from slicer.decompose.buildorder import MERGE_ANGLE, Groups, group_regions_refined, root_region
from slicer.decompose.overhang import Overhang, decomposition_overhang
from slicer.decompose.partition import (
    K_MAX,
    K_MIN,
    Partition,
    analysis_mesh,
    auto_k,
    coarse_partition,
)
from slicer.decompose.plane_refine import ParentFrame, refine_plane, splits_clear
from slicer.decompose.planes import (
    Check,
    PieceContext,
    Plane,
    PlaneSearchError,
    SearchSettings,
    fit_plane,
    search_plane,
    surface_samples,
    unreachable_phrase,
    verify_base,
)
from slicer.decompose.split import search_proxy, split_piece, split_solid
from slicer.mesh import (
    BaseChoice,
    canonical_mesh,
    check_size,
    place_on_platform,
    repair,
    separate_bodies,
    to_manifold,
    to_trimesh,
)
from slicer.planes2d import TOL
from slicer.printhead import Printhead

UP = np.array([0.0, 0.0, 1.0])
log = logging.getLogger(__name__)


class DecompositionError(ValueError):
    """The part cannot be decomposed into printable sub-parts; ``str()`` is one line."""


class _NoPlane(DecompositionError):
    """No plane cuts ``group`` from the piece of the group it is printed on."""

    def __init__(self, message: str, group: int) -> None:
        super().__init__(message)
        self.group = group


class RootRegionError(DecompositionError):
    """``settings.root`` names no coarse region; ``regions`` is how many there are."""

    def __init__(self, root: int, regions: int) -> None:
        super().__init__(f"root region {root} does not exist: valid regions are "
                         f"0..{regions - 1} (see the labels in preview.png)")
        self.root, self.regions = root, regions

    def __reduce__(self) -> tuple[type[RootRegionError], tuple[int, int]]:
        return RootRegionError, (self.root, self.regions)  # raised in a worker process too


RUNNERS_UP = 2
"""Valid attempts kept beside the best (:attr:`Decomposition.runners_up`): the first
alternatives the closed loop tries (``slicer.repair.ALTERNATIVES``); it decomposes with the
next seeds after them."""

@dataclass(frozen=True)
class DecomposeSettings:
    """Knobs of the decomposition (config ``decompose.*``)."""

    parts: int = 0  # coarse K; 0 = automatic
    root: int | None = None  # coarse region holding the root; None = the flat base's
    seed: int = 0
    search: SearchSettings = field(default_factory=SearchSettings)
    merge_angle: float = MERGE_ANGLE
    nozzle_diameter: float = 0.4


@dataclass
class Subpart:
    """One sub-part, in the platform frame.

    Attributes
    ----------
    index : int
    parent : int or None
        Sub-part it is printed on (``None`` for the root).
    mesh : trimesh.Trimesh
        Watertight solid.
    base_plane : Plane or None
        Base plane, unit normal pointing into this sub-part (``None`` for the root, which sits
        on the platform z = 0).
    base_area : float
        Area of the base cross-section, mm².
    build_direction : (3,) float
        Unit build direction (the base normal; +Z for the root).
    iterations : int
        Plane search perturbations used.
    """

    index: int
    parent: int | None
    mesh: trimesh.Trimesh
    base_plane: Plane | None
    base_area: float
    build_direction: np.ndarray
    iterations: int = 0

    @property
    def volume(self) -> float:
        """Volume, mm³."""
        return float(self.mesh.volume)


@dataclass
class Decomposition:
    """Result of :func:`decompose`.

    Attributes
    ----------
    placement : (4, 4) float
        Input frame → platform frame.
    subparts : list of Subpart
        Indexed by ``Subpart.index``.
    order : list of int
        Build order (parents before children).
    volume : float
        Volume of the placed model, mm³.
    timings : dict of str to float
        Seconds per stage.
    regions : int
        Coarse regions after clean-up; ``k`` is the K given to k-means.
    seed : int
        Seed of the attempt kept (``settings.seed`` unless a retry did better).
    attempts : list of str
        One line per attempt, in the order tried (seed, K, outcome).
    overhang : list of Overhang
        Overhanging surface of every sub-part (:mod:`slicer.decompose.overhang`).
    base : BaseChoice or None
        The flat face it stands on and the faces tried (:func:`slicer.decompose.decompose_on_bases`;
        None from :func:`decompose`, which takes the part as placed).
    """

    placement: np.ndarray
    subparts: list[Subpart]
    order: list[int]
    volume: float
    timings: dict[str, float]
    regions: int
    k: int
    partition: Partition | None = field(default=None, repr=False)
    groups: Groups | None = field(default=None, repr=False)
    seed: int = 0
    attempts: list[str] = field(default_factory=list)
    overhang: list[Overhang] = field(default_factory=list)
    base: BaseChoice | None = None
    runners_up: list[Decomposition] = field(default_factory=list, repr=False)
    """The other valid attempts of :func:`decompose` within the refusal threshold, least
    overhang first (another try of the closed loop, ``slicer.repair``, at no new cost)."""

    @property
    def overhang_deg(self) -> float:
        """The overhang limit the areas are measured against, degrees from horizontal."""
        return TOL.overhang_deg

    @property
    def overhang_area(self) -> float:
        """Overhanging area of all sub-parts, mm²."""
        return float(sum(o.area for o in self.overhang))

    def summary(self) -> str:
        """One line: sub-parts, the attempt kept and the overhang left."""
        return (f"{len(self.subparts)} sub-parts, seed {self.seed}, k={self.k} "
                f"({len(self.attempts)} attempt{'s' if len(self.attempts) != 1 else ''}), "
                f"overhang {self.overhang_area:.1f} mm² over {TOL.overhang_deg:g}°")

    def signature(self) -> tuple[object, ...]:
        """What makes two decompositions print alike: the placement, and every sub-part's
        parent, base plane (offset to 0.1 mm, normal to 0.01) and volume (to 1 mm³), in build
        order. Different seeds and K often end in the same sub-parts."""
        subs = {s.index: s for s in self.subparts}
        parts = []
        for i in self.order:
            s = subs[i]
            plane = None if s.base_plane is None else (
                round(float(np.dot(s.base_plane.point, s.base_plane.normal)), 1),
                *np.round(np.asarray(s.base_plane.normal, dtype=float), 2).tolist())
            parts.append((s.parent, plane, round(s.volume)))
        return (tuple(np.round(np.asarray(self.placement, dtype=float), 3).ravel().tolist()),
                tuple(parts))

    def to_json(self) -> dict[str, object]:
        """The ``decomposition.json`` payload (files named ``part_<k>.stl``)."""
        return {
            "placement": np.asarray(self.placement).tolist(),
            "volume_mm3": self.volume,
            "order": list(self.order),
            "coarse_k": self.k,
            "coarse_regions": self.regions,
            "seed": self.seed,
            "attempts": list(self.attempts),
            "overhang_deg": TOL.overhang_deg,
            "subparts": [_subpart_json(s, o) for s, o in
                         zip(self.subparts, self._overhangs(), strict=True)],
            **({} if self.base is None else {"base": self.base.to_json()}),
        }


    def _overhangs(self) -> list[Overhang | None]:
        if len(self.overhang) == len(self.subparts):
            return list(self.overhang)
        return [None] * len(self.subparts)


def _subpart_json(s: Subpart, over: Overhang | None) -> dict[str, object]:
    plane = None if s.base_plane is None else {
        "point": np.asarray(s.base_plane.point).tolist(),
        "normal": np.asarray(s.base_plane.normal).tolist()}
    return {"index": s.index, "parent": s.parent, "file": f"part_{s.index}.stl",
            "volume_mm3": s.volume, "base_plane": plane, "base_area_mm2": s.base_area,
            "build_direction": np.asarray(s.build_direction).tolist(),
            "plane_iterations": s.iterations,
            "overhang_mm2": None if over is None else over.area}


def decompose(mesh: trimesh.Trimesh, settings: DecomposeSettings, machine: MachineGeometry,
              head: Printhead, build_volume: np.ndarray | None = None,
              placement: np.ndarray | None = None) -> Decomposition:
    """Decompose a part into support-free sub-parts.

    The configured seed (and K) is tried first. When it is refused, or its sub-parts overhang
    more than the retry threshold (:attr:`~slicer.planes2d.Tolerances.overhang_retry_abs` and
    ``overhang_retry_rel`` of the surface), up to ``TOL.retry_seeds`` further attempts follow
    (:func:`attempt_plan`); when none is within the threshold, the same attempts again with
    stranded regions cut in three (``three_way``, :func:`group_regions_refined`: short hollow
    branches), and the valid result with the least overhang is kept (ties: fewest
    sub-parts, then the first tried). A best result with a sub-part overhanging more than the
    refusal threshold (``overhang_refuse_abs`` and ``overhang_refuse_rel``) is refused.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The part. When ``placement`` is None it is repaired and placed on its flat base;
        otherwise it is taken as already placed by ``placement``. Either way it is put in
        canonical order on the snap grid (:func:`~slicer.mesh.placement.canonical_mesh`), so the
        result depends on the shape, not on the face order or a translation's residue.
    settings : DecomposeSettings
    machine : MachineGeometry
        Only ``a_limits`` and ``c_limits`` are used (reachability of build directions).
    head : Printhead
    build_volume : (3,) float, optional
        Largest extents, mm.

    Raises
    ------
    DecompositionError, slicer.mesh.errors.MeshError
    """
    clock = _Clock()
    if placement is None:
        mesh, placed = place_on_platform(repair(mesh))
        placement = placed.matrix
    else:
        mesh = canonical_mesh(mesh)
    check_size(mesh, "<mesh>", build_volume, settings.nozzle_diameter)
    bodies = separate_bodies(mesh)
    if bodies:
        raise DecompositionError(bodies)
    clock.lap("load")
    area = float(mesh.area)
    job = _Job(mesh, analysis_mesh(mesh), settings, machine, head)  # every attempt's mesh
    tried, results, finer_ids, first_error = _attempts(job, area, clock)
    if not results:
        assert first_error is not None
        more = len(tried) - 1
        raise DecompositionError(str(first_error) + (
            f" (and {more} further seed{'s' if more != 1 else ''} refused too)" if more else ""))
    ranked = sorted(results, key=lambda d: (round(d.overhang_area, 1), len(d.subparts)))
    best, others = _kept(ranked, finer_ids, area)
    for dec in ranked:
        dec.placement = np.asarray(placement, dtype=float)
        dec.attempts = tried
    best.timings = clock.laps
    best.runners_up = [d for d in others if not _over_limit(d, area)][:RUNNERS_UP]
    for line in tried:
        log.debug("decompose attempt: %s", line)
    _refuse_overhang(best, area)
    log.info("decomposition: %s", best.summary())
    return best


@dataclass(frozen=True)
class _Job:
    """What every attempt of one decomposition shares (a worker gets it once)."""

    mesh: trimesh.Trimesh
    analysed: trimesh.Trimesh  # analysis_mesh(mesh)
    settings: DecomposeSettings
    machine: MachineGeometry
    head: Printhead


def _attempts(job: _Job, area: float, clock: _Clock
              ) -> tuple[list[str], list[Decomposition], set[int], DecompositionError | None]:
    """The attempts of :func:`decompose` in order (:func:`attempt_plan`, then the three-way
    cuts, then the finer retry), until one is within the retry threshold; later ones may
    be computed ahead by a worker process (:mod:`slicer.decompose.ahead`).

    Returns the line per attempt, the valid results in order, the ids of the finer retry's
    and the first refusal."""
    retry_above = max(TOL.overhang_retry_abs, TOL.overhang_retry_rel * area)
    order, finer = _attempt_order(list(attempt_plan(job.mesh, job.settings, job.analysed)))
    tried: list[str] = []
    results: list[Decomposition] = []
    finer_ids: set[int] = set()
    first_error: DecompositionError | None = None
    outcomes = in_order(len(order), lambda i: _tried(job, *order[i], clock),
                        functools.partial(_spawn, job),
                        lambda pool, i: pool.submit(_tried_there, *order[i]))
    with contextlib.closing(outcomes):
        for (seed, k, three_way), dec in zip(order, outcomes, strict=False):
            clock.lap("waited")  # for a worker's attempt; ~0 otherwise
            how = " three-way" if three_way else ""
            if isinstance(dec, DecompositionError):
                tried.append(f"seed {seed} k={k or 'auto'}{how}: refused: {dec}")
                first_error = first_error or dec
                continue
            tried.append(f"seed {seed} k={dec.k}{how}: {len(dec.subparts)} sub-parts, "
                         f"overhang {dec.overhang_area:.1f} mm²")
            results.append(dec)
            if (seed, k) == finer:
                finer_ids.add(id(dec))
            if dec.overhang_area <= retry_above:
                break
    return tried, results, finer_ids, first_error


def _attempt_order(plan: list[tuple[int, int]]
                   ) -> tuple[list[tuple[int, int, bool]], tuple[int, int] | None]:
    """(seed, K, three-way) of every attempt, in order, and the finer retry's (seed, K) or
    None: the plan's usual attempts, then the same three-way, then the finer retry (the
    last of the plan when its K is larger than the first retry's) both ways, only where no
    usual attempt, nor its three-way cut, is within the retry threshold."""
    finer = plan[-1] if len(plan) > 2 and plan[-1][1] > plan[1][1] else None
    usual = [p for p in plan if p != finer]
    order = [(s, k, False) for s, k in usual] + [(s, k, True) for s, k in usual]
    return order + ([] if finer is None else [(*finer, False), (*finer, True)]), finer


def _tried(job: _Job, seed: int, k: int, three_way: bool, clock: _Clock
           ) -> Decomposition | DecompositionError:
    """:func:`_attempt`, a refusal returned (but a bad root, which raises)."""
    try:
        return _attempt(job.mesh, job.analysed, job.settings, seed, k, job.machine, job.head,
                        clock, three_way)
    except RootRegionError:
        raise
    except DecompositionError as exc:
        return exc


_JOB: _Job | None = None  # in a worker process (:func:`_spawn`): the attempts' job


def _spawn(job: _Job) -> ProcessPoolExecutor:
    """A pool of one spawned worker for ``job``'s attempts (:func:`_tried_there`).

    The job goes as the worker's first task, not as its initializer's argument: those are
    written to the new process by the starting thread, which would wait while the worker
    imports the slicer; a task is written by the pool's own thread."""
    pool = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"),
                               initializer=die_with_parent, initargs=(os.getpid(),))
    pool.submit(_take_job, job)
    return pool


def _take_job(job: _Job) -> None:
    global _JOB
    _JOB = job


def _tried_there(seed: int, k: int, three_way: bool) -> Decomposition | DecompositionError:
    """:func:`_tried` in the worker process, on the job it was started with."""
    assert _JOB is not None, "not a decomposition worker"
    return _tried(_JOB, seed, k, three_way, _Clock())


def _kept(ranked: list[Decomposition], finer: set[int], area: float
          ) -> tuple[Decomposition, list[Decomposition]]:
    """The decomposition kept of ``ranked`` (least overhang first) and the others, in the
    order the closed loop tries them.

    The finer retry (ids in ``finer``) is kept only when every other result overhangs past
    the refusal limit (ball31 of the sweep); else it comes first among the others. A
    finer partition's least overhang *area* is no sign of the better plan, and a part the
    usual attempts decompose keeps what it had; where that plan leaves walls over air, the
    closed loop tries the finer one next (tree10 of the sweep: its three arms' roots held
    only that way)."""
    usual = [d for d in ranked if id(d) not in finer]
    best = usual[0] if usual and not _over_limit(usual[0], area) else ranked[0]
    others = [d for d in ranked if d is not best]
    others.sort(key=lambda d: id(d) not in finer)  # stable: the finer one first
    return best, others


def attempt_plan(mesh: trimesh.Trimesh, settings: DecomposeSettings,
                 analysed: trimesh.Trimesh | None = None) -> Iterator[tuple[int, int]]:
    """The (seed, K) attempts of :func:`decompose`, in order; K = 0 is automatic.

    First the configured ones. Then ``TOL.retry_seeds`` more, derived from the configured
    seed (seed + i·1 000 003, modulo 2³¹, so each is reproducible with ``--seed``/``--parts``);
    with an automatic K the i-th retry also coarsens it to K₀/i (never below ``K_MIN``):
    k-means over-segments box-like parts into many flat patches whose groups often leave a
    horizontal overhang with the root, and coarser patches group it right (Γ bracket: K 24
    gives a valid split for 5 of 31 seeds, K 6–8 for 12 of 12). An automatic K gets one
    more retry, finer: 2·K₀ (at most ``K_MAX``), which :func:`decompose` makes after all the
    others and their three-way cuts. K₀ counts patches about a tube wide, too
    few for a ball with arms spread in three directions (the sweep's ball31, K₀ 3: every
    coarser attempt kept an arm in the ball's root, 253–385 mm² over air; K 4–6 cut all
    three off in 11 of 12 seeds); :func:`_kept` says when it is kept. A fixed ``--root``
    names a region of the configured seed's partition, so it gets no retries. ``analysed``
    is ``analysis_mesh(mesh)`` when the caller has it already.
    """
    yield settings.seed, settings.parts
    if settings.root is not None:
        return
    k0 = settings.parts or auto_k(analysis_mesh(mesh) if analysed is None else analysed)
    for i in range(1, TOL.retry_seeds + 1):
        seed = (settings.seed + i * 1_000_003) % 2**31
        yield seed, settings.parts or max(K_MIN, round(k0 / i))
    if not settings.parts and k0 < K_MAX:
        yield (settings.seed + (TOL.retry_seeds + 1) * 1_000_003) % 2**31, min(K_MAX, 2 * k0)


def _attempt(mesh: trimesh.Trimesh, analysed: trimesh.Trimesh, settings: DecomposeSettings,
             seed: int, k: int, machine: MachineGeometry, head: Printhead, clock: _Clock,
             three_way: bool = False) -> Decomposition:
    """One decomposition with ``seed`` and K = ``k`` (0: automatic), overhang measured, of
    ``mesh`` partitioned on ``analysed`` (its :func:`analysis_mesh`); ``three_way``: stranded
    regions may be cut in three (:func:`group_regions_refined`)."""
    part = coarse_partition(mesh, k or None, seed, analysed)
    clock.lap("partition")
    root = root_region(part) if settings.root is None else settings.root
    if not 0 <= root < part.count:
        raise RootRegionError(root, part.count)
    try:
        part, groups = group_regions_refined(part, root, settings.merge_angle, seed,
                                             three_way=three_way)
    except ValueError as exc:
        raise DecompositionError(str(exc)) from None
    clock.lap("build_order")
    solid = to_manifold(mesh)
    subparts, order, groups = _cut_reparenting(mesh, solid, part, groups,
                                               replace(settings, seed=seed), machine, head)
    clock.lap("planes_split")
    _verify(subparts, machine, head)
    clock.lap("verify")
    over = decomposition_overhang([s.mesh for s in subparts], [s.parent for s in subparts],
                                  [s.base_plane for s in subparts],
                                  [s.build_direction for s in subparts])
    clock.lap("overhang")
    return Decomposition(np.eye(4), subparts, order, float(solid.volume()), clock.laps,
                         part.count, part.k_requested, part, groups, seed, [], over)


def _over_limit(dec: Decomposition, area: float) -> bool:
    """Whether a sub-part of ``dec`` overhangs more than the refusal threshold."""
    limit = max(TOL.overhang_refuse_abs, TOL.overhang_refuse_rel * area)
    worst = max(dec.overhang, key=lambda o: o.area)
    return worst.area > limit and worst.point is not None


def _refuse_overhang(dec: Decomposition, area: float) -> None:
    """Raise when a sub-part of ``dec`` overhangs more than the refusal threshold."""
    if not _over_limit(dec, area):
        return
    limit = max(TOL.overhang_refuse_abs, TOL.overhang_refuse_rel * area)
    worst = max(dec.overhang, key=lambda o: o.area)
    assert worst.point is not None
    where = "[" + ", ".join(f"{x:.1f}" for x in worst.point) + "]"
    tries = len(dec.attempts)
    raise DecompositionError(
        f"sub-part {worst.index} overhangs {worst.area:.0f} mm² more than "
        f"{TOL.overhang_deg:g}° from its build direction, near {where} mm (limit "
        f"{limit:.0f} mm²; best of {tries} attempt{'s' if tries != 1 else ''}, kept seed "
        f"{dec.seed}): it would print in the air; no support-free decomposition was found")


class _Clock:
    def __init__(self) -> None:
        self.t = time.perf_counter()
        self.laps: dict[str, float] = {}

    def lap(self, name: str) -> None:
        """Add the time since the last lap to ``name`` (attempts accumulate)."""
        now = time.perf_counter()
        self.laps[name] = self.laps.get(name, 0.0) + now - self.t
        self.t = now


def _cut_reparenting(mesh: trimesh.Trimesh, solid: m3.Manifold, part: Partition,
                     groups: Groups, settings: DecomposeSettings, machine: MachineGeometry,
                     head: Printhead) -> tuple[list[Subpart], list[int], Groups]:
    """:func:`_cut_all`; when no plane cuts a group from the group it hangs on and that is
    not the root, the group is hung on the nearest earlier ancestor it touches instead and
    the cuts are made again, with the groups used.

    Beyond the paper, whose build tree is the BFS tree of the regions: the groups are grown
    by the longest shared boundary, which can hang a branch on a sibling branch that meets
    it at the junction (three solid arms from one ball: each arm's plane must then keep
    the head off the sibling printed before it, and none does), where the junction's own
    group carries both."""
    tried: set[tuple[int, int]] = set()
    while True:
        try:
            subparts, order = _cut_all(mesh, solid, part, groups, settings, machine, head)
            return subparts, order, groups
        except _NoPlane as exc:
            up = _touching_ancestor(groups, exc.group)
            if up is None or (exc.group, up) in tried:
                raise DecompositionError(str(exc)) from None
            tried.add((exc.group, up))
            log.debug("group %d hung on group %d instead of %s", exc.group, up,
                      groups.parent[exc.group])
            groups = replace(groups, parent=[up if i == exc.group else p
                                             for i, p in enumerate(groups.parent)])


def _touching_ancestor(groups: Groups, g: int) -> int | None:
    """The nearest ancestor of group ``g`` above its parent whose regions share a boundary
    with ``g``'s, or None."""
    parent = groups.parent[g]
    mine = groups.region_group == g
    up = None if parent is None else groups.parent[parent]
    while up is not None:
        if groups.adjacency[np.ix_(mine, groups.region_group == up)].sum() > 0.0:
            return up
        up = groups.parent[up]
    return None


def _cut_all(mesh: trimesh.Trimesh, solid: m3.Manifold, part: Partition, groups: Groups,
             settings: DecomposeSettings, machine: MachineGeometry,
             head: Printhead) -> tuple[list[Subpart], list[int]]:
    """Cut every group from its parent's piece, in build order.

    Planes are searched on a simplified proxy of each piece (:func:`search_proxy`; the piece
    itself when it is small); every plane then cuts the full-resolution solid once. A cut
    whose child would be degenerate (volume below ``TOL.min_volume_share`` of the part's, or
    base below ``TOL.min_base_share`` of volume^(2/3)) is not made: the group stays with its
    parent's piece, and its children are cut from that piece.

    Returns
    -------
    subparts : list of Subpart
        Indexed 0.. in build order.
    order : list of int
        Build order (``subparts`` indices).
    """
    face_group = groups.region_group[part.labels]
    tree = cKDTree(part.mesh.triangles_center)
    solids = {0: solid}
    proxy = search_proxy(mesh, solids[0])
    pieces: dict[int, trimesh.Trimesh] = {0: proxy}
    on_base = (mesh.face_normals[:, 2] < -0.999) & (np.abs(mesh.triangles_center[:, 2]) < 1e-3)
    base_area = float(mesh.area_faces[on_base].sum())
    subparts: dict[int, Subpart] = {0: Subpart(0, None, mesh, None, base_area, UP)}
    owner = {0: 0}  # group -> group whose piece holds it (itself unless merged back)
    volume = float(solid.volume())
    min_volume = TOL.min_volume_share * volume
    min_base = TOL.min_base_share * volume ** (2.0 / 3.0)
    rng = np.random.default_rng(settings.seed)
    for g in groups.order[1:]:
        nominal = groups.parent[g]
        assert nominal is not None
        pg = owner[nominal]
        piece = pieces[pg]
        region = _subtree(groups, g)[face_group[tree.query(piece.triangles_center)[1]]]
        others = [p for k, p in pieces.items() if k != pg]
        ctx = PieceContext(piece, region, surface_samples(others, settings.seed), head,
                           machine.a_limits, settings.seed, machine.c_limits)
        check, its = _find_plane(ctx, part, face_group, groups, g, nominal, settings, rng)
        check, more = refine_plane(ctx, check, _frame_of(subparts[pg]), groups.direction[g],
                                   settings.search, rng)
        its += more
        child, rest = split_solid(solids[pg], check.plane, piece, check.child_faces)
        if child.volume() < min_volume or check.area < min_base:
            owner[g] = pg  # degenerate: never produced, the group prints with its parent
            continue
        owner[g] = g
        solids[pg], solids[g] = rest, child
        if proxy is mesh:
            pieces[pg], pieces[g] = to_trimesh(rest), to_trimesh(child)
        else:
            pieces[g], pieces[pg] = split_piece(piece, check.plane, check.child_faces)
        subparts[g] = Subpart(g, pg, mesh, check.plane, check.area, check.plane.normal, its)
    for g, s in subparts.items():
        s.mesh = pieces[g] if proxy is mesh else to_trimesh(solids[g])
    kept = [g for g in groups.order if g in subparts]
    index = {g: i for i, g in enumerate(kept)}
    out = []
    for g in kept:
        s = subparts[g]
        s.index = index[g]
        s.parent = None if s.parent is None else index[s.parent]
        out.append(s)
    return out, list(range(len(out)))


def _frame_of(parent: Subpart) -> ParentFrame:
    """How ``parent`` is printed: the root on the platform along +Z, others on their base."""
    base = parent.base_plane or Plane(np.zeros(3), UP)
    return ParentFrame(np.asarray(parent.build_direction, dtype=float), base)


def _subtree(groups: Groups, g: int) -> np.ndarray:
    """Which groups are ``g`` or below it in the build tree, (groups,) bool.

    The child piece cut off for ``g`` carries its descendants too (they are cut from it
    later), so their faces count as the child's when the plane is judged.
    """
    inside = np.zeros(groups.count, dtype=bool)
    inside[g] = True
    for h in groups.order:  # parents come before children
        parent = groups.parent[h]
        if parent is not None and inside[parent]:
            inside[h] = True
    return inside


def _find_plane(ctx: PieceContext, part: Partition, face_group: np.ndarray, groups: Groups,
                g: int, pg: int, settings: DecomposeSettings, rng: np.random.Generator
                ) -> tuple[Check, int]:
    """Search from the child's axis through the boundary, then from the boundary's LSQ plane."""
    am = part.mesh
    fa = face_group[am.face_adjacency]
    edge = ((fa[:, 0] == g) & (fa[:, 1] == pg)) | ((fa[:, 1] == g) & (fa[:, 0] == pg))
    if not edge.any():
        edge = (fa[:, 0] == g) ^ (fa[:, 1] == g)
    pts = am.vertices[am.face_adjacency_edges[edge].ravel()]
    centre = am.triangles_center[face_group == g].mean(axis=0)
    lsq = fit_plane(pts, centre)
    axis = groups.direction[g] * np.sign(groups.direction[g] @ (centre - lsq.point) or 1.0)
    axis = nearest_reachable(axis, ctx.a_limits, ctx.c_limits)
    total, best = 0, None
    for start in (Plane(lsq.point, axis), lsq):
        check, its = search_plane(ctx, start, settings.search, rng,
                                  functools.partial(splits_clear, ctx))
        total += its
        if check.ok:
            return check, total
        best = check if best is None or check.penalty < best.penalty else best
    assert best is not None
    # name a point on the part: the boundary point nearest the plane's (which may lie in
    # empty space once the search has moved the plane)
    where = pts[int(np.argmin(np.linalg.norm(pts - best.plane.point, axis=1)))]
    raise _NoPlane(_failure(best, g, pg, total, where, ctx), g)


def nearest_reachable(direction: np.ndarray, a_limits: tuple[float, float],
                      c_limits: tuple[float, float] | None = None) -> np.ndarray:
    """The direction reachable within the table limits nearest to unit ``direction`` (3,).

    With a continuous C the tilt from +Z is clamped into the reachable range (A turns a tilt
    t or -t to +Z; C any azimuth), the azimuth kept. A branch pointing below the horizontal
    is then searched from the horizontal through its root, not from a plane the walk must
    tilt step by step (each step also drifting the plane along the branch). With C limits
    only some azimuths are reachable at a tilt: the nearest direction any (A, C) within both
    limits turns to +Z is taken (:func:`kinematics.orient.nearest_reachable_direction`).

    Parameters
    ----------
    direction : (3,) float
        Unit direction in the platform frame.
    a_limits : (2,) float
        A range [min, max], degrees.
    c_limits : (2,) float or None
        C range [min, max], degrees; ``None`` for a continuous C.

    Returns
    -------
    (3,) float
        ``direction`` itself when reachable (or when nothing is), else the nearest reachable
        unit vector.
    """
    d = np.asarray(direction, dtype=float)
    if c_limits is not None:
        near = nearest_reachable_direction(d, a_limits, c_limits)
        return d if near is None else near
    tilt = np.degrees(np.arctan2(np.hypot(d[0], d[1]), d[2]))
    lo, hi = a_limits
    spans = [(max(lo, 0.0), hi), (max(-hi, 0.0), -lo)]
    options = [float(np.clip(tilt, a, b)) for a, b in spans if a <= b]
    if not options:
        return d
    best = min(options, key=lambda t: abs(t - tilt))
    if abs(best - tilt) < 1e-9:
        return d
    az = np.arctan2(d[1], d[0])
    t = np.radians(best)
    return np.array([np.sin(t) * np.cos(az), np.sin(t) * np.sin(az), np.cos(t)])


def _failure(check: Check, g: int, pg: int, iterations: int, point: np.ndarray,
             ctx: PieceContext) -> str:
    where = "[" + ", ".join(f"{x:.1f}" for x in point) + "]"
    head = f"boundary between sub-part {pg} and sub-part {g} near {where} mm"
    if not check.valid:
        why = "constraint II fails: no plane leaves the child on its positive side"
    elif not check.reachable:
        why = unreachable_phrase(check.plane.normal, ctx.a_limits, ctx.c_limits)
    elif not check.platform_ok:
        why = "constraint I fails: the printhead would reach below the platform"
    else:
        why = (f"constraint I fails: {check.collisions} samples of the printed part lie "
               "inside the printhead")
    return f"{head}: no plane after {iterations} iterations; {why}"


def _verify(subparts: list[Subpart], machine: MachineGeometry, head: Printhead) -> None:
    """Independent check of I and II on the final pieces, each against those before it."""
    printed: list[trimesh.Trimesh] = []
    for s in subparts:  # indices are in build order
        if s.base_plane is not None:
            obstacles = surface_samples(printed, 0)
            problem = verify_base(s.mesh, s.base_plane, obstacles, head, machine.a_limits,
                                  machine.c_limits)
            if problem:
                near = s.mesh.vertices[np.argmin(np.linalg.norm(
                    s.mesh.vertices - s.base_plane.point, axis=1))]  # a point on the part
                where = "[" + ", ".join(f"{x:.1f}" for x in near) + "]"
                raise DecompositionError(
                    f"boundary between sub-part {s.parent} and sub-part {s.index} near {where}"
                    f" mm: the final check of the cut sub-parts fails: {problem}")
        printed.append(s.mesh)


def write_decomposition(dec: Decomposition, out_dir: str | Path) -> Path:
    """Write ``decomposition.json`` and ``part_<k>.stl`` into ``out_dir``; returns the JSON."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for s in dec.subparts:
        s.mesh.export(out / f"part_{s.index}.stl")
    path = out / "decomposition.json"
    path.write_text(json.dumps(dec.to_json(), indent=2) + "\n", encoding="utf-8")
    return path


__all__ = ["DecomposeSettings", "Decomposition", "DecompositionError", "PlaneSearchError",
           "RootRegionError", "Subpart", "attempt_plan", "decompose", "nearest_reachable",
           "write_decomposition"]
