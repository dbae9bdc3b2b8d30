"""An upright sub-part as a column for the lean plan, and its stacked pieces at the plan's jumps.

Beyond the paper: where the lean plan (:mod:`~slicer.paths.lean`) needs a faster change of
direction than the wedge bound lets layers turn, it *jumps*: the sub-part is cut there by the
plane square to the new direction, and the piece above is printed on the cut, as a child is
printed on its base. A cut must leave exactly one solid on each side, leave every earlier
piece under it, and cut no child's base; a jump that does not is refused and the
plan solved again without it.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TypeVar

import manifold3d as m3
import numpy as np
import shapely
import trimesh

from slicer.decompose import Decomposition, Plane, Subpart
from slicer.mesh import to_manifold, to_trimesh
from slicer.paths.lean import LeanPlan
from slicer.paths.lean_costs import Column
from slicer.planes2d import section

T = TypeVar("T")

PROFILE_STEP = 0.5  # mm between the sections that measure the part's extent about its axis
BASE_TOL = 1e-3  # mm: a child's mesh vertex this close to its base plane lies on the base
STRADDLE = 0.5  # mm a child's base keeps from a jump's cut
STACK_TOL = 1e-3  # mm an earlier piece may reach above a later cut (rounding)
MIN_PIECE = 1e-3  # share of the volume below which a cut's fragment is no piece


@dataclass(frozen=True)
class Piece:
    """One stacked piece: its solid and the cut it stands on (None for the lowest)."""

    mesh: trimesh.Trimesh
    base: Plane | None


def column_of(subpart: Subpart, children: Sequence[Subpart], solid: m3.Manifold,
              origin: np.ndarray, frame: np.ndarray,
              hinted: tuple[np.ndarray, np.ndarray] | None = None) -> Column:
    """The :class:`~slicer.paths.lean_costs.Column` of an upright sub-part whose axis starts
    at ``origin`` with ``frame`` (rows u, v, axis); ``children`` are printed on it;
    ``hinted`` is (weight, margin) per face from a retry's hints."""
    weights, margins = (None, None) if hinted is None else hinted
    return Column(subpart.mesh, np.asarray(origin, dtype=float), np.asarray(frame, dtype=float),
                  [c.base_plane for c in children if c.base_plane is not None],
                  [_base_points(c) for c in children],
                  profile(solid, origin, frame, _height(subpart.mesh, origin, frame[2])),
                  weights, margins)


def _height(mesh: trimesh.Trimesh, origin: np.ndarray, axis: np.ndarray) -> float:
    return float(np.max((np.asarray(mesh.vertices) - origin) @ axis))


def _base_points(child: Subpart) -> np.ndarray:
    """The child's mesh vertices on its base plane, (k, 3)."""
    v = np.asarray(child.mesh.vertices, dtype=float)
    base = child.base_plane
    if base is None:
        return np.zeros((0, 3))
    h = (v - np.asarray(base.point, dtype=float)) @ np.asarray(base.normal, dtype=float)
    return v[np.abs(h) < BASE_TOL]


def profile(solid: m3.Manifold, origin: np.ndarray, frame: np.ndarray, height: float
            ) -> tuple[np.ndarray, np.ndarray]:
    """The part's largest distance from its axis at heights every ``PROFILE_STEP`` mm,
    ((m,), (m,)); 0 where a section is empty."""
    z = np.arange(0.0, max(height, 0.0) + PROFILE_STEP, PROFILE_STEP)
    radius = np.zeros(len(z))
    axis = np.asarray(frame[2], dtype=float)
    for i, h in enumerate(z):
        xy = shapely.get_coordinates(section(solid, origin + (h + 1e-3) * axis, frame))
        radius[i] = float(np.linalg.norm(xy, axis=1).max()) if len(xy) else 0.0
    return z, radius


def stack(column: Column, plan: LeanPlan) -> tuple[list[Piece], int | None]:
    """Cut the column at the plan's jumps, lowest first: (pieces, None), or ([], the band of
    the first jump that cannot be made)."""
    rest = to_manifold(column.mesh)
    volume = rest.volume()
    pieces: list[Piece] = []
    below: Plane | None = None
    lows: list[m3.Manifold] = []
    for band in plan.jumps:
        cut = plan.cut(band)
        split = _split(rest, cut, MIN_PIECE * volume)
        if split is None or not _clear(cut, column) or not _under(lows, cut):
            return [], band
        low, rest = split
        pieces.append(Piece(to_trimesh(low), below))
        lows.append(low)
        below = cut
    pieces.append(Piece(to_trimesh(rest), below))
    return pieces, None


def _split(solid: m3.Manifold, cut: Plane, least: float
           ) -> tuple[m3.Manifold, m3.Manifold] | None:
    """(below, above) the cut when each side is one solid (fragments under ``least`` mm³
    ignored), else None."""
    offset = float(cut.point @ cut.normal)
    above = [c for c in solid.trim_by_plane(cut.normal, offset).decompose()
             if c.volume() > least]
    low = [c for c in solid.trim_by_plane(-cut.normal, -offset).decompose()
           if c.volume() > least]
    if len(above) != 1 or len(low) != 1:
        return None
    return low[0], above[0]


def _clear(cut: Plane, column: Column) -> bool:
    """The cut leaves every child's base on one side, ``STRADDLE`` mm away."""
    for pts in column.child_bases:
        h = cut.signed(pts) if len(pts) else np.zeros(0)
        if len(h) and h.min() < STRADDLE and h.max() > -STRADDLE:
            return False
    return True


def _under(pieces: Sequence[m3.Manifold], cut: Plane) -> bool:
    """Every earlier piece lies under the cut: material above it would be in the head's way
    when the piece on the cut starts."""
    for piece in pieces:
        v = np.asarray(piece.to_mesh64().vert_properties)[:, :3]
        if len(v) and float(cut.signed(v).max()) > STACK_TOL:
            return False
    return True


def restack(decomposition: Decomposition, root: int, pieces: Sequence[Piece],
            defer: frozenset[int] = frozenset()) -> tuple[Decomposition, dict[int, int]]:
    """``decomposition`` with sub-part ``root`` replaced by its stacked ``pieces``, numbered
    ``root, root + 1, ...``; later sub-parts are renumbered after them, and each child of the
    root is printed on the piece that holds its base.

    The pieces print in a row, then the other sub-parts in their order, except the root's
    children in ``defer`` (original indices) and everything printed on them: those print
    right after the piece holding their base, before the pieces above it (a branch that
    turns back along the root, which the head could not reach past the finished root).

    Returns the decomposition and the original index of every sub-part that is no piece.
    """
    extra = len(pieces) - 1
    old = {s.index: s for s in decomposition.subparts}
    renum = {k: (k if k < root else k + extra) for k in old if k != root}
    cuts = [p.base for p in pieces[1:] if p.base is not None]
    subs = [_piece(old[root], k + root, p) for k, p in enumerate(pieces)]
    on_piece: dict[int, int] = {}
    for k, sp in old.items():
        if k == root:
            continue
        parent = sp.parent
        if parent == root and sp.base_plane is not None:
            at = np.asarray(sp.base_plane.point, dtype=float)[None]
            parent = root + sum(1 for c in cuts if c.signed(at)[0] > 0)
            on_piece[k] = parent
        elif parent is not None:
            parent = renum[parent]
        subs.append(_with(sp, index=renum[k], parent=parent))
    early = _subtrees(old, defer)
    order: list[int] = []
    for i in range(len(pieces)):
        order.append(root + i)
        order += [renum[k] for k in decomposition.order
                  if k in early and on_piece.get(_top(old, k, root), -1) == root + i]
    order += [renum[k] for k in decomposition.order if k != root and k not in early]
    dec = _with(decomposition, subparts=sorted(subs, key=lambda s: s.index), order=order)
    return dec, {v: k for k, v in renum.items()}


def _subtrees(subs: dict[int, Subpart], tops: frozenset[int]) -> set[int]:
    """The sub-parts ``tops`` and everything printed on them, directly or not."""
    out = set(tops)
    grew = True
    while grew:
        more = {k for k, sp in subs.items() if sp.parent in out and k not in out}
        out |= more
        grew = bool(more)
    return out


def _top(subs: dict[int, Subpart], k: int, root: int) -> int:
    """The child of ``root`` that sub-part ``k`` is printed on, directly or not (``k`` when
    it has no such ancestor)."""
    seen = 0
    while subs[k].parent not in (root, None) and seen < len(subs):
        k = int(subs[k].parent)  # type: ignore[arg-type]
        seen += 1
    return k


def _piece(root: Subpart, index: int, piece: Piece) -> Subpart:
    """A stacked piece as a sub-part: the lowest keeps the root's place on the platform."""
    if piece.base is None:
        return _with(root, index=index, mesh=piece.mesh)
    return _with(root, index=index, parent=index - 1, mesh=piece.mesh, base_plane=piece.base,
                 base_area=0.0, build_direction=piece.base.normal.copy())


def _with(obj: T, **changes: object) -> T:
    """A copy of ``obj`` with ``changes``: a dataclass by :func:`dataclasses.replace`, any
    other record (a test's namespace) by a shallow copy."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return dataclasses.replace(obj, **changes)
    out = copy.copy(obj)
    for name, value in changes.items():
        setattr(out, name, value)
    return out
