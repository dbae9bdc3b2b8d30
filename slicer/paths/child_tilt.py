"""A sub-part printed on another, its layers in a fixed direction where that holds its walls.

Beyond the paper. A branch's layers follow its skeleton's tangent (paper §2.2.4), and the
decomposition judges a sub-part's overhang along its base normal. A sub-part that takes in
more than the branch overhangs along the tangent: a branch leaving a tube near its top
takes in a piece of the tube's rim, whose inner wall is vertical, and layers square to a
32° branch (58° off the vertical) print that wall 58° over air (the sweep's pipe8, 10–11
layers), while layers 33° off the vertical hold both the branch's underside and the rim.

The root's lean plan (:mod:`~slicer.paths.lean`) chooses a direction per band; a child is
short, so here one direction holds for all of it past its base: a fixed layer normal from a
grid within ``max_tilt`` of the base normal (:class:`~slicer.paths.lean_costs.DirectionGrid`,
:data:`STEP_DEG` apart), the march turning from the base to it at its own rate. A fixed
direction, not one off the skeleton: a sub-part that takes in a piece of the tube has a
skeleton that strays into it (pipe8's turns 70° sideways there), and its tangent is not the
branch's. Each candidate is priced as the lean plan prices a face (area beyond the overhang
limit, :func:`~slicer.paths.lean_costs.hinge`, the replay's hints weighing the faces near
walls it found over air) against the skeleton's own layers; the cheapest is taken when it
costs at most :data:`SHARE` of the skeleton's price and saves at least :data:`LEAST` mm².
The march still vetoes a layer the head cannot print, and the replay judges the file.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import trimesh

from slicer.decompose import Plane, on_cuts
from slicer.paths.lean_costs import CHUNK, DirectionGrid, LeanSettings, hinge
from slicer.paths.skeleton import SkeletonCurve
from slicer.planes2d import plane_frame

STEP_DEG = 5.0  # spacing of the candidate directions
SHARE = 0.5  # a direction is taken when it costs at most this share of the skeleton's ...
LEAST = 2.0  # ... and saves at least this many mm²


def _priced_faces(mesh: trimesh.Trimesh, cuts: Sequence[Plane],
                  hinted: tuple[np.ndarray, np.ndarray] | None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(normals (f, 3), centres (f, 3), weighted areas (f,), stricter limits (f,) in
    degrees) of the faces not on a cut."""
    keep = ~on_cuts(mesh, cuts)
    area = np.asarray(mesh.area_faces, dtype=float)[keep]
    margin = np.zeros(len(area))
    if hinted is not None:
        area, margin = area * hinted[0][keep], hinted[1][keep]
    return (np.asarray(mesh.face_normals, dtype=float)[keep],
            np.asarray(mesh.triangles_center, dtype=float)[keep], area, margin)


def direction_prices(mesh: trimesh.Trimesh, cuts: Sequence[Plane], directions: np.ndarray,
                     settings: LeanSettings,
                     hinted: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Weighted overhang area of ``mesh`` printed with each fixed layer normal of
    ``directions`` (m, 3), (m,) float.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The sub-part, (f,) faces.
    cuts : sequence of Plane
        Its base and its children's bases: faces on them are not priced.
    directions : (m, 3) float
        Unit layer normals.
    settings : LeanSettings
        The overhang limits (``soft_deg``, ``hard_deg``).
    hinted : ((f,) float, (f,) float), optional
        Weight and stricter limit (degrees) of every face, from the replay's hints.
    """
    n, _, area, margin = _priced_faces(mesh, cuts, hinted)
    dirs = np.asarray(directions, dtype=float).reshape(-1, 3)
    soft, hard = (settings.soft_deg - margin)[:, None], (settings.hard_deg - margin)[:, None]
    out = np.empty(len(dirs))
    # (faces, CHUNK) temporaries: all ~600 cells at once would take 150 MB per array for a
    # sub-part of 30 000 faces
    for lo in range(0, len(dirs), CHUNK):
        out[lo:lo + CHUNK] = area @ hinge(n @ dirs[lo:lo + CHUNK].T, soft, hard)
    return out


def skeleton_price(mesh: trimesh.Trimesh, curve: SkeletonCurve, cuts: Sequence[Plane],
                   settings: LeanSettings,
                   hinted: tuple[np.ndarray, np.ndarray] | None = None) -> float:
    """Weighted overhang area of ``mesh`` printed along ``curve``'s tangent (each face at
    its nearest point of the curve); parameters as :func:`direction_prices`."""
    n, c, area, margin = _priced_faces(mesh, cuts, hinted)
    d = curve.tangent(_arc(curve, c))
    return float(area @ hinge((n * d).sum(axis=1), settings.soft_deg - margin,
                              settings.hard_deg - margin))


def cheapest_direction(mesh: trimesh.Trimesh, curve: SkeletonCurve, base_normal: np.ndarray,
                       cuts: Sequence[Plane], settings: LeanSettings,
                       hinted: tuple[np.ndarray, np.ndarray] | None = None
                       ) -> np.ndarray | None:
    """The fixed layer normal (3,) to print the sub-part with instead of its skeleton's, or
    None when none within ``settings.max_tilt`` of ``base_normal`` saves enough (parameters
    as :func:`direction_prices`)."""
    grid = DirectionGrid.make(settings.max_tilt, STEP_DEG)
    dirs = grid.world(plane_frame(np.asarray(base_normal, dtype=float)))[grid.inside]
    prices = direction_prices(mesh, cuts, dirs, settings, hinted)
    tilt = grid.tilt[grid.inside]
    k = int(np.argmin(prices + settings.tilt_cost * tilt))
    along = skeleton_price(mesh, curve, cuts, settings, hinted)
    if prices[k] > SHARE * along or along - prices[k] < LEAST:
        return None
    return dirs[k]


def _arc(curve: SkeletonCurve, points: np.ndarray) -> np.ndarray:
    """Arc length of the curve's point nearest each of ``points`` (k, 3), (k,)."""
    if curve.line is not None:
        start, d = curve.line
        return np.clip((points - start) @ d, 0.0, None)
    return curve.project(points)
