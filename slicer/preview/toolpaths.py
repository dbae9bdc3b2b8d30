"""A PNG of a print plan's toolpaths in the platform frame, coloured by sub-part, with the
points a refusal names (unsupported walls, a layer in the air) marked in red."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from mpl_toolkits.mplot3d.art3d import Line3DCollection

from slicer.plan import PrintPlan

MAX_SEGMENTS = 60_000  # per view, evenly thinned beyond this
MARK_COLOUR = "red"


def _segments(plan: PrintPlan) -> tuple[np.ndarray, np.ndarray]:
    """All extrusion segments (n, 2, 3) and the sub-part of each (n,)."""
    segs, owner = [], []
    for sp in plan.subparts:
        for layer in sp.layers:
            for path in layer.paths:
                p = np.asarray(path.points, dtype=float).reshape(-1, 3)
                if path.closed and len(p) > 2:
                    p = np.vstack([p, p[:1]])
                if len(p) < 2:
                    continue
                segs.append(np.stack([p[:-1], p[1:]], axis=1))
                owner.append(np.full(len(p) - 1, sp.index))
    if not segs:
        return np.zeros((0, 2, 3)), np.zeros(0, dtype=int)
    return np.concatenate(segs), np.concatenate(owner)


def render_toolpaths(plan: PrintPlan, path: str | Path, dpi: int = 110,
                     marks: np.ndarray | None = None, note: str | None = None) -> None:
    """Write a two-view PNG (3D and side view) of the plan's toolpaths to ``path``.

    ``marks`` (k, 3) are platform-frame points drawn in red over the paths (the failing
    region of a refusal), labelled ``note`` in the legend and the title.
    """
    segs, owner = _segments(plan)
    marks = np.zeros((0, 3)) if marks is None else np.asarray(marks, dtype=float).reshape(-1, 3)
    if len(segs) > MAX_SEGMENTS:
        keep = np.linspace(0, len(segs) - 1, MAX_SEGMENTS).astype(int)
        segs, owner = segs[keep], owner[keep]
    cmap = plt.get_cmap("tab10")
    colors = cmap(owner % 10) if len(owner) else np.zeros((0, 4))
    fig = plt.figure(figsize=(11, 5.5))
    # drawn in the order given, so the marks stay in front of the paths
    ax = fig.add_subplot(1, 2, 1, projection="3d", computed_zorder=False)
    ax.add_collection3d(Line3DCollection(segs, colors=colors, linewidths=0.3))
    if len(marks):
        ax.scatter(marks[:, 0], marks[:, 1], marks[:, 2], c=MARK_COLOUR, s=4,
                   depthshade=False)
    if len(segs):
        lo, hi = segs.reshape(-1, 3).min(axis=0), segs.reshape(-1, 3).max(axis=0)
        span = float((hi - lo).max()) / 2 or 1.0
        mid = (lo + hi) / 2
        ax.set_xlim(mid[0] - span, mid[0] + span)
        ax.set_ylim(mid[1] - span, mid[1] + span)
        ax.set_zlim(max(0.0, mid[2] - span), mid[2] + span)
    ax.set_xlabel("x mm")
    ax.set_ylabel("y mm")
    ax.set_zlabel("z mm")
    side = fig.add_subplot(1, 2, 2)
    from matplotlib.collections import LineCollection

    # matplotlib types segments as a Sequence; its docs (and code) take an (n, 2, 2) array too
    side.add_collection(LineCollection(segs[:, :, [0, 2]],  # type: ignore[arg-type]
                                       colors=colors, linewidths=0.3))
    if len(marks):
        side.scatter(marks[:, 0], marks[:, 2], c=MARK_COLOUR, s=4, zorder=3)
    side.autoscale()
    side.set_aspect("equal")
    side.set_xlabel("x mm")
    side.set_ylabel("z mm")
    handles = [plt.Line2D([], [], color=cmap(sp.index % 10), label=f"sub-part {sp.index}")
               for sp in plan.subparts]
    if len(marks):
        handles.append(plt.Line2D([], [], color=MARK_COLOUR, marker="o", linestyle="",
                                  label=note or "marked"))
    side.legend(handles=handles, loc="upper right", fontsize=8)
    fig.suptitle(f"{len(plan.subparts)} sub-parts, "
                 f"{sum(len(sp.layers) for sp in plan.subparts)} layers"
                 + (f": {note}" if note and len(marks) else ""))
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
