"""Build order (paper 2.2.2): region adjacency graph, BFS from the root, and grouping.

The coarse regions are merged into *groups* while walking the BFS tree: a region joins its
BFS parent's group when its own axis (the least-spread direction of its area-weighted face
normals: the axis of a tube or rod, whether hollow or not) lies within ``merge_angle`` of the
group's build direction, or when the region is not tubular enough to have an axis (junction
blobs, caps). The root group prints along +Z. A region also joins a group when it prints along
the group's direction with no face overhanging more than 40° from vertical. A tube that
k-means cut into several slices or sectors is therefore one sub-part, and a branch leaving it
at an angle starts a new group whose direction is its axis, oriented away from the parent.

A solid branch's flat end cap hides its axis from the plain normal-spread test; such regions
are judged again on their side faces (:func:`side_axes`, :func:`revolve_misfit`). A region
still without an axis that would overhang in the group it joined is halved when that exposes
a branch (:func:`group_regions_refined`). See docs/decomposition.md, step 3.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from slicer.decompose.partition import (
    Partition,
    boundary_lengths,
    split_region,
    split_region_k,
)

MERGE_ANGLE = 25.0  # degrees between a region's axis and its group's direction
TUBULAR_RATIO = 0.35  # λ_min / λ_mid of the normal covariance below which a region has an axis
OVERHANG_COS = np.cos(np.radians(50.0))  # n·(-d) above this: a face overhangs direction d
OVERHANG_SHARE = 0.02  # a region prints along d when less of its area overhangs
COAXIAL_SHARE = 0.5  # bore/outside of one tube: centres within this share of the patch radius
SWEEP_RATIO = 0.25  # λ_mid / λ_max above which its normals sweep around that axis
CAP_ANGLE = 10.0  # degrees: faces whose normal is this close to ±axis are caps, not sides
SIDE_SHARE = 0.5  # side faces must hold this share of a region's area for it to have an axis
SPLIT_ROUNDS = 2  # times a stranded region (no axis, overhanging in its group) may be halved
REVOLVE_MISFIT = 0.3  # side normals must meet the axis line within this share of the radius


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

    The plain estimate is the unit eigenvector of the smallest eigenvalue of
    Σ area · n nᵀ over the region's faces. It is well defined when the normals sweep around
    it: λ_min / λ_mid < :data:`TUBULAR_RATIO` and λ_mid / λ_max > :data:`SWEEP_RATIO` (a flat
    slab or a narrow strip has no axis). A flat end cap (the end of a solid rod, normals along
    the axis) adds its whole area to λ_min and can hide the axis of the tube it closes; a
    region that fails the plain test is therefore tried again on its *side faces* only
    (:func:`side_axes`).

    Returns
    -------
    axes : (k, 3) float
        Unit axis of every region.
    tubular : (k,) bool
        Whether that axis is well defined, by the plain test or on the side faces.
    """
    cov = _normal_covariance(part, np.ones((len(part.labels), 1), dtype=bool))[:, 0]
    vals, vecs = np.linalg.eigh(cov)
    plain = _sweeps(vals)
    side_axis, side_ok = side_axes(part, vecs)
    use_side = ~plain & side_ok
    axes = np.where(use_side[:, None], side_axis, vecs[:, :, 0])
    return axes, plain | side_ok


def side_axes(part: Partition, candidates: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axis of every region estimated from its side faces, ignoring the caps.

    For each candidate axis a (the three eigenvectors of the region's normal covariance) the
    faces whose normals lie within :data:`CAP_ANGLE` of ±a are taken as caps and dropped; the
    covariance of the remaining *side* faces must pass the sweep test
    (:func:`_sweeps`) and the side faces must hold at least :data:`SIDE_SHARE` of the region's
    area (a region that is mostly cap has no axis). Among the candidates that qualify, the one
    whose side faces give the smallest λ_min / λ_mid wins; its axis is the side covariance's
    least-spread direction.

    Parameters
    ----------
    part : Partition
    candidates : (k, 3, 3) float
        Candidate axes of every region, one per column.

    Returns
    -------
    axes : (k, 3) float
        Side-face axis of every region (the first candidate where none qualifies).
    ok : (k,) bool
        Whether some candidate qualifies.
    """
    n, w, lab = part.mesh.face_normals, part.mesh.area_faces, part.labels
    dots = np.einsum("fi,fic->fc", n, candidates[lab])  # (f, 3): n · candidate c
    side = np.abs(dots) < np.cos(np.radians(CAP_ANGLE))
    vals, vecs = np.linalg.eigh(_normal_covariance(part, side))  # (k, 3, 3), (k, 3, 3, 3)
    share = np.stack([np.bincount(lab, weights=w * side[:, c], minlength=part.count)
                      for c in range(3)], axis=1) / np.maximum(part.areas(), 1e-12)[:, None]
    ok = _sweeps(vals) & (share >= SIDE_SHARE)  # (k, 3)
    ratio = np.where(ok, vals[..., 0] / np.maximum(vals[..., 1], 1e-12), np.inf)
    best = np.argmin(ratio, axis=1)
    rows = np.arange(part.count)
    axes = vecs[rows, best, :, 0]
    keep = side[np.arange(len(lab)), best[lab]]
    return axes, ok.any(axis=1) & (revolve_misfit(part, axes, keep) < REVOLVE_MISFIT)


def revolve_misfit(part: Partition, axes: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """How far a region's faces are from a surface of revolution about its axis, (k,) float.

    The normals of a tube's side (round, polygonal, hollow or not) all meet its axis line:
    (p − c) · (a × n) = 0 for a point c on the line. c is fitted by least squares in the plane
    across a; the misfit is the RMS of (p − c) · (a × n) over the RMS distance |(p − c)⊥| of
    the faces from the line (area-weighted). It is near 0 for a tube and near 1 for a slab or a
    half-disc, whose normals happen to be square to some direction without meeting a line.

    Parameters
    ----------
    part : Partition
    axes : (k, 3) float
        Unit axis of every region.
    faces : (f,) bool
        Faces that count (the side faces).
    """
    k, lab = part.count, part.labels
    w = part.mesh.area_faces * faces
    a = axes[lab]  # (f, 3)
    m = np.cross(a, part.mesh.face_normals)  # (f, 3), across the axis
    p = part.mesh.triangles_center
    tot = np.maximum(np.bincount(lab, weights=w, minlength=k), 1e-12)
    mean = np.stack([np.bincount(lab, weights=w * p[:, i], minlength=k)
                     for i in range(3)], axis=1) / tot[:, None]  # (k, 3)
    q = p - mean[lab]  # centred positions (f, 3)
    lhs = sum_rows(lab, w[:, None, None] * m[:, :, None] * m[:, None, :], k)
    rhs = sum_rows(lab, (w * np.einsum("fi,fi->f", q, m))[:, None] * m, k)
    scale = np.trace(lhs, axis1=1, axis2=2)[:, None, None] + 1e-12
    lhs = lhs + scale * (axes[:, :, None] * axes[:, None, :] + 1e-9 * np.eye(3))  # pins c
    # along the axis; the ridge keeps regions without side faces solvable
    c = np.linalg.solve(lhs, rhs[:, :, None])[:, :, 0]  # (k, 3), relative to ``mean``
    d = q - c[lab]
    resid = np.einsum("fi,fi->f", d, m)
    across = d - np.einsum("fi,fi->f", d, a)[:, None] * a
    r2 = np.bincount(lab, weights=w * resid**2, minlength=k)
    d2 = np.bincount(lab, weights=w * np.einsum("fi,fi->f", across, across), minlength=k)
    return np.sqrt(r2 / np.maximum(d2, 1e-12))


def _normal_covariance(part: Partition, mask: np.ndarray) -> np.ndarray:
    """Σ area · n nᵀ per region over the masked faces, once per mask column.

    Parameters
    ----------
    part : Partition
    mask : (f, s) bool
        Which faces count in each of ``s`` sums.

    Returns
    -------
    (k, s, 3, 3) float
    """
    n, w, lab = part.mesh.face_normals, part.mesh.area_faces, part.labels
    s = mask.shape[1]
    f, c = np.nonzero(mask)
    index, nf, wf = lab[f] * s + c, n[f], w[f]
    cov = np.empty((part.count * s, 3, 3))
    for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)):  # symmetric: n_i n_j = n_j n_i
        cov[:, i, j] = cov[:, j, i] = np.bincount(index, weights=nf[:, i] * nf[:, j] * wf,
                                                  minlength=part.count * s)
    return cov.reshape(part.count, s, 3, 3)


def sum_rows(index: np.ndarray, values: np.ndarray, count: int) -> np.ndarray:
    """Σ of the rows of ``values`` by ``index``: what ``np.add.at(out, index, values)`` adds
    into zeros, bit for bit (both add each row in turn, in the order given), by one
    ``np.bincount`` per column, several times faster.

    Parameters
    ----------
    index : (f,) int
        Row of the sum each row of ``values`` goes to, in [0, count).
    values : (f, ...) float
    count : int
        Rows of the sum.

    Returns
    -------
    (count, ...) float
    """
    flat = values.reshape(len(values), int(np.prod(values.shape[1:])))
    out = np.empty((count, flat.shape[1]))
    for j in range(flat.shape[1]):
        out[:, j] = np.bincount(index, weights=flat[:, j], minlength=count)
    return out.reshape((count, *values.shape[1:]))


def _sweeps(vals: np.ndarray) -> np.ndarray:
    """Whether normals with covariance eigenvalues ``vals`` (..., 3), ascending, sweep around
    the least-spread direction: λ_min / λ_mid < :data:`TUBULAR_RATIO` and
    λ_mid / λ_max > :data:`SWEEP_RATIO`, (...) bool."""
    ratio = vals[..., 0] / np.maximum(vals[..., 1], 1e-12)
    sweep = vals[..., 1] / np.maximum(vals[..., 2], 1e-12)
    return (ratio < TUBULAR_RATIO) & (sweep > SWEEP_RATIO)


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
        before = None
        while before is None or (group != before).any():  # absorbing a blob may make a
            before = group.copy()  # region beyond it adjacent to a group it aligns with
            _grow_aligned(group, gdir, adjacency, axes, tubular, cos_max, part)
            _absorb_axisless(group, adjacency, tubular)
            _join_coaxial(group, np.asarray(gdir), axes, tubular, centres, part.areas(),
                          cos_max)
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


def group_regions_refined(part: Partition, root: int, merge_angle: float = MERGE_ANGLE,
                          seed: int = 0, rounds: int = SPLIT_ROUNDS, three_way: bool = False
                          ) -> tuple[Partition, Groups]:
    """:func:`group_regions`, halving stranded regions that hide a branch and grouping again.

    A region is *stranded* (:func:`stranded_regions`) when it has no axis, so it joined a
    group by its boundary only, and overhangs along that group's direction: a k-means patch
    straddling the end of a solid branch and the tube it leaves (no axis: the two tubes'
    normals mix) would print the branch in the tube's layers. Each stranded region is cut in
    two (:func:`slicer.decompose.partition.split_region`), or else, with ``three_way``, in
    three (:func:`~slicer.decompose.partition.split_region_k`); a cut is kept only when it
    reveals a branch: a half that is a clean tube (:func:`clean_tubes`) whose axis is more
    than ``merge_angle`` away from the group's direction. The groups are then built again, at
    most ``rounds`` times.

    Parameters
    ----------
    part : Partition
    root : int
        Root region (never cut).
    merge_angle : float
        Degrees, as in :func:`group_regions`.
    seed : int
        Seed of the 2-means cuts.
    rounds : int
    three_way : bool
        Also cut a region in three where two halves reveal no branch (a short hollow
        branch's wall and bore with the tube's patch). :func:`~slicer.decompose.decompose`
        asks for it only when no attempt without it is good enough: it finds branches the
        halving misses, and on other parts it can take a piece of a junction for a branch.

    Returns
    -------
    part : Partition
        The partition the groups refer to (``part`` itself when nothing was cut; the original
        regions keep their indices, halves get new ones).
    groups : Groups
    """
    groups = group_regions(part, root, merge_angle)
    cos_max = np.cos(np.radians(merge_angle))
    for _ in range(rounds):
        cut = False
        for r in np.flatnonzero(stranded_regions(part, groups, root)):
            direction = groups.direction[groups.region_group[r]]
            for pieces in _cuts(part, int(r), seed, three_way):
                new = np.array([r, *range(part.count, pieces.count)])
                axes, tube = clean_tubes(pieces)
                if (tube[new] & (np.abs(axes[new] @ direction) < cos_max)).any():
                    part, cut = pieces, True
                    break
        if not cut:
            break
        groups = group_regions(part, root, merge_angle)
    return part, groups


def _cuts(part: Partition, region: int, seed: int, three_way: bool) -> Iterator[Partition]:
    """The cuts of a stranded region tried in turn: in two, then (``three_way``) in three."""
    halves = split_region(part, region, seed)
    if halves is not None:
        yield halves
    thirds = split_region_k(part, region, seed, 3) if three_way else None
    if thirds is not None:
        yield thirds


def clean_tubes(part: Partition) -> tuple[np.ndarray, np.ndarray]:
    """:func:`region_axes`, keeping as tubular only regions whose normals also meet the axis
    line (:func:`revolve_misfit` below :data:`REVOLVE_MISFIT`, over the faces that are not
    caps): the normal-spread test alone also passes for a patch of a junction that mixes two
    tubes' normals, which must not start a branch.

    Returns
    -------
    axes : (k, 3) float
    tube : (k,) bool
    """
    axes, tubular = region_axes(part)
    n = part.mesh.face_normals
    side = np.abs(np.einsum("fi,fi->f", n, axes[part.labels])) < np.cos(np.radians(CAP_ANGLE))
    return axes, tubular & (revolve_misfit(part, axes, side) < REVOLVE_MISFIT)


def stranded_regions(part: Partition, groups: Groups, root: int) -> np.ndarray:
    """Regions without an axis whose area overhangs along their group's direction by
    :data:`OVERHANG_SHARE` or more, (k,) bool (the root and base regions never are)."""
    _, tubular = region_axes(part)
    share = np.stack([overhang_share(part, d) for d in groups.direction])  # (g, k)
    over = share[groups.region_group, np.arange(part.count)] >= OVERHANG_SHARE
    out = over & ~tubular
    out[root] = False
    out[_base_regions(part)] = False
    return out


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
