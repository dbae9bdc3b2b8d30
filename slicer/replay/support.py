"""Support of deposited points: earlier material (or the platform) beneath along the nozzle.

Rule (issue 8): a point p with nozzle axis u is *supported* when the material of a bead
deposited in an earlier layer lies beneath it, at a depth ``0 < d ≤ 1.5 · max(t, h)`` along u
(t the nominal layer height, h the point's own bead height: wedge layers may be up to 1.5 t
thick; one t deeper when t < 0.4 w, see :func:`depth_limit`), with the bead's centreline
at a lateral offset ``≤ d · tan 45° + 0.1 w`` (w the line width). The material's depth is
the centreline's, less how far the bead reaches towards p across its path (half a width
times the share of u across the bead): 0 when both layers share an axis (the tip is the top
of the bead), half a width where a branch's first layer stands on the flank of its parent's
beads, a base plane across the parent's layers. A point is also
supported when the platform (z = 0, within its radius) lies within that depth along the axis.
Samples stand for their piece of centreline (``Samples.step``), so the spacing of the samples
along a path adds no offset. The same rule is applied to every point; wall points (within
0.75 w of the model surface) are also reported on their own.

A point that fails the rule but lies over the previous layer's outline (its bead's footprint,
``FOOTPRINT`` widths around it across its axis, inside the model ``OUTLINE_DEPTH`` bead
heights beneath it: ``slicer.replay.check``), with material of the previous layer within
:func:`bridge_reach` (half the sparse infill spacing w / density, plus one line width)
beneath it, *bridges over sparse infill*: reported apart, and not counted as an overhang.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from slicer.replay.kdtree import point_tree
from slicer.replay.samples import Samples

DEPTH_FACTOR = 1.5
THIN_LAYER = 0.4  # x line width: thinner layers, the cone one layer down misses w/2
OVERHANG_DEG = 45.0
LATERAL_SLACK = 0.1  # × line width
WALL_SLACK = 0.75  # × line width: wall points are this close to the surface
BAD_LAYER_SHARE = 0.05
OVERHANG_SHARE = 0.25  # a layer with more of its extrusion (by length) unsupported ...
OVERHANG_RUN = 15.0  # ... in a continuous unsupported run longer than this (mm) is refused
RUN_GAP = 1.5  # × line width: judged samples farther apart lie on different beads
NEIGHBOURS = 10
OUTLINE_DEPTH = 1.5  # × bead height: the previous layer's mid-height beneath a bead's tip
FOOTPRINT = 0.5  # × line width: the bead's footprint there must lie in the outline
BRIDGE_SLACK = 1.0  # × line width: bridging reaches half the sparse spacing plus this
CHUNK_PAIRS = 1 << 17  # (sample, candidate) pairs tested at once: 3 MiB per (pairs, 3) array


def depth_limit(s: Samples, layer_height: float, line_width: float | None = None
                ) -> np.ndarray:
    """Largest depth searched beneath each sample, (n,): ``DEPTH_FACTOR`` times its layer's
    thickness, and with ``line_width`` one layer more when layers are thinner than
    ``THIN_LAYER`` times the width. The 45 degree cone one layer down is then narrower than
    half a line (t + 0.1 w < w/2): a solid line crossing the lines below at 90 degrees,
    between two of them, finds no support there; the layer under those runs its way."""
    dmax = DEPTH_FACTOR * np.maximum(layer_height, s.h) + 1e-6
    if line_width is not None and layer_height < THIN_LAYER * line_width:
        dmax = dmax + layer_height
    return dmax


def max_depth(h_max: float, layer_height: float, line_width: float | None = None) -> float:
    """The largest :func:`depth_limit` of samples whose beads are at most ``h_max`` high."""
    d = DEPTH_FACTOR * max(layer_height, h_max) + 1e-6
    if line_width is not None and layer_height < THIN_LAYER * line_width:
        d += layer_height
    return d


def support_reach(depth: float, layer_height: float, line_width: float) -> float:
    """How far from a sample the support search reaches (its candidates lie within this of
    the sample), for a largest searched ``depth``, mm."""
    return search_radius(depth, layer_height, line_width) + layer_height


def search_radius(depth: float, layer_height: float, line_width: float) -> float:
    """The candidates' distance bound from the point one layer beneath a sample, mm."""
    tan = math.tan(math.radians(OVERHANG_DEG))
    slack = LATERAL_SLACK * line_width
    return math.hypot(depth, depth * tan + slack) + layer_height


def _check(s: Samples, top: np.ndarray, below: np.ndarray, dmax: np.ndarray,
           slack: float, half_width: float) -> np.ndarray:
    """Which (top, below) pairs put ``below``'s bead in the support cone of ``top``.

    The bead of ``below`` is its piece of centreline ``q + τ · step`` (|τ| ≤ 1/2); the point
    of it tested is the one laterally nearest to ``top``'s nozzle axis. All in dot products
    of ``rel = p − q``, ``step`` and the unit axis ``u``: across the axis, ``rel`` and
    ``step`` have the dot product ``rel·step − (rel·u)(step·u)`` and ``step`` the squared
    length ``step·step − (step·u)²``. The depth is that of the bead's material nearest
    ``top`` along ``u`` (:func:`_side_reach`), and it must be positive: material level with
    ``top`` or above it is beside it, not beneath. The lateral offset is the centreline's.
    """
    u = s.u[top]
    rel = s.p[top] - s.p[below]
    step = s.step[below]
    along, step_along = _dot(rel, u), _dot(step, u)
    rel_step, step_step = _dot(rel, step), _dot(step, step)
    den = step_step - step_along * step_along
    tau = np.clip((rel_step - along * step_along) / np.where(den > 0, den, 1.0), -0.5, 0.5)
    d = along - tau * step_along
    lat2 = _dot(rel, rel) - 2.0 * tau * rel_step + tau * tau * step_step - d * d
    depth = d - _side_reach(u, s.u[below], step, half_width)
    reach = depth * math.tan(math.radians(OVERHANG_DEG)) + slack
    return ((s.seq[below] < s.seq[top]) & (depth > 0) & (depth <= dmax[top])
            & (lat2 <= reach * reach))


def _side_reach(u: np.ndarray, u_below: np.ndarray, step: np.ndarray,
                half_width: float) -> np.ndarray:
    """How far the earlier bead's material reaches from its centreline towards a point above
    it along ``u`` (n, 3): half a width times the share of ``u`` across the bead, (n,).

    A bead is ``w`` wide across its path within its own layer (along ``u_below × step``) and
    its top is its nozzle tip. Where the new layer's axis is the old one's, the material
    nearest along ``u`` is the tip (reach 0); where a branch's first layer lies on the side
    of its parent's beads (a base plane across the parent's layers), it is the bead's flank,
    half a width nearer than the centreline. A sample without a direction reaches nothing.
    """
    across = np.cross(u_below, step)
    norm = np.linalg.norm(across, axis=1)
    share = np.abs(_dot(across, u)) / np.where(norm > 1e-12, norm, np.inf)
    return half_width * share


def bead_axes(u: np.ndarray, step: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors along and across beads in the plane across their axes, each (n, 3).

    ``u`` (n, 3) are the unit nozzle axes and ``step`` (n, 3) the samples' pieces of path;
    a piece without length across its axis takes any direction across it.
    """
    along = step - _dot(step, u)[:, None] * u
    norm = np.linalg.norm(along, axis=1)
    bare = norm <= 1e-9
    if bare.any():  # x × u, or y × u where u is along x
        ref = np.where(np.abs(u[bare, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
        along[bare] = np.cross(ref, u[bare])
        norm[bare] = np.linalg.norm(along[bare], axis=1)
    along /= norm[:, None]
    return along, np.cross(u, along)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products of (n, 3) arrays, (n,)."""
    return np.einsum("ij,ij->i", a, b)


def platform_support(p: np.ndarray, u: np.ndarray, dmax: np.ndarray, radius: float,
                     slack: float) -> np.ndarray:
    """Points (n, 3) with axes ``u`` (n, 3) that have the platform plane within reach
    ``dmax`` (n,) beneath them, (n,) bool."""
    uz = u[:, 2]
    t = np.where(uz > 1e-9, p[:, 2] / np.where(uz > 1e-9, uz, 1.0), np.inf)
    foot = p[:, :2] - t[:, None] * u[:, :2]
    return (t >= -1e-6) & (t <= dmax) & (np.linalg.norm(foot, axis=1) <= radius + slack)


def strict_support(s: Samples, layer_height: float, line_width: float,
                   platform_radius: float, tree: cKDTree | None = None,
                   judged: np.ndarray | None = None, depth: float | None = None
                   ) -> np.ndarray:
    """The support rule for the samples ``judged`` (indices, (m,); all when ``None``), with
    every sample's bead as material beneath: (m,) bool.

    Candidates are the ``NEIGHBOURS`` samples nearest a point one layer height beneath each
    sample along its axis (where supporting material lies); material of the same or later
    layers is farther from there, so the nearest candidates are the supporting ones. They are
    searched within :func:`search_radius` of ``depth`` (default: the largest
    :func:`depth_limit` of ``s``): ``s`` may then be the samples near the judged ones only,
    every sample within :func:`support_reach` of them, with ``depth`` that of all samples.
    """
    judged = np.arange(len(s)) if judged is None else judged
    dmax = depth_limit(s, layer_height, line_width)
    slack = LATERAL_SLACK * line_width
    ok = np.zeros(len(judged), dtype=bool)
    for chunk in support_chunks(len(judged), 1):
        j = judged[chunk]
        ok[chunk] = platform_support(s.p[j], s.u[j], dmax[j], platform_radius, slack)
    if len(s) < 2:
        return ok
    r = search_radius(float(dmax.max()) if depth is None else depth, layer_height, line_width)
    tree = tree or point_tree(s.p)
    todo = np.flatnonzero(~ok)
    for k in (1, min(NEIGHBOURS, len(s))):  # the nearest candidate settles most samples
        for chunk in support_chunks(len(todo), k):  # (len, k) temporaries stay bounded
            part = todo[chunk]
            ok[part] = _supported(s, judged[part], k, tree, r, dmax, layer_height, slack,
                                  0.5 * line_width)
        todo = todo[~ok[todo]]
    return ok


def support_chunks(n: int, k: int) -> list[slice]:
    """Slices of ``n`` samples searched ``k`` candidates at a time, at most ``CHUNK_PAIRS``
    (sample, candidate) pairs each: the pairs' (pairs, 3) temporaries stay bounded."""
    step = max(1, CHUNK_PAIRS // max(k, 1))
    return [slice(lo, min(lo + step, n)) for lo in range(0, n, step)]


def _supported(s: Samples, top: np.ndarray, k: int, tree: cKDTree, r: float,
               dmax: np.ndarray, layer_height: float, slack: float, half_width: float
               ) -> np.ndarray:
    """Whether one of the ``k`` samples nearest a point one layer height beneath each
    sample ``top`` (m,) supports it, (m,) bool."""
    _, idx = tree.query(s.p[top] - s.u[top] * layer_height, k=k,
                        distance_upper_bound=r, workers=-1)
    idx = idx.reshape(len(top), k)
    valid = idx < len(s)
    below = np.where(valid, idx, 0)
    tops = np.repeat(top[:, None], k, axis=1)
    hit = valid & _check(s, tops.ravel(), below.ravel(), dmax, slack,
                         half_width).reshape(valid.shape)
    return hit.any(axis=1)


def bridge_reach(line_width: float, infill_density: float) -> float:
    """How far from the previous layer's beads a point still bridges sparse infill, mm.

    The sparse lines lie ``S = w / density`` apart and each layer's lines cross those of
    the layer beneath at 90°, so a line of the first skin (or of the sparse infill itself)
    spans S between two of them: every point of it lies within S / 2 of one.
    ``BRIDGE_SLACK`` widths more cover the gap beside the inner perimeter (the outermost
    sparse line may lie a spacing from the fill domain's edge, which is 0.85 w inside the
    perimeter's centreline). Without sparse infill (density 0) the first skin spans the
    hollow interior from wall to wall: unbounded.
    """
    if infill_density <= 0:
        return math.inf
    return 0.5 * line_width / infill_density + BRIDGE_SLACK * line_width


def bridged(s: Samples, candidates: np.ndarray, layer_height: float, line_width: float,
            infill_density: float) -> np.ndarray:
    """Of the ``candidates`` (bool mask (n,): unsupported samples over the previous layer's
    outline), those with a bead of the previous layer in print order beneath them
    (``0 < depth ≤ DEPTH_FACTOR · max(t, h)`` along their axis) within :func:`bridge_reach`
    across it, (n,) bool."""
    out = np.zeros(len(s), dtype=bool)
    if not candidates.any():
        return out
    reach = bridge_reach(line_width, infill_density)
    order = np.argsort(s.seq, kind="stable")
    seq_sorted = s.seq[order]
    cand = np.flatnonzero(candidates)
    cand = cand[np.argsort(s.seq[cand], kind="stable")]
    cuts = np.flatnonzero(np.r_[True, s.seq[cand][1:] != s.seq[cand][:-1], True])
    top, below = [np.zeros(0, dtype=np.intp)], [np.zeros(0, dtype=np.intp)]
    for lo, hi in itertools.pairwise(cuts):  # candidates of one layer, over the one before
        a, b = np.searchsorted(seq_sorted, [s.seq[cand[lo]] - 1, s.seq[cand[lo]]])
        if b > a:
            prev = order[a:b]
            top.append(cand[lo:hi])
            below.append(prev[point_tree(s.p[prev]).query(s.p[cand[lo:hi]])[1]])
    idx, q = np.concatenate(top), np.concatenate(below)
    rel = s.p[idx] - s.p[q]
    d = np.einsum("ij,ij->i", rel, s.u[idx])
    lat = np.linalg.norm(rel - d[:, None] * s.u[idx], axis=1)
    out[idx] = (d > 0) & (d <= depth_limit(s, layer_height)[idx]) & (lat <= reach)
    return out


@dataclass
class LayerSupport:
    """Unsupported extrusion of every printed layer, by length (one row per layer).

    Attributes
    ----------
    seq : (k,) int
        Layers in print order (``Samples.seq``).
    subpart, layer : (k,) int
        Their sub-part and layer index.
    z : (k,) float
        Median platform-frame z of each layer's samples, mm.
    length, unsupported : (k,) float
        Extruded length of each layer and its unsupported part, mm.
    run : (k,) float
        Longest continuous unsupported run of each layer (one bead, or adjacent beads), mm.
    where : (k, 3) float
        Platform-frame point in the middle of that run (NaN without one).
    """

    seq: np.ndarray
    subpart: np.ndarray
    layer: np.ndarray
    z: np.ndarray
    length: np.ndarray
    unsupported: np.ndarray
    run: np.ndarray
    where: np.ndarray

    @property
    def share(self) -> np.ndarray:
        """Unsupported share of each layer's extrusion, (k,)."""
        return self.unsupported / np.maximum(self.length, 1e-12)

    @property
    def severity(self) -> np.ndarray:
        """How far each layer is into the refusal zone, (k,): the smaller of its share and
        its longest run over their limits (``OVERHANG_SHARE``, ``OVERHANG_RUN``); above 1 a
        layer prints in the air."""
        return np.minimum(self.share / OVERHANG_SHARE, self.run / OVERHANG_RUN)

    def overhangs(self) -> np.ndarray:
        """Rows of the layers over both limits, worst first, (j,) int."""
        sev = self.severity
        rows = np.flatnonzero(sev > 1.0)
        return rows[np.argsort(-sev[rows], kind="stable")]

    def worst(self) -> int | None:
        """Row of the layer nearest the refusal zone (``None`` without layers)."""
        return int(np.argmax(self.severity)) if len(self.seq) else None

    @classmethod
    def joined(cls, parts: list[LayerSupport]) -> LayerSupport:
        """The rows of ``parts`` (of distinct layers, in print order) as one."""
        if not parts:
            e = np.zeros(0)
            return cls(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64), e,
                       e, e, e, np.zeros((0, 3)))
        return cls(*(np.concatenate([getattr(p, f) for p in parts]) for f in (
            "seq", "subpart", "layer", "z", "length", "unsupported", "run", "where")))


def layer_support(s: Samples, judged: np.ndarray, supported: np.ndarray,
                  line_width: float) -> LayerSupport:
    """Per layer, how much of its extrusion the judged samples find unsupported.

    Parameters
    ----------
    s : Samples
        Every deposited sample (n), in file order.
    judged : (m,) int
        Increasing indices of the judged samples; each stands for the path from itself to
        the next judged one (the length of the samples' pieces, ``|step|``).
    supported : (m,) bool
        Their verdicts (support or bridging).
    line_width : float
        mm; judged samples more than ``RUN_GAP`` widths apart break a run.

    Returns
    -------
    LayerSupport
    """
    if len(judged) == 0:
        e = np.zeros(0)
        return LayerSupport(np.zeros(0, np.int64), np.zeros(0, np.int64),
                            np.zeros(0, np.int64), e, e, e, e, np.zeros((0, 3)))
    piece = np.sqrt(np.einsum("ij,ij->i", s.step, s.step))
    weight = np.add.reduceat(piece, judged)
    seq = s.seq[judged].astype(np.int64)
    p = s.p[judged]
    bad = ~supported
    # runs: consecutive judged samples of one layer, equally (un)supported, on one bead
    gap = np.linalg.norm(np.diff(p, axis=0), axis=1) > RUN_GAP * line_width
    cut = np.r_[True, gap | (seq[1:] != seq[:-1]) | (bad[1:] != bad[:-1])]
    run_id = np.cumsum(cut) - 1
    first = np.flatnonzero(cut)
    last = np.r_[first[1:] - 1, len(judged) - 1]
    run_len = np.bincount(run_id, weights=weight)
    run_len[~bad[first]] = 0.0
    layers, row = np.unique(seq, return_inverse=True)  # seq is sorted in file order
    k = len(layers)
    length = np.bincount(row, weights=weight, minlength=k)
    unsupported = np.bincount(row, weights=np.where(bad, weight, 0.0), minlength=k)
    # the longest run of each layer: runs sorted by (layer, length), the last of each layer
    run_row = row[first]
    order = np.lexsort((run_len, run_row))
    top = order[np.r_[run_row[order][1:] != run_row[order][:-1], True]]
    run = np.zeros(k)
    run[run_row[top]] = run_len[top]
    where = np.full((k, 3), np.nan)
    has = run_len[top] > 0
    where[run_row[top[has]]] = p[(first[top[has]] + last[top[has]]) // 2]
    z = _median_z(p[:, 2], row, k)
    lay = np.flatnonzero(np.r_[True, seq[1:] != seq[:-1]])
    return LayerSupport(layers, s.subpart[judged][lay].astype(np.int64),
                        s.layer[judged][lay].astype(np.int64), z, length, unsupported, run,
                        where)


def _median_z(z: np.ndarray, row: np.ndarray, k: int) -> np.ndarray:
    """Median of ``z`` (m,) within each of the ``k`` groups ``row`` (m,), (k,)."""
    order = np.lexsort((z, row))
    counts = np.bincount(row, minlength=k)
    starts = np.r_[0, np.cumsum(counts)[:-1]]
    return z[order][starts + (counts - 1) // 2]
