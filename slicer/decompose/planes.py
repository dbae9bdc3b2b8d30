"""Separating planes (paper 2.2.3): fitting, base cross-sections, constraints and search.

A plane (point p, unit normal n pointing into the child) cuts the *parent piece* (the solid
the child is still attached to). The child is the part of the positive half-space that is
connected, over the surface, to the child's coarse region; the rest of the positive side (for
example the top of the main tube that a branch's plane also crosses) stays with the parent.

Constraints, judged on every candidate plane:

* **I** — no material already printed (everything but the child piece, which is conservative:
  material printed later counts too) may enter the printhead placed with its tip anywhere on
  the child's base cross-section S and its axis along n, and the head may not reach below the
  platform plane z = 0. Because every tip lies on the plane, an obstacle point q at height
  h = (q - p)·n above it is inside the head for some tip iff its in-plane distance to S is
  below the head radius R(h): the test is exact over the whole of S, not over sampled tips
  (obstacles are surface samples, so a margin of the sample spacing is added).
* **II** — the base faces up: the child lies on the positive side (it keeps most of its coarse
  region), and n is reachable within the A limits.

Search. The paper perturbs the plane at random around the initial one. Here the start is the
least-squares plane through the whole region boundary, and the search is a *directed,
accumulating* random walk: each step perturbs the current best plane (offset in [0, max] mm,
normal within the max angle), with the offset biased along +n (away from the parent, into the
child) while constraint I fails, and the normal tilted towards +Z while n is unreachable. A
step is kept when it does not raise the violation count, and rejected when it grows the base
cross-section by more than ``area_growth_max`` over the start's. Pushing a 45° branch's plane
outward is exactly what clears the heater block from the main tube, and an accumulating walk
gets there in a few dozen steps where independent perturbations around the start never would.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, field

import manifold3d as m3
import numpy as np
import shapely
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from shapely.geometry.base import BaseGeometry

from kinematics.orient import nearest_reachable_direction, needed_pose, reachable_mask
from slicer.mesh import to_manifold
from slicer.printhead import Printhead

EPS = 1e-6  # mm: "on the plane"
GRID = 1e-6  # mm: section vertices are snapped to this grid so loops close
SAMPLE_SPACING = 1.0  # mm between obstacle surface samples
CHILD_SHARE = 0.5  # a positive component is the child's when this share of it is child region
KEEP_SHARE = 0.3  # the child must keep this share of its coarse region on the positive side
PLATFORM_TOL = 1e-6  # mm
PROXY_FACES = 12_000  # the plane search runs on a simplified copy of pieces with more faces
PROXY_TOLERANCES = (0.01, 0.05, 0.2)  # mm, tried in turn; all far below SAMPLE_SPACING
STALL_WINDOW = 200  # search steps without a lower penalty before giving up on a start plane


class PlaneSearchError(ValueError):
    """No plane satisfies both constraints; ``str()`` names the boundary and the constraint."""


@dataclass(frozen=True)
class Plane:
    """An oriented plane: ``point`` (3,) on it, unit ``normal`` (3,) into the child."""

    point: np.ndarray
    normal: np.ndarray

    def signed(self, points: np.ndarray) -> np.ndarray:
        """Signed heights of (n, 3) points above the plane, (n,) float."""
        return (np.asarray(points) - self.point) @ self.normal


@dataclass
class Check:
    """Result of judging one plane."""

    plane: Plane
    valid: bool  # a child piece exists and keeps enough of its region
    reachable: bool
    collisions: int  # obstacle samples inside the head somewhere over S
    platform_ok: bool
    area: float
    child_faces: np.ndarray = field(repr=False)  # (m,) bool over the piece's faces
    section: BaseGeometry | None = field(default=None, repr=False)
    tangled: bool = False  # the child's positive side is still joined to parent material
    start_area: float = 0.0  # base area of the search's first valid plane (the 15 % rule)

    @property
    def constraint_i(self) -> bool:
        """I: nothing printed inside the head anywhere over the base, platform clear."""
        return self.valid and self.collisions == 0 and self.platform_ok

    @property
    def constraint_ii(self) -> bool:
        """II: the child is on the positive side and the direction is reachable."""
        return self.valid and self.reachable

    @property
    def ok(self) -> bool:
        """Both constraints hold."""
        return self.constraint_i and self.constraint_ii

    @property
    def penalty(self) -> float:
        """How far from feasible (0 when ok)."""
        if not self.valid:
            return 1e9
        return self.collisions + 1e4 * (not self.platform_ok) + 1e6 * (not self.reachable)


def fit_plane(points: np.ndarray, towards: np.ndarray) -> Plane:
    """Least-squares plane through (n, 3) ``points``, normal oriented towards ``towards``."""
    centre = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centre, full_matrices=False)
    normal = vt[-1]
    if (np.asarray(towards) - centre) @ normal < 0:
        normal = -normal
    return Plane(centre, normal / np.linalg.norm(normal))


def plane_basis(normal: np.ndarray) -> np.ndarray:
    """(2, 3) orthonormal in-plane axes for a unit ``normal``."""
    helper = np.eye(3)[np.argmin(np.abs(normal))]
    u = np.cross(normal, helper)
    u /= np.linalg.norm(u)
    return np.stack([u, np.cross(normal, u)])


@dataclass
class PieceContext:
    """Everything about one parent piece that does not depend on the plane.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The parent piece (watertight, platform frame).
    child_region : (m,) bool
        Faces of ``mesh`` in the child's coarse group.
    others : (k, 3) float
        Surface samples of every other piece (material that may already be printed).
    head : Printhead
    a_limits : (2,) float
    seed : int
    c_limits : (2,) float or None
        With ``a_limits``, the table angles a build direction must be reachable with.
    """

    mesh: trimesh.Trimesh
    child_region: np.ndarray
    others: np.ndarray
    head: Printhead
    a_limits: tuple[float, float]
    seed: int = 0
    c_limits: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        m = self.mesh
        self.pairs = m.face_adjacency
        self.pair_edges = m.face_adjacency_edges
        count = max(int(m.area / SAMPLE_SPACING**2), 100)
        pts, face = trimesh.sample.sample_surface(m, count, seed=self.seed)
        self.samples = np.concatenate([pts, m.vertices])
        self.sample_face = np.concatenate([face, np.full(len(m.vertices), -1)])
        self.vertex_faces = m.vertex_faces

    @functools.cached_property
    def solid(self) -> m3.Manifold:
        """The piece as a manifold3d solid (made once, for exact splits)."""
        return to_manifold(self.mesh)


def evaluate(ctx: PieceContext, plane: Plane) -> Check:
    """Judge ``plane`` against constraints I and II on the piece in ``ctx``."""
    m = ctx.mesh
    h = plane.signed(m.vertices)
    child, tangled = _child_faces(ctx, h)
    region_area = m.area_faces[ctx.child_region].sum()
    kept = m.area_faces[child & ctx.child_region].sum()
    reachable = bool(reachable_mask(plane.normal[None], ctx.a_limits, ctx.c_limits)[0])
    if not child.any() or kept < KEEP_SHARE * region_area:
        return Check(plane, False, reachable, 0, False, 0.0, child, None, tangled)
    section = base_section(m, plane, child)
    if section is None or section.area <= 0:
        return Check(plane, False, reachable, 0, False, 0.0, child)
    collisions = _collisions(ctx, plane, child, section)
    platform_ok = _platform_clear(ctx.head, plane, section)
    return Check(plane, True, reachable, collisions, platform_ok, float(section.area), child,
                 section)


def child_faces(ctx: PieceContext, plane: Plane) -> tuple[np.ndarray, bool]:
    """The faces of the piece cut off with the child by ``plane``, (m,) bool, and whether
    the child's positive side is still tangled with parent material (see :func:`evaluate`)."""
    return _child_faces(ctx, plane.signed(ctx.mesh.vertices))


def _child_faces(ctx: PieceContext, h: np.ndarray) -> tuple[np.ndarray, bool]:
    """Faces whose positive part is connected to the child region, (m,) bool, and whether
    the child region's positive side is still joined to mostly parent material."""
    m = ctx.mesh
    fpos = h[m.faces].max(axis=1) > EPS
    link = fpos[ctx.pairs].all(axis=1) & (h[ctx.pair_edges].max(axis=1) > EPS)
    a = ctx.pairs[link]
    n = len(m.faces)
    graph = coo_matrix((np.ones(len(a)), (a[:, 0], a[:, 1])), shape=(n, n))
    _, comp = connected_components(graph, directed=False)
    w = m.area_faces * fpos
    total = np.bincount(comp, weights=w, minlength=comp.max() + 1)
    mine = np.bincount(comp, weights=w * ctx.child_region, minlength=comp.max() + 1)
    is_child = mine > CHILD_SHARE * np.maximum(total, 1e-12)
    tangled = bool(((mine > 0) & ~is_child).any() and mine[~is_child].max() >
                   0.5 * mine.sum())
    return fpos & is_child[comp], tangled


def base_section(mesh: trimesh.Trimesh, plane: Plane, faces: np.ndarray
                 ) -> BaseGeometry | None:
    """The cross-section of ``faces`` of ``mesh`` with ``plane`` in plane coordinates.

    Returns
    -------
    shapely Polygon/MultiPolygon or None
        Material region (even-odd over the closed loops), in the :func:`plane_basis` frame.
    """
    idx = np.flatnonzero(faces)
    if len(idx) == 0:
        return None
    segs = trimesh.intersections.mesh_plane(mesh, plane.normal, plane.point,
                                            local_faces=idx)
    if len(segs) == 0:
        return None
    flat = (segs - plane.point) @ plane_basis(plane.normal).T
    lines = shapely.set_precision(shapely.linestrings(flat), GRID)
    cells = shapely.get_parts(shapely.polygonize(lines))
    if len(cells) == 0:
        return None
    rings = shapely.polygons(shapely.get_exterior_ring(cells))
    # types-shapely types polygons() of an array as one polygon or an array (a coordinate
    # array makes one polygon); an array of rings makes an array of polygons
    return functools.reduce(shapely.symmetric_difference, rings)  # type: ignore[arg-type]


def _collisions(ctx: PieceContext, plane: Plane, child: np.ndarray,
                section: BaseGeometry) -> int:
    """Obstacle samples inside the head for some tip on ``section``."""
    own = np.zeros(len(ctx.samples), dtype=bool)
    on_face = ctx.sample_face >= 0
    own[on_face] = child[ctx.sample_face[on_face]]
    vf = ctx.vertex_faces  # the samples end with every vertex, in order
    own[~on_face] = (child[vf] & (vf >= 0)).any(axis=1)
    pts = np.concatenate([ctx.samples[~own], ctx.others])
    h = plane.signed(pts)
    up = (h > EPS) & (h <= ctx.head.height)
    if not up.any():
        return 0
    flat = (pts[up] - plane.point) @ plane_basis(plane.normal).T
    x0, y0, x1, y1 = section.bounds
    reach = ctx.head.max_radius + SAMPLE_SPACING
    near = ((flat[:, 0] > x0 - reach) & (flat[:, 0] < x1 + reach)
            & (flat[:, 1] > y0 - reach) & (flat[:, 1] < y1 + reach))
    if not near.any():
        return 0
    dist = shapely.distance(shapely.points(flat[near]), section)
    radius = ctx.head.radius_at(h[up][near]) + SAMPLE_SPACING
    return int((dist < radius).sum())


def _platform_clear(head: Printhead, plane: Plane, section: BaseGeometry) -> bool:
    """Whether the head stays above z = 0 with its tip anywhere on ``section``."""
    ring = np.concatenate([np.asarray(g.exterior.coords) for g in shapely.get_parts(section)])
    tips = plane.point + ring @ plane_basis(plane.normal)
    low = tips[:, 2].min() + head.lowest_point(np.zeros(3), plane.normal)
    return bool(low >= -PLATFORM_TOL)


@dataclass(frozen=True)
class SearchSettings:
    """Limits of the local dynamic search (paper: 2 mm, 5°, 15 %)."""

    offset_max: float = 2.0
    angle_max: float = 5.0
    area_growth_max: float = 0.15
    max_iterations: int = 2000  # hard bound per start plane
    stall_window: int = STALL_WINDOW  # stop after this many steps without progress
    refine_steps: int = 300  # refinement steps after the first feasible plane; 0 = the paper


def perturb(plane: Plane, rng: np.random.Generator, settings: SearchSettings,
            check: Check) -> Plane:
    """One random step from ``plane``, directed by what ``check`` found wrong."""
    n = plane.normal
    pushed = check.collisions > 0 or check.tangled or not check.platform_ok
    sign = 1.0 if (pushed and rng.random() < 0.8) else rng.choice([-1.0, 1.0])
    point = plane.point + sign * rng.uniform(0.0, settings.offset_max) * n
    angle = np.radians(rng.uniform(0.0, settings.angle_max))
    if not check.reachable:
        axis = np.cross(n, [0.0, 0.0, 1.0])  # tilt towards +Z
    else:
        u, v = plane_basis(n)
        phi = rng.uniform(0.0, 2.0 * np.pi)
        axis = np.cos(phi) * u + np.sin(phi) * v
    if np.linalg.norm(axis) < 1e-12:
        return Plane(point, n)
    rot = trimesh.transformations.rotation_matrix(angle, axis)[:3, :3]
    normal = rot @ n
    return Plane(point, normal / np.linalg.norm(normal))


def _reachable_step(ctx: PieceContext, plane: Plane) -> Plane:
    """``plane`` turned to the nearest reachable normal when C is limited.

    With C limits a tilted direction is reachable only within a narrow wedge of azimuths
    (±10° of C: ±10° around ±Y), which random steps almost always leave, and tilting
    towards +Z (what :func:`perturb` does for an unreachable normal) never enters it; so
    the walk stays on the reachable directions. A continuous C keeps the plain step.
    """
    if ctx.c_limits is None:
        return plane
    near = nearest_reachable_direction(plane.normal, ctx.a_limits, ctx.c_limits)
    return plane if near is None else Plane(plane.point, near)


def _pushed_on(best: Check, cand: Check) -> bool:
    """Keep walking an invalid plane only while the child is tangled with parent material
    and the step moved the plane into the child (away from the parent)."""
    step = (cand.plane.point - best.plane.point) @ best.plane.normal
    return not best.valid and best.tangled and cand.tangled and step > 0


def search_plane(ctx: PieceContext, start: Plane, settings: SearchSettings,
                 rng: np.random.Generator,
                 accept: Callable[[Check], bool] | None = None) -> tuple[Check, int]:
    """Local dynamic search from ``start`` until constraints I and II hold.

    The search stops at the first feasible plane, after ``settings.max_iterations`` steps,
    or when ``settings.stall_window`` steps in a row brought no progress on the failing
    constraint: progress is a strictly lower :attr:`Check.penalty` (an invalid plane becoming
    valid, an unreachable direction becoming reachable, the platform clearing, fewer samples
    in the head). Feasible planes of the sample pipes are found within ~25 steps, each
    improvement within ~5 of the last, so a window of 200 only cuts hopeless searches short
    (an unreachable branch: 400 steps instead of 4000).

    Returns
    -------
    check : Check
        The best plane found (``check.ok`` tells whether it is feasible).
    iterations : int
        Perturbations tried.
    """
    best = _judged(ctx, start, accept)
    if best.ok:
        best.start_area = best.area
        return best, 0
    area0 = best.area if best.valid else np.inf
    progress = 0  # last step that lowered the penalty
    for it in range(1, settings.max_iterations + 1):
        if it - progress > settings.stall_window:
            return best, it - 1
        cand = _judged(ctx, _reachable_step(ctx, perturb(best.plane, rng, settings, best)),
                       accept)
        if not cand.valid and not _pushed_on(best, cand):
            continue
        if best.valid and cand.area > (1.0 + settings.area_growth_max) * area0:
            continue
        if cand.penalty <= best.penalty:
            if not best.valid and cand.valid:
                area0 = cand.area
            if cand.penalty < best.penalty:
                progress = it
            best = cand
            if best.ok:
                best.start_area = area0
                return best, it
    return best, settings.max_iterations


def surface_samples(meshes: list[trimesh.Trimesh], seed: int) -> np.ndarray:
    """Surface samples (spacing about :data:`SAMPLE_SPACING`) and vertices of ``meshes``."""
    out = [np.zeros((0, 3))]
    for m in meshes:
        count = max(int(m.area / SAMPLE_SPACING**2), 100)
        out += [trimesh.sample.sample_surface(m, count, seed=seed)[0], m.vertices]
    return np.concatenate(out)


def _judged(ctx: PieceContext, plane: Plane, accept: Callable[[Check], bool] | None) -> Check:
    """:func:`evaluate`, with a feasible plane that ``accept`` refuses marked as colliding."""
    check = evaluate(ctx, plane)
    if check.ok and accept is not None and not accept(check):
        check.collisions = 1
    return check


def verify_base(child: trimesh.Trimesh, plane: Plane, obstacles: np.ndarray, head: Printhead,
                a_limits: tuple[float, float], c_limits: tuple[float, float] | None = None
                ) -> str | None:
    """Re-check I and II on a finished sub-part; the problem as a phrase, or None.

    Parameters
    ----------
    child : trimesh.Trimesh
        The sub-part.
    plane : Plane
        Its base plane.
    obstacles : (k, 3) float
        Surface samples of everything printed before it.
    a_limits, c_limits : (2,) float
        Table limits, degrees (``c_limits`` None: continuous C).
    """
    if not reachable_mask(plane.normal[None], a_limits, c_limits)[0]:
        return unreachable_phrase(plane.normal, a_limits, c_limits)
    h = plane.signed(child.vertices)
    if h.min() < -1e-4 * max(1.0, child.scale):
        return "constraint II fails: the sub-part reaches below its base plane"
    lifted = Plane(plane.point + 1e-4 * plane.normal, plane.normal)
    section = base_section(child, lifted, np.ones(len(child.faces), dtype=bool))
    if section is None or section.area <= 0:
        return "constraint II fails: empty base cross-section"
    if not _platform_clear(head, plane, section):
        return "constraint I fails: the printhead would reach below the platform"
    hits = _head_hits(obstacles, plane, section, head)
    if hits:
        return f"constraint I fails: {hits} samples of the printed part lie inside the printhead"
    return None


def _head_hits(pts: np.ndarray, plane: Plane, section: BaseGeometry,
               head: Printhead) -> int:
    """Points inside the head for some tip on ``section`` (margin: the sample spacing)."""
    h = plane.signed(pts)
    up = (h > EPS) & (h <= head.height)
    if not up.any():
        return 0
    flat = (pts[up] - plane.point) @ plane_basis(plane.normal).T
    dist = shapely.distance(shapely.points(flat), section)
    return int((dist < head.radius_at(h[up]) + SAMPLE_SPACING).sum())


def unreachable_phrase(direction: np.ndarray, a_limits: tuple[float, float],
                       c_limits: tuple[float, float] | None) -> str:
    """Why build ``direction`` (3,) cannot be printed: the angles it needs and the limits."""
    lims = f"machine.a_limits [{a_limits[0]:g}, {a_limits[1]:g}]"
    if c_limits is not None:
        lims += f" / machine.c_limits [{c_limits[0]:g}, {c_limits[1]:g}]"
    dirn = "[" + ", ".join(f"{x:.3f}" for x in direction) + "]"
    return (f"constraint II fails: the build direction {dirn} needs {needed_pose(direction)}, "
            f"outside {lims}")
