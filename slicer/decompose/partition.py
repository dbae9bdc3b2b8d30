"""Coarse partition (paper 2.2.1): k-means on area-weighted triangle centroids.

The part is first refined so that no triangle is longer than a fixed share of its size (the
manifold meshes of CAD parts have triangles spanning a whole tube, whose centroids say nothing
about where the surface is). Area weighting is done by drawing the k-means training set from
the triangle centroids with probability proportional to area; every triangle is then assigned
to its nearest centre (``scipy.cluster.vq``). Clusters that fall apart into several surface
pieces are split, and pieces below a share of the area are merged into the neighbour they
share the longest boundary with.

K by default is chosen from the shape itself: the part is over-segmented into patches about as
wide as its narrowest extent (:func:`auto_k`), and :mod:`slicer.decompose.buildorder` then merges
neighbouring patches whose union prints along one direction. The final number of sub-parts
therefore comes from the geometry, not from K.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.cluster.vq import kmeans2, vq
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from slicer.mesh import canonical_mesh

TARGET_FACES = 8_000  # faces of the analysis mesh
TRAIN_SAMPLES = 6_000  # k-means training centroids (area-weighted draw)
MIN_REGION_SHARE = 0.01  # regions below this share of the area are merged away
K_MIN, K_MAX = 2, 24


@dataclass
class Partition:
    """Coarse regions on an analysis mesh.

    Attributes
    ----------
    mesh : trimesh.Trimesh
        The refined analysis mesh the labels live on.
    labels : (n,) int
        Region of every face, 0..k-1.
    k_requested : int
        K given to k-means.
    """

    mesh: trimesh.Trimesh
    labels: np.ndarray
    k_requested: int

    @property
    def count(self) -> int:
        """Number of regions."""
        return int(self.labels.max()) + 1 if len(self.labels) else 0

    def centres(self) -> np.ndarray:
        """Area-weighted centroid of each region, (k, 3) float."""
        w = self.mesh.area_faces
        c = self.mesh.triangles_center
        tot = np.bincount(self.labels, weights=w, minlength=self.count)
        out = np.stack([np.bincount(self.labels, weights=w * c[:, i], minlength=self.count)
                        for i in range(3)], axis=1)
        return out / np.maximum(tot, 1e-12)[:, None]

    def areas(self) -> np.ndarray:
        """Surface area of each region, (k,) float."""
        return np.bincount(self.labels, weights=self.mesh.area_faces, minlength=self.count)


def analysis_mesh(mesh: trimesh.Trimesh, target_faces: int = TARGET_FACES) -> trimesh.Trimesh:
    """``mesh`` refined so every edge is at most about sqrt(2·area / target_faces).

    Meshes that already have ``target_faces`` faces are used as they are.
    """
    if len(mesh.faces) >= target_faces:
        return mesh
    max_edge = float(np.sqrt(2.0 * mesh.area / target_faces)) * 2.0
    if mesh.edges_unique_length.max() <= max_edge:
        return mesh
    verts, faces = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, max_edge,
                                                    max_iter=12)
    # processing merges the split edges' vertices in an order that hangs on their last
    # bits: canonical order again, so the partition depends on the shape only
    return canonical_mesh(trimesh.Trimesh(verts, faces, process=True))


def auto_k(mesh: trimesh.Trimesh) -> int:
    """K for an over-segmentation into patches about as wide as the part's narrowest extent.

    A patch of radius ℓ = half the smallest bounding-box extent is about one tube diameter
    long for branched tubular parts, so K = area / (π ℓ²), clipped to [K_MIN, K_MAX].
    """
    ell = 0.5 * float(np.sort(mesh.extents)[0])
    k = round(mesh.area / (np.pi * ell**2))
    return int(np.clip(k, K_MIN, K_MAX))


def kmeans_labels(points: np.ndarray, weights: np.ndarray, k: int, seed: int) -> np.ndarray:
    """Area-weighted k-means labels.

    Parameters
    ----------
    points : (n, 3) float
        Triangle centroids.
    weights : (n,) float
        Triangle areas.
    k : int
    seed : int

    Returns
    -------
    (n,) int
    """
    rng = np.random.default_rng(seed)
    k = int(min(k, len(points)))
    train = points[rng.choice(len(points), size=max(TRAIN_SAMPLES, 20 * k),
                              p=weights / weights.sum())]
    centres, _ = kmeans2(train, k, minit="++", seed=rng)
    labels, _ = vq(points, centres)
    return _compact(labels)


def _compact(labels: np.ndarray) -> np.ndarray:
    """Relabel to 0..k-1 in order of first appearance."""
    _, first, inv = np.unique(labels, return_index=True, return_inverse=True)
    order = np.argsort(np.argsort(first))
    return order[inv].astype(np.int64)


def split_disconnected(mesh: trimesh.Trimesh, labels: np.ndarray) -> np.ndarray:
    """Give every edge-connected piece of a region its own label."""
    adj = mesh.face_adjacency
    same = labels[adj[:, 0]] == labels[adj[:, 1]]
    a = adj[same]
    n = len(mesh.faces)
    graph = coo_matrix((np.ones(len(a)), (a[:, 0], a[:, 1])), shape=(n, n))
    _, comp = connected_components(graph, directed=False)
    return _compact(comp)


def boundary_lengths(mesh: trimesh.Trimesh, labels: np.ndarray) -> np.ndarray:
    """Shared boundary length between every pair of regions, (k, k) float (symmetric)."""
    k = int(labels.max()) + 1
    adj = mesh.face_adjacency
    la, lb = labels[adj[:, 0]], labels[adj[:, 1]]
    cross = la != lb
    length = np.linalg.norm(np.diff(mesh.vertices[mesh.face_adjacency_edges[cross]], axis=1),
                            axis=2).ravel()
    out = coo_matrix((length, (la[cross], lb[cross])), shape=(k, k)).toarray()
    return out + out.T


def merge_small(mesh: trimesh.Trimesh, labels: np.ndarray,
                min_share: float = MIN_REGION_SHARE) -> np.ndarray:
    """Merge regions below ``min_share`` of the area into their longest-boundary neighbour.

    Each pass merges every small region at once, into the neighbour it shares the longest
    boundary with (kept neighbours preferred). A small region may only merge into a larger one
    (area, then index, breaks ties), so the merge targets form no cycle and every pass makes
    progress: the smallest region always has somewhere to go. Regions stay edge-connected,
    since a region only ever joins an edge neighbour. A region with no neighbour at all (a
    separate body) is left as it is. Passes repeat until no small region is left.
    """
    labels = labels.copy()
    for _ in range(64):
        k = int(labels.max()) + 1
        areas = np.bincount(labels, weights=mesh.area_faces, minlength=k)
        small = areas < min_share * mesh.area
        if not small.any() or k == 1:
            break
        target = _merge_targets(boundary_lengths(mesh, labels), areas, small)
        if np.array_equal(target, np.arange(k)):
            break
        labels = _compact(target[labels])
    return labels


def _merge_targets(shared: np.ndarray, areas: np.ndarray, small: np.ndarray) -> np.ndarray:
    """Final region every region merges into this pass, (k,) int (itself when kept).

    Parameters
    ----------
    shared : (k, k) float
        Boundary lengths between regions.
    areas : (k,) float
    small : (k,) bool
        Regions to merge away.
    """
    k = len(areas)
    rank = np.empty(k, dtype=np.int64)
    rank[np.lexsort((np.arange(k), areas))] = np.arange(k)
    allowed = (shared > 0) & (rank[None, :] > rank[:, None])  # only into larger regions
    score = np.where(allowed, np.where(small[None, :], 0.5, 1.0) * shared, 0.0)
    target = np.where(small & allowed.any(axis=1), np.argmax(score, axis=1), np.arange(k))
    for _ in range(int(np.ceil(np.log2(max(k, 2)))) + 1):  # follow chains r -> t -> ...
        target = target[target]
    return target


def split_region(part: Partition, region: int, seed: int,
                 min_share: float = MIN_REGION_SHARE) -> Partition | None:
    """``part`` with ``region`` cut in two by area-weighted 2-means on its face centroids.

    The first half keeps the index ``region``, the second becomes region ``part.count`` (the
    other regions keep theirs, so a root chosen by index stays valid). Returns ``None`` when
    the halves would not both be edge-connected and at least ``min_share`` of the whole area.
    """
    m = part.mesh
    faces = np.flatnonzero(part.labels == region)
    if len(faces) < 2:
        return None
    half = kmeans_labels(m.triangles_center[faces], m.area_faces[faces], 2, seed)
    labels = part.labels.copy()
    labels[faces[half == 1]] = part.count
    # stray faces of one half cut off inside the other (the 2-means boundary runs across
    # single triangles) go to the other half: each half keeps its largest piece only
    comp = split_disconnected(m, labels)[faces]
    area = np.bincount(comp, weights=m.area_faces[faces])
    for h in (0, 1):
        mine = half == h
        if mine.any():
            main = np.unique(comp[mine])[np.argmax(area[np.unique(comp[mine])])]
            labels[faces[mine & (comp != main)]] = part.count if h == 0 else region
    areas = np.bincount(labels, weights=m.area_faces, minlength=part.count + 1)
    pieces = int(split_disconnected(m, labels).max()) + 1
    if pieces != part.count + 1 or min(areas[region], areas[-1]) < min_share * m.area:
        return None
    return Partition(m, labels, part.k_requested)


def split_region_k(part: Partition, region: int, seed: int, k: int,
                   min_share: float = MIN_REGION_SHARE) -> Partition | None:
    """``part`` with ``region`` cut into edge-connected pieces by ``k``-means.

    Area-weighted k-means on the region's face centroids, each connected piece of a cluster
    a piece of its own, pieces below ``min_share`` of the whole area merged into a
    neighbour within the region (:func:`merge_small`), so there may be fewer or more than
    ``k``. Where a 2-means cut
    (:func:`split_region`) cannot separate a short hollow branch from the tube it leaves (its
    outer wall and its bore fall in one half, joined only across the other), three clusters
    can: the branch's bore, its outer wall and the tube's patch. The largest piece keeps the
    index ``region``, the others become ``part.count``, ``part.count + 1``, ... Returns
    ``None`` when fewer than two pieces are left.
    """
    m = part.mesh
    faces = np.flatnonzero(part.labels == region)
    if len(faces) < 2 * k:
        return None
    sub = m.submesh([faces], append=True)  # the region's faces, in the same order
    assert isinstance(sub, trimesh.Trimesh)  # one face set appended: one mesh
    if len(sub.faces) != len(faces):  # a face dropped (degenerate): labels would not align
        return None
    clusters = kmeans_labels(m.triangles_center[faces], m.area_faces[faces], k, seed)
    pieces = merge_small(sub, split_disconnected(sub, clusters), min_share * m.area / sub.area)
    areas = np.bincount(pieces, weights=m.area_faces[faces])
    count = len(areas)
    if count < 2 or areas.min() < min_share * m.area:
        return None
    new_id = np.empty(count, dtype=np.int64)
    order = np.argsort(-areas, kind="stable")
    new_id[order[0]] = region
    new_id[order[1:]] = part.count + np.arange(count - 1)
    labels = part.labels.copy()
    labels[faces] = new_id[pieces]
    return Partition(m, labels, part.k_requested)


def coarse_partition(mesh: trimesh.Trimesh, k: int | None, seed: int,
                     analysed: trimesh.Trimesh | None = None) -> Partition:
    """K-means coarse partition of ``mesh`` (paper 2.2.1) with connectivity clean-up.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Watertight part.
    k : int or None
        Number of clusters; ``None`` or 0 chooses it with :func:`auto_k`.
    seed : int
    analysed : trimesh.Trimesh, optional
        ``analysis_mesh(mesh)``, when the caller has it already (the attempts of one
        decomposition share it; it is not modified).
    """
    work = analysis_mesh(mesh) if analysed is None else analysed
    k_used = auto_k(work) if not k else int(k)
    labels = kmeans_labels(work.triangles_center, work.area_faces, k_used, seed)
    labels = merge_small(work, split_disconnected(work, labels))
    return Partition(work, labels, k_used)
