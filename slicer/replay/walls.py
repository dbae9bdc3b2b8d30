"""Unsupported wall layers: which layers, how bad, and where, for a refusal to name.

A layer is an *unsupported wall layer* when more than
:data:`~slicer.replay.support.BAD_LAYER_SHARE` of its judged wall points (within
``WALL_SLACK`` line widths of the model surface) fail the strict support rule
(:func:`~slicer.replay.support.strict_support`); it is *over air* when that holds of the
points that also bridge no sparse infill (:func:`~slicer.replay.support.bridged`: a top
skin within 0.75 w of the surface lies on the sparse lines beneath, not over air).
:func:`wall_layers` finds either kind, as its ``supported`` mask says, describes each layer
(:class:`WallLayer`: its sub-part and layer, how many wall points, the share unsupported, a
representative point) and gathers the unsupported wall samples themselves
(:class:`WallSamples`, platform frame), which a preview marks and a caller may steer by.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slicer.replay.support import BAD_LAYER_SHARE

MAX_WALL_LAYERS = 50  # layers a report describes, worst first
MAX_WALL_SAMPLES = 20_000  # unsupported wall samples a report keeps (evenly thinned)


@dataclass(frozen=True)
class WallLayer:
    """One unsupported wall layer.

    Attributes
    ----------
    subpart, layer : int
        Where it lies in the print.
    seq : int
        The layer in print order (``Samples.seq``).
    wall_points, unsupported : int
        Its judged wall points, and how many of them fail the support rule.
    share : float
        ``unsupported / wall_points``, above ``BAD_LAYER_SHARE``.
    z : float
        Median platform-frame z of its unsupported wall points, mm.
    point : (float, float, float) or None
        The unsupported wall point nearest their mean, in the part's (STL) frame when the
        file has a placement, else in the platform frame, mm (rounded to 0.01).
    """

    subpart: int
    layer: int
    seq: int
    wall_points: int
    unsupported: int
    share: float
    z: float
    point: tuple[float, float, float] | None


@dataclass(frozen=True)
class WallSamples:
    """Unsupported wall samples of the unsupported wall layers (at most
    ``MAX_WALL_SAMPLES``, evenly thinned, in print order).

    Attributes
    ----------
    p : (k, 3) float
        Platform-frame positions, mm.
    subpart, layer : (k,) int32
        Sub-part and layer of each.
    total : int
        How many there were before the thinning.
    """

    p: np.ndarray
    subpart: np.ndarray
    layer: np.ndarray
    total: int

    @classmethod
    def empty(cls) -> WallSamples:
        """No samples."""
        return cls(np.zeros((0, 3)), np.zeros(0, np.int32), np.zeros(0, np.int32), 0)

    def __len__(self) -> int:
        return len(self.p)

    @classmethod
    def joined(cls, parts: list[WallSamples], cap: int = MAX_WALL_SAMPLES) -> WallSamples:
        """``parts`` in order as one, thinned evenly to at most ``cap`` samples."""
        if not parts:
            return cls.empty()
        p = np.concatenate([s.p for s in parts])
        sub = np.concatenate([s.subpart for s in parts])
        lay = np.concatenate([s.layer for s in parts])
        total = sum(s.total for s in parts)
        if len(p) > cap:
            keep = np.linspace(0, len(p) - 1, cap).round().astype(np.int64)
            p, sub, lay = p[keep], sub[keep], lay[keep]
        return cls(p, sub, lay, total)


@dataclass(frozen=True)
class WallLayerPoints:
    """The judged samples of some whole layers, for :func:`wall_layers`.

    Attributes
    ----------
    p : (m, 3) float
        Platform-frame positions.
    seq, subpart, layer : (m,) int
        Layer in print order, sub-part and layer index of each.
    wall, supported : (m,) bool
        Whether each is a wall point, and whether it counts as supported (the strict rule,
        or with bridging too for the layers over air).
    """

    p: np.ndarray
    seq: np.ndarray
    subpart: np.ndarray
    layer: np.ndarray
    wall: np.ndarray
    supported: np.ndarray


def wall_layers(points: WallLayerPoints, to_part: np.ndarray | None, keep: bool = True
                ) -> tuple[list[WallLayer], WallSamples]:
    """The unsupported wall layers among ``points`` (which hold every judged sample of each
    of their layers) and their unsupported wall samples.

    Parameters
    ----------
    points : WallLayerPoints
    to_part : (4, 4) float or None
        Platform frame → the part's (STL) frame, for the layers' points.
    keep : bool
        Gather the samples (else empty ones are returned).

    Returns
    -------
    layers : list of WallLayer
        In print order.
    samples : WallSamples
        Not thinned (``total`` is their number).
    """
    bad = points.wall & ~points.supported
    seq = points.seq[points.wall].astype(np.int64)
    if len(seq) == 0:
        return [], WallSamples.empty()
    layers, row, total = np.unique(seq, return_inverse=True, return_counts=True)
    row_bad = row[~points.supported[points.wall]]
    n_bad = np.bincount(row_bad, minlength=len(layers))
    share = n_bad / total
    worse = share > BAD_LAYER_SHARE
    pick = bad & np.isin(points.seq, layers[worse])
    samples = WallSamples(points.p[pick], points.subpart[pick].astype(np.int32),
                          points.layer[pick].astype(np.int32), int(pick.sum())
                          ) if keep else WallSamples.empty()
    where, z = _representatives(points.p[pick], np.searchsorted(layers, points.seq[pick]),
                                len(layers))
    seqs, firsts = np.unique(points.seq, return_index=True)
    out = []
    for r in np.flatnonzero(worse):
        first = int(firsts[np.searchsorted(seqs, layers[r])])
        out.append(WallLayer(int(points.subpart[first]), int(points.layer[first]),
                             int(layers[r]), int(total[r]), int(n_bad[r]),
                             round(float(share[r]), 4), round(float(z[r]), 3),
                             _point(where[r], to_part)))
    return out, samples


def _representatives(p: np.ndarray, row: np.ndarray, k: int
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Per group ``row`` (m,) of points ``p`` (m, 3): the point nearest the group's mean
    (k, 3) and the group's median z (k,); NaN for empty groups."""
    where, z = np.full((k, 3), np.nan), np.full(k, np.nan)
    if len(p) == 0:
        return where, z
    count = np.bincount(row, minlength=k)
    mean = np.stack([np.bincount(row, weights=p[:, i], minlength=k) for i in range(3)],
                    axis=1) / np.maximum(count, 1)[:, None]
    d = np.linalg.norm(p - mean[row], axis=1)
    nearest = np.lexsort((d, row))
    first = nearest[np.r_[True, row[nearest][1:] != row[nearest][:-1]]]
    where[row[first]] = p[first]
    by_z = np.lexsort((p[:, 2], row))
    starts = np.r_[0, np.cumsum(count)[:-1]]
    has = count > 0
    z[has] = p[by_z, 2][starts[has] + (count[has] - 1) // 2]
    return where, z


def _point(where: np.ndarray, to_part: np.ndarray | None
           ) -> tuple[float, float, float] | None:
    """``where`` (3,) in the part's frame by ``to_part``, rounded; None when not finite."""
    if not np.isfinite(where).all():
        return None
    if to_part is not None:
        where = to_part[:3, :3] @ where + to_part[:3, 3]
    x, y, z = (round(float(v), 2) for v in where)
    return x, y, z


def worst_first(layers: list[WallLayer], cap: int = MAX_WALL_LAYERS) -> list[WallLayer]:
    """``layers`` by falling share (then print order), at most ``cap``."""
    return sorted(layers, key=lambda w: (-w.share, w.seq))[:cap]


def wall_layer_text(layer: WallLayer) -> str:
    """One clause naming an unsupported wall layer, its share and a point of it."""
    at = "" if layer.point is None else (
        f", around [{layer.point[0]:.1f}, {layer.point[1]:.1f}, {layer.point[2]:.1f}] mm "
        "(part frame)")
    return (f"sub-part {layer.subpart} layer {layer.layer}, {100 * layer.share:.1f}% of its "
            f"{layer.wall_points} wall points unsupported{at}")
