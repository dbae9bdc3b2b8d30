"""Build order (paper 2.2.2): region adjacency graph, BFS from the root, and grouping.

The coarse regions are merged into *groups* while walking the BFS tree: a region joins its
BFS parent's group when its own axis (the least-spread direction of its area-weighted face
normals: the axis of a tube or rod, whether hollow or not) lies within ``merge_angle`` of the
group's build direction, or when the region is not tubular enough to have an axis (junction
blobs, caps). The root group prints along +Z. A region also joins a group when it prints along
the group's direction with no face overhanging more than 40° from vertical. A tube that
k-means cut into several slices or sectors is therefore one sub-part, and a branch leaving it
at an angle starts a new group whose direction is its axis, oriented away from the parent.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from slicer.partition import Partition, boundary_lengths

MERGE_ANGLE = 25.0  # degrees between a region's axis and its group's direction
TUBULAR_RATIO = 0.35  # λ_min / λ_mid of the normal covariance below which a region has an axis
OVERHANG_COS = np.cos(np.radians(50.0))  # n·(-d) above this: a face overhangs direction d
OVERHANG_SHARE = 0.02  # a region prints along d when less of its area overhangs
COAXIAL_SHARE = 0.5  # bore/outside of one tube: centres within this share of the patch radius
SWEEP_RATIO = 0.25  # λ_mid / λ_max above which its normals sweep around that axis


@dataclass
class Groups:
    """Regions merged into printable groups, in build order.

    Attributes
    ----------
    region_group : (k,) int
        Group of every coarse region.
    parent : list of int or None
        Parent group of every group (``None`` for the root group 0).
    direction : (g, 3) float
        Nominal build direction of every group (+Z for the root).
    order : list of int
        BFS order of groups (group ids are already in this order).
    adjacency : (k, k) float
        Shared boundary length between coarse regions.
    """

    region_group: np.ndarray
    parent: list[int | None]
    direction: np.ndarray
    order: list[int]
    adjacency: np.ndarray

    @property
    def count(self) -> int:
        """Number of groups."""
        return len(self.parent)


def region_axes(part: Partition) -> tuple[np.ndarray, np.ndarray]:
    """Tube axis of every region and whether it is well defined.

    Returns
    -------
    axes : (k, 3) float
        Unit eigenvector of the smallest eigenvalue of Σ area · n nᵀ.
    tubular : (k,) bool
        Whether the normals sweep around that axis: λ_min / λ_mid < :data:`TUBULAR_RATIO`
        and λ_mid / λ_max > :data:`SWEEP_RATIO` (a flat slab or a narrow strip has no axis).
    """
    n, w, lab = part.mesh.face_normals, part.mesh.area_faces, part.labels
    outer = n[:, :, None] * n[:, None, :] * w[:, None, None]
    cov = np.zeros((part.count, 3, 3))
    np.add.at(cov, lab, outer)
    vals, vecs = np.linalg.eigh(cov)
    ratio = vals[:, 0] / np.maximum(vals[:, 1], 1e-12)
    sweep = vals[:, 1] / np.maximum(vals[:, 2], 1e-12)
    return vecs[:, :, 0], (ratio < TUBULAR_RATIO) & (sweep > SWEEP_RATIO)


def bfs_tree(adjacency: np.ndarray, root: int) -> tuple[list[int], list[int | None]]:
    """BFS order and parent of every node reachable from ``root`` (neighbours by boundary
    length, longest first, so the order is deterministic)."""
    k = len(adjacency)
    parent: list[int | None] = [None] * k
    seen = np.zeros(k, dtype=bool)
    seen[root] = True
    order, queue = [], deque([root])
    while queue:
        r = queue.popleft()
        order.append(r)
        nbrs = np.flatnonzero(adjacency[r] > 0)
        for s in nbrs[np.argsort(-adjacency[r, nbrs], kind="stable")]:
            if not seen[s]:
                seen[s] = True
                parent[s] = r
                queue.append(int(s))
    return order, parent


def root_region(part: Partition, base_z: float = 0.0, tol: float = 1e-3) -> int:
    """The region holding the most flat-base area (faces facing -Z on z = base_z)."""
    m = part.mesh
    on_base = (m.face_normals[:, 2] < -0.999) & (np.abs(m.triangles_center[:, 2] - base_z) < tol)
    area = np.bincount(part.labels[on_base], weights=m.area_faces[on_base],
                       minlength=part.count)
    if area.max() <= 0:
        return int(np.argmin(part.centres()[:, 2]))
    return int(np.argmax(area))


def group_regions(part: Partition, root: int, merge_angle: float = MERGE_ANGLE) -> Groups:
    """Merge coarse regions into printable groups, grown greedily from the root.

    A group absorbs every adjacent free region whose axis is within ``merge_angle`` of the
    group's direction, until none is left; then regions without an axis join the neighbouring
    group they share the longest boundary with; then the free region sharing the longest
    boundary with an existing group starts a new group (direction: its axis, oriented away
    from that group). Regions touching the flat base always join the root group.
    """
    adjacency = boundary_lengths(part.mesh, part.labels)
    order, _ = bfs_tree(adjacency, root)
    if len(order) != part.count:
        raise ValueError("the part's regions are not all connected to the root region")
    axes, tubular = region_axes(part)
    centres = part.centres()
    cos_max = np.cos(np.radians(merge_angle))
    group = np.full(part.count, -1)
    group[root] = 0
    group[_base_regions(part)] = 0
    gparent: list[int | None] = [None]
    gdir = [np.array([0.0, 0.0, 1.0])]
    while (group < 0).any():
        _grow_aligned(group, gdir, adjacency, axes, tubular, cos_max, part)
        _absorb_axisless(group, adjacency, tubular)
        _join_coaxial(group, np.asarray(gdir), axes, tubular, centres, part.areas(), cos_max)
        free = group < 0
        if not free.any():
            break
        touch = adjacency[np.ix_(group >= 0, free)]
        i, j = np.unravel_index(np.argmax(touch), touch.shape)
        p, r = np.flatnonzero(group >= 0)[i], np.flatnonzero(free)[j]
        away = centres[r] - centres[p]
        group[r] = len(gparent)
        gparent.append(int(group[p]))
        gdir.append(axes[r] if axes[r] @ away >= 0 else -axes[r])
    return Groups(group, gparent, np.asarray(gdir), list(range(len(gparent))), adjacency)


def _base_regions(part: Partition, tol: float = 1e-3) -> np.ndarray:
    m = part.mesh
    on_base = np.abs(m.vertices[m.faces][:, :, 2]).min(axis=1) < tol
    return np.unique(part.labels[on_base])


def overhang_share(part: Partition, direction: np.ndarray) -> np.ndarray:
    """Share of each region's area that overhangs when printed along ``direction``, (k,)."""
    m = part.mesh
    over = (m.face_normals @ -np.asarray(direction)) > OVERHANG_COS
    bad = np.bincount(part.labels, weights=m.area_faces * over, minlength=part.count)
    return bad / np.maximum(part.areas(), 1e-12)


def _grow_aligned(group: np.ndarray, gdir: list[np.ndarray], adjacency: np.ndarray,
                  axes: np.ndarray, tubular: np.ndarray, cos_max: float,
                  part: Partition) -> None:
    """Let every group absorb adjacent free regions aligned with its direction, or printable
    along it without overhang (in place)."""
    printable = [overhang_share(part, d) < OVERHANG_SHARE for d in gdir]
    changed = True
    while changed:
        changed = False
        for r in np.flatnonzero(group < 0):
            nb = np.flatnonzero((adjacency[r] > 0) & (group >= 0))
            for g in np.unique(group[nb]):
                if printable[g][r] or (tubular[r] and abs(axes[r] @ gdir[g]) >= cos_max):
                    group[r] = g
                    changed = True
                    break


def _join_coaxial(group: np.ndarray, gdir: np.ndarray, axes: np.ndarray, tubular: np.ndarray,
                  centres: np.ndarray, areas: np.ndarray, cos_max: float) -> None:
    """A free tubular region joins the group of a grouped tubular region on the same axis
    nearby (in place): the bore and the outside of one hollow tube share no edge, only the
    wall between them, so adjacency alone never puts them together.

    Both axes must be within the merge angle of each other and of the group's direction
    ``gdir`` (g, 3); "nearby": the centres are closer than :data:`COAXIAL_SHARE` of the
    smaller region's patch radius sqrt(area / π).
    """
    radius = COAXIAL_SHARE * np.sqrt(areas / np.pi)
    changed = True
    while changed:
        changed = False
        for r in np.flatnonzero((group < 0) & tubular):
            cand = np.flatnonzero((group >= 0) & tubular)
            dist = np.linalg.norm(centres[cand] - centres[r], axis=1)
            near = ((dist < np.minimum(radius[cand], radius[r]))
                    & (np.abs(axes[cand] @ axes[r]) >= cos_max)
                    & (np.abs(gdir[group[cand]] @ axes[r]) >= cos_max))
            if near.any():
                group[r] = group[cand[near][np.argmin(dist[near])]]
                changed = True


def _absorb_axisless(group: np.ndarray, adjacency: np.ndarray, tubular: np.ndarray) -> None:
    """Regions without an axis join the adjacent group with the longest boundary (in place)."""
    changed = True
    while changed:
        changed = False
        for r in np.flatnonzero((group < 0) & ~tubular):
            nb = np.flatnonzero((adjacency[r] > 0) & (group >= 0))
            if len(nb):
                group[r] = group[nb[np.argmax(adjacency[r, nb])]]
                changed = True
