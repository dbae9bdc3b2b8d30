"""The root's layers leaned against its overhangs, and cut into stacked pieces where needed.

:func:`lean_upright` builds the root's column (:mod:`~slicer.paths.columns`), plans its lean
(:mod:`~slicer.paths.lean`), cuts it at the plan's jumps and returns the decomposition the
planner slices, with the lean plan of every piece. Hints from a replay that found walls
printed in the air (:class:`LeanHints`) weigh the faces near them more, so a second plan
leans harder there.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, TypeVar

import manifold3d as m3
import numpy as np
import trimesh
from scipy.spatial import cKDTree

from slicer.decompose import Decomposition, Subpart
from slicer.paths.columns import STRADDLE, Piece, column_of, restack, stack
from slicer.paths.lean import LeanPlan, LeanProblem, Turning, lean_problem, solve
from slicer.paths.lean_costs import LeanSettings
from slicer.planes2d import TOL
from slicer.printhead import Printhead

T = TypeVar("T")

log = logging.getLogger(__name__)

MAX_CUT_TRIES = 6  # jumps refused by the column before the plan gives up jumping
HINT_RADIUS = 2.5  # mm: faces this near a hinted point weigh more
HINT_WEIGHT = 10.0  # ... by this factor per round of hints
HINT_MARGIN = 8.0  # ... and their overhang limits are this many degrees stricter
HINT_SPACING = 0.5  # mm between the surface samples that find the faces near a hint
HINT_SAMPLES = 200_000  # ... at most
FORCED_SLACK = 1.0  # mm: a forced cut passes at most this much higher over the base than
#                     the lowest allowed cut


@dataclass(frozen=True)
class LeanHints:
    """Points (platform frame) where earlier tries printed walls in the air, one array per
    try; each try's points weigh the faces near them ``HINT_WEIGHT`` times more and make
    their overhang limits ``HINT_MARGIN`` degrees stricter: the plan's price found them
    fine, the replay did not."""

    rounds: tuple[np.ndarray, ...] = ()

    def weights(self, mesh: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray] | None:
        """(weight, margin in degrees) of every face of ``mesh``, each (f,), or None
        without hints."""
        if not self.rounds:
            return None
        tree = cKDTree(np.asarray(mesh.triangles_center))
        w, margin = np.ones(len(mesh.faces)), np.zeros(len(mesh.faces))
        for pts in self.rounds:
            if not len(pts):
                continue
            hit = _near_faces(mesh, tree, np.asarray(pts, dtype=float))
            w[hit] *= HINT_WEIGHT
            margin[hit] += HINT_MARGIN
        return w, margin

    def more(self, points: np.ndarray) -> LeanHints:
        """These hints and one more try's points."""
        return LeanHints((*self.rounds, np.asarray(points, dtype=float).reshape(-1, 3)))


NO_HINTS = LeanHints()


def _near_faces(mesh: trimesh.Trimesh, tree: cKDTree, points: np.ndarray) -> np.ndarray:
    """Faces of ``mesh`` near ``points`` (k, 3): those of the surface samples within
    ``HINT_RADIUS`` (a coarse mesh's faces are larger than the radius: their centres may lie
    far from the point) and every face centred within it."""
    count = int(min(HINT_SAMPLES, max(1000, mesh.area / HINT_SPACING**2)))
    samples, faces = trimesh.sample.sample_surface(mesh, count, seed=0)
    near = cKDTree(samples).query_ball_point(points, r=HINT_RADIUS)
    centred = tree.query_ball_point(points, r=HINT_RADIUS)
    found = [faces[np.asarray(n, dtype=np.int64)] for n in near]
    return np.unique(np.concatenate([np.zeros(0, dtype=np.int64), *found]
                                    + [np.asarray(n, dtype=np.int64) for n in centred]))


@dataclass
class Leaned:
    """The decomposition to slice (the root possibly in stacked pieces), the lean plan of
    each of the root's pieces by sub-part index, and the original index of every other
    sub-part (empty when nothing was renumbered)."""

    decomposition: Decomposition
    plans: dict[int, LeanPlan] = field(default_factory=dict)
    original: dict[int, int] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)
    """Wall seconds of pricing the candidates (``lean_price``) and of solving the plan, every
    time it was solved (``lean_solve``)."""

    def child_of_root(self, index: int) -> int | None:
        """The original index of the root's child that sub-part ``index`` is printed on
        (itself included), or None for the root or one of its pieces."""
        subs = {s.index: s for s in self.decomposition.subparts}
        pieces = set(self.plans) | {s.index for s in subs.values() if s.parent is None}
        k = index
        for _ in range(len(subs)):
            if k in pieces or k not in subs:
                return None
            parent = subs[k].parent
            if parent is None or parent in pieces:
                return self.original.get(k, k)
            k = parent
        return None


#: ``base_centre(mesh, point, normal) -> (3,)``: where a sub-part's axis starts on its base.
BaseCentre = Callable[[trimesh.Trimesh, np.ndarray, np.ndarray], np.ndarray]


def lean_upright(decomposition: Decomposition, solid: m3.Manifold, base_centre: BaseCentre,
                 turning: Turning, head: Printhead, settings: LeanSettings | None = None,
                 hints: LeanHints = NO_HINTS, defer: frozenset[int] = frozenset()) -> Leaned:
    """Plan the lean of the root (the sub-part on the platform) and cut it at its jumps.

    Parameters
    ----------
    decomposition : Decomposition
    solid : manifold3d.Manifold
        The root's slicing solid.
    base_centre : BaseCentre
        The planner's centre of a base section.
    turning : Turning
        The march's turn bound.
    head : Printhead
    settings : LeanSettings, optional
        ``None`` leaves the root upright (the paper's slicing).
    hints : LeanHints
    defer : frozenset of int
        Children of the root (indices of ``decomposition``) to print before the root above
        their base: the root is cut just above it (a forced jump) and the child with all
        printed on it goes between the pieces (:func:`~slicer.paths.columns.restack`).

    Returns
    -------
    Leaned
    """
    seconds: dict[str, float] = {}
    leaned = _lean_upright(decomposition, solid, base_centre, turning, head, settings, hints,
                           defer, seconds)
    return replace(leaned, seconds=seconds)


def _lean_upright(decomposition: Decomposition, solid: m3.Manifold, base_centre: BaseCentre,
                  turning: Turning, head: Printhead, settings: LeanSettings | None,
                  hints: LeanHints, defer: frozenset[int], seconds: dict[str, float]
                  ) -> Leaned:
    """:func:`lean_upright`, its stages timed into ``seconds``."""
    root = _root(decomposition)
    if settings is None or root is None:
        return Leaned(decomposition)
    kids = [s for s in decomposition.subparts if s.parent == root.index]
    origin = base_centre(root.mesh, np.array([0.0, 0.0, float(root.mesh.bounds[0][2])]),
                         np.array([0.0, 0.0, 1.0]))
    column = column_of(root, kids, solid, origin, np.eye(3), hints.weights(root.mesh))
    problem = _timed(seconds, "lean_price", lean_problem, column, head, turning, settings)
    bases = [column.child_bases[i] for i, k in enumerate(kids) if k.index in defer]
    refused: set[int] = set()
    for _ in range(MAX_CUT_TRIES):
        forced = _forced(problem, bases, refused)
        if len(forced) < len(defer):
            return Leaned(decomposition)  # no cut above a deferred child's base
        plan = _timed(seconds, "lean_solve", solve, problem, frozenset(refused), forced)
        if not plan.leans:
            return Leaned(decomposition)
        pieces, bad = stack(column, plan)
        if bad is None:
            return _leaned(decomposition, root, pieces, plan, defer)
        refused.add(bad)
    forced = _forced(problem, bases, refused)
    if len(forced) < len(defer):
        return Leaned(decomposition)
    plan = _timed(seconds, "lean_solve", solve, problem,
                  frozenset(range(len(problem.limits))) - set(forced), forced)
    pieces, bad = stack(column, plan)
    if bad is not None or not plan.leans:
        return Leaned(decomposition)
    return _leaned(decomposition, root, pieces, plan, defer)


def _timed(seconds: dict[str, float], name: str, fn: Callable[..., T], *args: Any) -> T:
    """``fn(*args)``, its wall seconds added to ``seconds[name]``."""
    t0 = time.perf_counter()
    try:
        return fn(*args)
    finally:
        seconds[name] = seconds.get(name, 0.0) + time.perf_counter() - t0


def _forced(problem: LeanProblem, bases: list[np.ndarray], refused: set[int]
            ) -> dict[int, np.ndarray]:
    """For each base (points, (k, 3)), the first band above it and not ``refused`` where
    some allowed cut leaves it all ``STRADDLE`` mm below, with the mask of those cuts'
    directions, (n, n) bool."""
    col, band = problem.column, problem.settings.band
    dirs = problem.grid.world(col.frame).reshape(-1, 3)
    out: dict[int, np.ndarray] = {}
    for pts in bases:
        if not len(pts):
            continue
        at = ((np.asarray(pts) - col.origin) @ dirs.T) / (dirs @ col.axis)[None, :]
        top = at.max(axis=0).reshape(problem.grid.inside.shape)  # (n, n)
        first = int(np.floor((float(top.min()) + STRADDLE) / band - 0.5)) + 1
        for b in range(max(first, 1), len(problem.limits)):
            if b in refused:
                continue
            gap = (b + 0.5) * band - STRADDLE - top  # > 0: the base lies under the cut
            mask = problem.costs.jump_ok[b] & (gap > 0)
            if mask.any():  # the cuts that pass lowest over the base: the piece under the
                # cut ends low beside the child, whose head must clear it
                out[b] = mask & (gap <= float(gap[mask].min()) + FORCED_SLACK)
                break
    return out


def _root(decomposition: Decomposition) -> Subpart | None:
    """The sub-part printed first, on the platform."""
    subs = {s.index: s for s in decomposition.subparts}
    first = subs.get(decomposition.order[0]) if decomposition.order else None
    return first if first is not None and first.parent is None else None


def _leaned(decomposition: Decomposition, root: Subpart, pieces: Sequence[Piece],
            plan: LeanPlan, defer: frozenset[int]) -> Leaned:
    """The decomposition with the root in ``pieces`` and ``plan`` for each."""
    tilt = plan.tilt()
    log.info("root leans up to %.0f° (overhang %.1f → %.1f mm² priced), %d stacked piece(s)%s",
             float(tilt.max()), plan.upright, plan.cost, len(pieces),
             f", sub-part(s) {sorted(defer)} printed before the pieces above them"
             if defer else "")
    if len(pieces) == 1:
        same = {s.index: s.index for s in decomposition.subparts if s.index != root.index}
        return Leaned(decomposition, {root.index: plan}, same)
    dec, original = restack(decomposition, root.index, pieces, defer)
    return Leaned(dec, {root.index + k: plan.piece(k) for k in range(len(pieces))}, original)


def turning_of(t: float, f_min: float, f_max: float) -> Turning:
    """The march's turn bound at layer height ``t`` and thickness bounds (shares of ``t``)."""
    return Turning(t, f_min, f_max, TOL.turn_margin)
