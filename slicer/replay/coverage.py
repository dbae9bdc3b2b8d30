"""How much of the model's volume the deposited beads reach.

The model is sampled on a regular grid (at most ``MAX_GRID`` points). A grid point in the
*shell* (within ``perimeters · w`` of the surface) is covered when a deposited sample's bead
holds it: axial offset along that sample's nozzle axis within the bead height (± a quarter
layer) and lateral offset at most 0.75 w. A *core* point (deeper inside, where sparse infill
goes) is covered when a deposited sample lies within half the infill spacing (w / density)
plus 0.75 w laterally and 1.5 layer heights axially: the toolpaths reach it at the designed
density.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from slicer.replay.columns import volume_grid
from slicer.replay.geometry import ModelIndex
from slicer.replay.kdtree import point_tree
from slicer.replay.samples import Samples

MAX_GRID = 60_000
MIN_PITCH = 0.3
NEIGHBOURS = 12
REACH = 0.75  # × line width


def mesh_volume(tris: np.ndarray) -> float:
    """Enclosed volume of a closed mesh (t, 3, 3), mm³."""
    return abs(float(np.einsum("ij,ij->i", tris[:, 0], np.cross(tris[:, 1], tris[:, 2])).sum())
               / 6.0)


def grid_pitch(volume: float) -> float:
    """Grid spacing that keeps the grid under ``MAX_GRID`` points, mm."""
    return max(MIN_PITCH, (volume / MAX_GRID) ** (1.0 / 3.0))


def shell_grid(model: ModelIndex, depth: float) -> tuple[np.ndarray, np.ndarray]:
    """The model's coverage grid (g, 3) and which of its points lie in the shell (within
    ``depth`` of the surface), (g,) bool; kept in ``model.grids``: it needs nothing of the
    G-code, so a slicer may build it before the replay."""
    if depth not in model.grids:
        g = volume_grid(model.tris, grid_pitch(mesh_volume(model.tris)))
        model.grids[depth] = (g, model.within(g, depth) if len(g) else np.zeros(0, bool))
    return model.grids[depth]


def shell_depth(perimeters: int, line_width: float) -> float:
    """How deep the shell (the perimeters) reaches below the surface, mm."""
    return max(perimeters, 1) * line_width


def _shell_covered(g: np.ndarray, s: Samples, tree: cKDTree, w: float, t: float,
                   h_max: float) -> np.ndarray:
    r = shell_reach(w, t, h_max)
    k = min(NEIGHBOURS, len(s))
    dist, idx = tree.query(g, k=k, distance_upper_bound=r, workers=-1)
    dist, idx = dist.reshape(len(g), k), idx.reshape(len(g), k)
    valid = np.isfinite(dist)
    j = np.where(valid, idx, 0)
    rel = g[:, None, :] - s.p[j]
    u = s.u[j]
    ax = np.einsum("ijk,ijk->ij", rel, u)
    lat = np.linalg.norm(rel - ax[..., None] * u, axis=2)
    inside = (ax <= 0.25 * t) & (ax >= -s.h[j] - 0.25 * t) & (lat <= REACH * w)
    return (valid & inside).any(axis=1)


def _core_covered(g: np.ndarray, s: Samples, tree: cKDTree, lateral: float, t: float
                  ) -> np.ndarray:
    k = min(NEIGHBOURS, len(s))
    dist, idx = tree.query(g, k=k, distance_upper_bound=float(np.hypot(lateral, 1.5 * t)),
                           workers=-1)
    dist, idx = dist.reshape(len(g), k), idx.reshape(len(g), k)
    valid = np.isfinite(dist)
    rel = g[:, None, :] - s.p[np.where(valid, idx, 0)]
    ax = np.einsum("ijk,ijk->ij", rel, s.u[np.where(valid, idx, 0)])
    return (valid & (np.abs(ax) <= 1.5 * t)).any(axis=1)


def shell_reach(line_width: float, layer_height: float, h_max: float) -> float:
    """How far from a shell grid point a covering sample may lie, mm (``h_max``: the
    largest bead height)."""
    return float(np.hypot(REACH * line_width, h_max + 0.25 * layer_height))


def core_lateral(line_width: float, infill_density: float) -> float:
    """Lateral reach of a sample covering a core grid point, mm."""
    spacing = line_width / infill_density if infill_density > 0 else 0.0
    return 0.5 * spacing + REACH * line_width


def coverage_reach(line_width: float, layer_height: float, infill_density: float,
                   h_max: float) -> float:
    """How far from a grid point any covering sample may lie, mm."""
    return max(shell_reach(line_width, layer_height, h_max),
               float(np.hypot(core_lateral(line_width, infill_density), 1.5 * layer_height)))


def covered(g: np.ndarray, shell: np.ndarray, s: Samples, tree: cKDTree, line_width: float,
            layer_height: float, infill_density: float, h_max: float) -> np.ndarray:
    """Which grid points ``g`` (k, 3) (``shell`` (k,) bool: those in the shell) a sample of
    ``s`` (KD-tree ``tree``) covers, (k,) bool. ``h_max`` is the largest bead height of all
    the deposits, so that ``s`` may be those near ``g`` only: every sample within
    :func:`coverage_reach` of a point of ``g``."""
    out = np.zeros(len(g), dtype=bool)
    if len(s) == 0 or len(g) == 0:
        return out
    out[shell] = _shell_covered(g[shell], s, tree, line_width, layer_height, h_max)
    core = ~shell
    if core.any():
        out[core] = _core_covered(g[core], s, tree, core_lateral(line_width, infill_density),
                                  layer_height)
    return out


def shares(covered: np.ndarray, shell: np.ndarray) -> tuple[float, float]:
    """(total, shell) shares of the grid ``covered`` (1.0 for an empty grid or shell)."""
    if len(covered) == 0:
        return 1.0, 1.0
    return float(covered.mean()), float(covered[shell].mean()) if shell.any() else 1.0


def coverage(model: ModelIndex, s: Samples, line_width: float, layer_height: float,
             perimeters: int, infill_density: float, tree: cKDTree | None = None
             ) -> tuple[float, float]:
    """Share of the model volume covered, overall and in the shell, by all the deposits.

    Parameters
    ----------
    model : ModelIndex
        The model in the platform frame.
    s : Samples
        Deposited samples.
    tree : cKDTree, optional
        KD-tree of ``s.p`` (built when not given).

    Returns
    -------
    (total, shell) : float, float
        Shares in [0, 1] (1.0 for an empty model).
    """
    g, shell = shell_grid(model, shell_depth(perimeters, line_width))
    if len(g) == 0:
        return 1.0, 1.0
    if len(s) == 0:
        return 0.0, 0.0
    tree = point_tree(s.p) if tree is None else tree
    h_max = float(s.h.max())
    return shares(covered(g, shell, s, tree, line_width, layer_height, infill_density, h_max),
                  shell)
