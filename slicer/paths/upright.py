"""The root's layers leaned against its overhangs, and cut into stacked pieces where needed.

:func:`lean_upright` builds the root's column (:mod:`~slicer.paths.columns`), plans its lean
(:mod:`~slicer.paths.lean`), cuts it at the plan's jumps and returns the decomposition the
planner slices, with the lean plan of every piece. Hints from a replay that found walls
printed in the air (:class:`LeanHints`) weigh the faces near them more, so a second plan
leans harder there.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import manifold3d as m3
import numpy as np
import trimesh
from scipy.spatial import cKDTree

from slicer.decompose import Decomposition, Subpart
from slicer.paths.columns import column_of, restack, stack
from slicer.paths.lean import LeanPlan, Turning, lean_problem, solve
from slicer.paths.lean_costs import LeanSettings
from slicer.planes2d import TOL
from slicer.printhead import Printhead

log = logging.getLogger(__name__)

MAX_CUT_TRIES = 6  # jumps refused by the column before the plan gives up jumping
HINT_RADIUS = 2.5  # mm: faces this near a hinted point weigh more
HINT_WEIGHT = 10.0  # ... by this factor per round of hints
HINT_MARGIN = 8.0  # ... and their overhang limits are this many degrees stricter


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
            near = tree.query_ball_point(np.asarray(pts, dtype=float), r=HINT_RADIUS)
            hit = np.unique(np.concatenate([np.asarray(n, dtype=np.int64) for n in near]))
            w[hit] *= HINT_WEIGHT
            margin[hit] += HINT_MARGIN
        return w, margin

    def more(self, points: np.ndarray) -> LeanHints:
        """These hints and one more try's points."""
        return LeanHints((*self.rounds, np.asarray(points, dtype=float).reshape(-1, 3)))


NO_HINTS = LeanHints()


@dataclass
class Leaned:
    """The decomposition to slice (the root possibly in stacked pieces) and the lean plan of
    each of the root's pieces, by sub-part index."""

    decomposition: Decomposition
    plans: dict[int, LeanPlan] = field(default_factory=dict)


#: ``base_centre(mesh, point, normal) -> (3,)``: where a sub-part's axis starts on its base.
BaseCentre = Callable[[trimesh.Trimesh, np.ndarray, np.ndarray], np.ndarray]


def lean_upright(decomposition: Decomposition, solid: m3.Manifold, base_centre: BaseCentre,
                 turning: Turning, head: Printhead, settings: LeanSettings | None = None,
                 hints: LeanHints = NO_HINTS) -> Leaned:
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

    Returns
    -------
    Leaned
    """
    root = _root(decomposition)
    if settings is None or root is None:
        return Leaned(decomposition)
    kids = [s for s in decomposition.subparts if s.parent == root.index]
    origin = base_centre(root.mesh, np.array([0.0, 0.0, float(root.mesh.bounds[0][2])]),
                         np.array([0.0, 0.0, 1.0]))
    column = column_of(root, kids, solid, origin, np.eye(3), hints.weights(root.mesh))
    problem = lean_problem(column, head, turning, settings)
    refused: set[int] = set()
    plan = solve(problem)
    for _ in range(MAX_CUT_TRIES):
        if not plan.leans:
            return Leaned(decomposition)
        pieces, bad = stack(column, plan)
        if bad is None:
            return _leaned(decomposition, root, pieces, plan)
        refused.add(bad)
        plan = solve(problem, frozenset(refused))
    plan = solve(problem, frozenset(range(len(plan.directions))))
    pieces, _ = stack(column, plan)
    return _leaned(decomposition, root, pieces, plan) if plan.leans else Leaned(decomposition)


def _root(decomposition: Decomposition) -> Subpart | None:
    """The sub-part printed first, on the platform."""
    subs = {s.index: s for s in decomposition.subparts}
    first = subs.get(decomposition.order[0]) if decomposition.order else None
    return first if first is not None and first.parent is None else None


def _leaned(decomposition: Decomposition, root: Subpart, pieces: Sequence, plan: LeanPlan
            ) -> Leaned:
    """The decomposition with the root in ``pieces`` and ``plan`` for each."""
    tilt = plan.tilt()
    log.info("root leans up to %.0f° (overhang %.1f → %.1f mm² priced), %d stacked piece(s)",
             float(tilt.max()), plan.upright, plan.cost, len(pieces))
    dec = restack(decomposition, root.index, pieces) if len(pieces) > 1 else decomposition
    return Leaned(dec, {root.index + k: plan for k in range(len(pieces))})


def turning_of(t: float, f_min: float, f_max: float) -> Turning:
    """The march's turn bound at layer height ``t`` and thickness bounds (shares of ``t``)."""
    return Turning(t, f_min, f_max, TOL.turn_margin)
