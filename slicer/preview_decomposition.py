"""A PNG a person checks at a glance: sub-parts in colours, cut planes, build order labels."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from mpl_toolkits.mplot3d.art3d import Poly3DCollection

from slicer.planes import plane_basis

if TYPE_CHECKING:
    from slicer.decompose import Decomposition

MAX_FACES = 4000  # per sub-part drawn


def render_preview(dec: Decomposition, path: str | Path, views: tuple[tuple[float, float], ...]
                   = ((20.0, -60.0), (20.0, 30.0))) -> Path:
    """Draw every sub-part, its base plane and its build-order label into ``path``."""
    colours = plt.get_cmap("tab10")
    fig = plt.figure(figsize=(6.0 * len(views), 6.0), dpi=100)
    lo = np.min([s.mesh.bounds[0] for s in dec.subparts], axis=0)
    hi = np.max([s.mesh.bounds[1] for s in dec.subparts], axis=0)
    centre, half = (lo + hi) / 2.0, (hi - lo).max() / 2.0
    for v, (elev, azim) in enumerate(views):
        ax = fig.add_subplot(1, len(views), v + 1, projection="3d")
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
        ax.set_xlim(centre[0] - half, centre[0] + half)
        ax.set_ylim(centre[1] - half, centre[1] + half)
        ax.set_zlim(max(0.0, centre[2] - half), centre[2] + half)
        ax.view_init(elev, azim)
        ax.set_xlabel("x")
        ax.set_ylabel("y")
        ax.set_zlabel("z")
    fig.suptitle(f"{len(dec.subparts)} sub-parts, build order {dec.order}")
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out)
    plt.close(fig)
    return out


def _draw_plane(ax: object, plane: object, size: float, colour: object) -> None:
    u, v = plane_basis(plane.normal)
    corners = np.array([plane.point + size * (a * u + b * v)
                        for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
    ax.add_collection3d(Poly3DCollection([corners], facecolor=colour, edgecolor="black",
                                         alpha=0.35, linewidths=1.5))
    tip = plane.point + plane.normal * size
    ax.quiver(*plane.point, *(tip - plane.point), color="black", linewidth=1.5)
