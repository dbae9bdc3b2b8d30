"""Second phase of the plane search: among feasible planes, the one leaving the parent least
overhang.

The paper stops at the first plane that satisfies constraints I and II. For a branch steeper
than 45° that plane is pushed out along the branch until the heater block clears the main
tube, and the stretch of branch between the tube and the plane stays with the parent: printed
along the parent's direction, its underside overhangs by the branch's angle (60° for a branch
30° above the horizontal). Here the walk goes on from the first feasible plane, keeping only
feasible steps (same 2 mm / 5° / 15 % limits) that lower the parent's **residual overhang**:
the area of the parent's surface, after the cut, that faces down more than
:data:`OVERHANG_DEG` from the parent's build direction. Tilting the base towards the
horizontal lets the plane come closer to the tube on its lower side, where the overhang is.

The residual is measured on the piece's surface samples (about one per mm², see
:class:`slicer.decompose.planes.PieceContext`), so it is an area in mm² up to sampling noise.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
import trimesh

from slicer.decompose.planes import (
    Check,
    PieceContext,
    Plane,
    SearchSettings,
    child_faces,
    evaluate,
    perturb,
    surface_samples,
    verify_base,
)
from slicer.decompose.split import split_solid
from slicer.mesh import to_trimesh
from slicer.printhead import Printhead

OVERHANG_DEG = 47.0  # faces steeper than this from the build direction count (45° + slack)
BASE_TOL = 0.05  # mm: samples this close to the parent's own base plane are its base face
REFINE_WINDOW = 60  # stop after this many steps without a lower residual
STEEP_BASE_DEG = 50.0  # only children whose axis leans further than this from the parent's
# direction are refined (see :func:`refine_plane`)
CLEARANCE = 1.0  # mm added to the head's radius when a refined plane is settled: the walk
# ends on the edge of the feasible set, where the final check's own samples may disagree
EXACT_CLEARANCE = 0.5  # mm added to the head's radius in the exact check of a found plane
SETTLE_STEPS = (0.0, 0.5, 1.0, 1.5, 2.0)  # mm: a refined plane moves out along n until clear
MIN_GAIN = 1.0  # mm² (about one sample): smaller gains are sampling noise
LEAN_SHARE = 0.5  # share of refinement steps that lean the base away from the parent's axis


@dataclass(frozen=True)
class ParentFrame:
    """How the parent piece is printed: its build ``direction`` (3,) and ``base`` plane."""

    direction: np.ndarray
    base: Plane


def residual_overhang(ctx: PieceContext, plane: Plane, child: np.ndarray,
                      parent: ParentFrame) -> float:
    """Surface samples of the parent side of ``plane`` that overhang, about mm².

    A sample is on the parent side when it lies on a face outside the child piece, or on a
    child face below the plane. It overhangs when its face's normal points more than
    :data:`OVERHANG_DEG` below the horizontal of the parent's build direction, except on the
    parent's base plane (that face lies on the platform or on the grandparent).
    """
    return Overhang.of(ctx, parent).residual(plane, child)


@dataclass(frozen=True)
class Overhang:
    """The overhanging surface samples of a piece: ``points`` (k, 3) on ``faces`` (k,)."""

    points: np.ndarray
    faces: np.ndarray

    @classmethod
    def of(cls, ctx: PieceContext, parent: ParentFrame) -> Overhang:
        """The samples of ``ctx`` that overhang when the piece prints as ``parent``."""
        on_face = ctx.sample_face >= 0
        pts, face = ctx.samples[on_face], ctx.sample_face[on_face]
        down = ctx.mesh.face_normals[face] @ parent.direction < -np.cos(
            np.radians(OVERHANG_DEG))
        down &= np.abs(parent.base.signed(pts)) >= BASE_TOL
        return cls(pts[down], face[down])

    def residual(self, plane: Plane, child: np.ndarray) -> float:
        """How many of them stay with the parent when ``plane`` cuts off ``child`` faces."""
        return float((~child[self.faces] | (plane.signed(self.points) <= 0.0)).sum())


def refine_plane(ctx: PieceContext, found: Check, parent: ParentFrame, axis: np.ndarray,
                 settings: SearchSettings, rng: np.random.Generator) -> tuple[Check, int]:
    """Walk on from the feasible ``found`` to feasible planes with less residual overhang.

    Only a child whose unit ``axis`` (3,) leans more than :data:`STEEP_BASE_DEG` from the
    parent's direction is refined. A branch within that angle leaves the parent a stretch
    that overhangs by about its own angle, within the replay's 45° rule and its slack. Past
    it, the first plane's base is that steep too, which already puts the child's first layer
    beyond the parent's beads next to the cut (they are inset half a line width), so leaning
    the base further costs nothing there.

    Returns
    -------
    check : Check
        ``found``, or a feasible plane with a residual at least :data:`MIN_GAIN` lower that
        also clears the head widened by :data:`CLEARANCE` (see :func:`settle`).
    steps : int
        Perturbations tried.
    """
    if abs(axis @ parent.direction) >= np.cos(np.radians(STEEP_BASE_DEG)):
        return found, 0
    area_cap = (1.0 + settings.area_growth_max) * (found.start_area or found.area)
    walked, steps = _walk(ctx, found, parent, settings, rng, area_cap)
    return settle(ctx, walked, found, area_cap), steps


def _walk(ctx: PieceContext, found: Check, parent: ParentFrame, settings: SearchSettings,
          rng: np.random.Generator, area_cap: float) -> tuple[Check, int]:
    """Accumulating walk over feasible planes, each kept step lowering the residual."""
    best, overhang = found, Overhang.of(ctx, parent)
    cost = overhang.residual(found.plane, found.child_faces)
    progress, step = 0, 0
    for step in range(1, settings.refine_steps + 1):
        if cost < MIN_GAIN or step - progress > REFINE_WINDOW:
            return best, step - 1
        plane = _propose(best, parent, settings, rng)
        child, tangled = child_faces(ctx, plane)  # the residual first: it is cheap
        c = overhang.residual(plane, child)
        if tangled or c > cost - MIN_GAIN:
            continue
        cand = evaluate(ctx, plane)
        if cand.ok and not cand.tangled and cand.area <= area_cap:
            best, cost, progress = cand, c, step
    return best, step


def settle(ctx: PieceContext, walked: Check, found: Check, area_cap: float) -> Check:
    """``walked`` moved out along its normal (:data:`SETTLE_STEPS`) until it also clears the
    head widened by :data:`CLEARANCE`; ``found`` when no such step is feasible."""
    if walked is found:
        return found
    wide = _with_clearance(ctx, CLEARANCE)
    for shift in SETTLE_STEPS:
        plane = Plane(walked.plane.point + shift * walked.plane.normal, walked.plane.normal)
        if not evaluate(wide, plane).ok:
            continue
        cand = evaluate(ctx, plane)
        if cand.ok and not cand.tangled and cand.area <= area_cap and splits_clear(ctx, cand):
            cand.start_area = found.start_area
            return cand
    return found


def splits_clear(ctx: PieceContext, cand: Check) -> bool:
    """The final check of :func:`slicer.decompose.decompose`, run now on the exact split:
    the search's face connectivity can count parent material that a straddling face links
    to the child as the child's, which the exact split then leaves in the head's way."""
    try:
        kid, others = split_solid(ctx.solid, cand.plane, ctx.mesh, cand.child_faces)
    except ValueError:
        return False
    child, rest = to_trimesh(kid), to_trimesh(others)
    obstacles = np.concatenate([surface_samples([rest], ctx.seed + 1), ctx.others])
    head = _with_clearance(ctx, EXACT_CLEARANCE).head
    return verify_base(child, cand.plane, obstacles, head, ctx.a_limits,
                       ctx.c_limits) is None


def _propose(best: Check, parent: ParentFrame, settings: SearchSettings,
             rng: np.random.Generator) -> Plane:
    """A step from ``best``: half of the time a plain perturbation, otherwise the normal
    leans up to the max angle away from the parent's direction (about the plane's point),
    with a random offset: the move that brings the lower side of a cut towards the parent."""
    if rng.random() >= LEAN_SHARE:
        return perturb(best.plane, rng, settings, best)
    n = best.plane.normal
    axis = np.cross(n, parent.direction)
    if np.linalg.norm(axis) < 1e-9:
        return perturb(best.plane, rng, settings, best)
    angle = -np.radians(rng.uniform(0.0, settings.angle_max))
    normal = trimesh.transformations.rotation_matrix(angle, axis)[:3, :3] @ n
    normal /= np.linalg.norm(normal)
    shift = rng.uniform(-settings.offset_max, settings.offset_max)
    return Plane(best.plane.point + shift * normal, normal)


def _with_clearance(ctx: PieceContext, margin: float) -> PieceContext:
    """``ctx`` (same samples) with every radius of the head widened by ``margin``."""
    wide = copy.copy(ctx)
    wide.head = Printhead(tuple((s, e, r0 + margin, r1 + margin)
                                for s, e, r0, r1 in ctx.head.segments))
    return wide

