"""The KD-trees of the replay check, built the way that is fastest on its point sets."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def point_tree(points: np.ndarray, leafsize: int = 16) -> cKDTree:
    """A KD-tree of ``points`` (n, k) split at the midpoint of each cell, not the median.

    On the replay's point sets (beads along toolpaths, samples on a surface) the sliding
    midpoint tree builds about three times faster than the balanced one and answers the
    nearest-neighbour queries faster too; the answers are the same. ``leafsize``: points
    per leaf (the dense surface samples are searched faster with 32).
    """
    return cKDTree(points, leafsize=leafsize, balanced_tree=False, compact_nodes=False)
