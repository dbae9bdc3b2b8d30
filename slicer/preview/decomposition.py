"""A PNG a person checks at a glance: sub-parts in colours, cut planes, build order labels,
and the coarse region numbers that ``hostctl decompose --root`` takes; for a refused
decomposition, the part as placed with the point the refusal names in red."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from mpl_toolkits.mplot3d.art3d import Poly3DCollection

from slicer.decompose import Plane, plane_basis

if TYPE_CHECKING:
    import trimesh
    from matplotlib.typing import ColorType
    from mpl_toolkits.mplot3d import Axes3D

    from slicer.decompose import Decomposition

MAX_FACES = 4000  # per sub-part drawn


def render_preview(dec: Decomposition, path: str | Path, views: tuple[tuple[float, float], ...]
                   = ((20.0, -60.0), (20.0, 30.0))) -> Path:
    """Draw every sub-part, its base plane and its build-order label into ``path``."""
    colours = plt.get_cmap("tab10")
    panels = len(views) + (dec.partition is not None)
    fig = plt.figure(figsize=(6.0 * panels, 6.0), dpi=100)
    lo = np.min([s.mesh.bounds[0] for s in dec.subparts], axis=0)
    hi = np.max([s.mesh.bounds[1] for s in dec.subparts], axis=0)
    centre, half = (lo + hi) / 2.0, (hi - lo).max() / 2.0
    for v, (elev, azim) in enumerate(views):
        ax = fig.add_subplot(1, panels, v + 1, projection="3d")
        for rank, i in enumerate(dec.order):
            s = dec.subparts[i]
            c = colours(i % 10)
            faces = s.mesh.triangles[:: max(1, len(s.mesh.faces) // MAX_FACES)]
            ax.add_collection3d(Poly3DCollection(faces, facecolor=c, edgecolor="none",
                                                 alpha=0.55))
            label = f"#{rank + 1}: part {i}" + ("" if s.parent is None else f" on {s.parent}")
            top = s.mesh.centroid + s.build_direction * 0.6 * np.ptp(s.mesh.vertices, 0).max()
            ax.text(*top, label, color="black", fontsize=9, weight="bold")
            if s.base_plane is not None:
                _draw_plane(ax, s.base_plane, np.sqrt(s.base_area) * 1.2, c)
        _frame(ax, centre, half, elev, azim)
    if dec.partition is not None:
        ax = fig.add_subplot(1, panels, panels, projection="3d")
        _draw_regions(ax, dec)
        ax.set_title("coarse regions (hostctl decompose --root N)")
        _frame(ax, centre, half, *views[0])
    fig.suptitle(f"{len(dec.subparts)} sub-parts, build order {dec.order}")
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out)
    plt.close(fig)
    return out


def render_refused(mesh: trimesh.Trimesh, points: np.ndarray, reason: str, path: str | Path,
                   views: tuple[tuple[float, float], ...] = ((20.0, -60.0), (20.0, 30.0))
                   ) -> Path:
    """Draw the part ``mesh`` as placed with ``points`` (k, 3), the failing region a refused
    decomposition names, as large red dots; ``reason`` (one line) is the title."""
    fig = plt.figure(figsize=(6.0 * len(views), 6.5), dpi=100)
    lo, hi = mesh.bounds
    centre, half = (lo + hi) / 2.0, float((hi - lo).max()) / 2.0
    faces = mesh.triangles[:: max(1, len(mesh.faces) // MAX_FACES)]
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    for v, (elev, azim) in enumerate(views):
        # drawn in the order given, so the point stays in front of the faces
        ax = fig.add_subplot(1, len(views), v + 1, projection="3d", computed_zorder=False)
        ax.add_collection3d(Poly3DCollection(faces, facecolor="lightgrey", edgecolor="none",
                                             alpha=0.45))
        if len(p):
            ax.scatter(p[:, 0], p[:, 1], p[:, 2], c="red", s=120, edgecolors="black",
                       depthshade=False)
        _frame(ax, centre, half, elev, azim)
    fig.suptitle(_wrapped(f"refused: {reason}"), fontsize=9)
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out)
    plt.close(fig)
    return out


def _wrapped(text: str, width: int = 150) -> str:
    """``text`` broken into lines of at most about ``width`` characters."""
    import textwrap

    return "\n".join(textwrap.wrap(text, width))


def _frame(ax: Axes3D, centre: np.ndarray, half: float, elev: float, azim: float) -> None:
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(max(0.0, centre[2] - half), centre[2] + half)
    ax.view_init(elev, azim)
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_zlabel("z")


def _draw_regions(ax: Axes3D, dec: Decomposition) -> None:
    """Coarse regions in colours, each labelled with its number (what ``--root`` takes) at
    the face nearest its area centroid."""
    part = dec.partition
    assert part is not None
    step = max(1, len(part.mesh.faces) // (MAX_FACES * 2))
    cmap = plt.get_cmap("tab20")
    ax.add_collection3d(Poly3DCollection(part.mesh.triangles[::step], edgecolor="none",
                                         facecolor=cmap(part.labels[::step] % 20), alpha=0.5))
    centres = part.centres()
    tri = part.mesh.triangles_center
    for r in range(part.count):
        faces = np.flatnonzero(part.labels == r)
        at = tri[faces[np.argmin(np.linalg.norm(tri[faces] - centres[r], axis=1))]]
        ax.text(*at, str(r), color="black", fontsize=9, weight="bold",
                bbox={"facecolor": "white", "alpha": 0.7, "pad": 1, "edgecolor": "none"})


def _draw_plane(ax: Axes3D, plane: Plane, size: float, colour: ColorType) -> None:
    u, v = plane_basis(plane.normal)
    corners = np.array([plane.point + size * (a * u + b * v)
                        for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
    ax.add_collection3d(Poly3DCollection([corners], facecolor=colour, edgecolor="black",
                                         alpha=0.35, linewidths=1.5))
    tip = plane.point + plane.normal * size
    ax.quiver(*plane.point, *(tip - plane.point), color="black", linewidth=1.5)
