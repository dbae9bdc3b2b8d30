"""Fewer, longer extruding moves: a path's vertices that a straight move passes within the
linearisation tolerance are left out.

A layer's paths are marched from the mesh's triangles, so a wall on a finely faceted part has
a vertex every few tenths of a millimetre although the curve it follows is straight to within
hundredths over a millimetre or more. Every vertex is a G-code line to stream. Here the
vertices of every path are thinned at once (Douglas–Peucker, all paths' open spans a step at a
time): a vertex is left out when the move from the kept vertex before it to the kept one after
it passes within ``tol`` of it and deposits its filament within ``tol`` of where the path did.
The table angles are those of the layer for a whole path, so the joint-space move is the
path's segment turned rigidly: a distance in the platform frame is the same at the nozzle.
"""

from __future__ import annotations

import numpy as np


def kept_vertices(points: np.ndarray, e: np.ndarray, start: np.ndarray, tol: float
                  ) -> np.ndarray:
    """Which vertices of the paths to keep so that no path strays more than ``tol`` from them.

    Parameters
    ----------
    points : (N, 3) float
        Vertices of every path, path after path (``Extrusions.points``).
    e : (N,) float
        Filament of the segment ending at each vertex (0 at a path's first).
    start : (P + 1,) int
        Path j's vertices are ``start[j]:start[j + 1]``.
    tol : float
        mm: the largest distance of a left-out vertex from the move that replaces it, and the
        largest shift along the move of the filament laid up to it.

    Returns
    -------
    (N,) bool
        True where kept: every path's first and last vertex, and each vertex that a move
        between its kept neighbours would miss by more than ``tol``.
    """
    keep = np.zeros(len(points), dtype=bool)
    first, last = start[:-1], start[1:] - 1
    some = last >= first
    keep[first[some]] = keep[last[some]] = True
    cum = np.cumsum(e)
    lo, hi = first[some], last[some]
    while True:
        wide = hi - lo > 1  # a span with a vertex between its kept ends
        lo, hi = lo[wide], hi[wide]
        if not len(lo):
            return keep
        k, worst = _farthest(points, cum, lo, hi)
        split = worst > tol
        keep[k[split]] = True
        lo = np.concatenate([lo[split], k[split]])
        hi = np.concatenate([k[split], hi[split]])


def merged_filament(e: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Filament of each kept vertex's move: all the path laid since the kept vertex before.

    Returns
    -------
    (N,) float
        The kept vertices' filament (a path's first keeps its 0), 0 where left out; the sum is
        ``e``'s.
    """
    cum = np.cumsum(e)
    idx = np.flatnonzero(keep)
    out = np.zeros(len(e))
    out[idx] = np.diff(cum[idx], prepend=0.0)
    if len(idx):  # the filament before the first kept vertex belongs to it
        out[idx[0]] = cum[idx[0]]
    return out


def _farthest(points: np.ndarray, cum: np.ndarray, lo: np.ndarray, hi: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """Per span (lo, hi): its inner vertex that the move lo → hi misses most, and by how much.

    The miss of a vertex is the larger of its distance from the segment and the shift, in mm
    along the move, of the filament laid up to it were the span's filament laid evenly.
    """
    count = hi - lo - 1
    span = np.repeat(np.arange(len(lo)), count)
    offset = np.cumsum(count) - count
    k = np.arange(int(count.sum())) - offset[span] + lo[span] + 1
    a = points[lo][span]
    ab = points[hi][span] - a
    length2 = np.einsum("ij,ij->i", ab, ab)
    ap = points[k] - a
    t = np.clip(np.einsum("ij,ij->i", ap, ab) / np.where(length2 > 0, length2, 1.0), 0.0, 1.0)
    distance = np.linalg.norm(ap - t[:, None] * ab, axis=1)
    laid = (cum[hi] - cum[lo])[span]  # the span's filament
    off = np.abs(cum[k] - cum[lo][span] - t * laid)
    with np.errstate(divide="ignore", invalid="ignore"):
        rate = laid / np.sqrt(length2)  # filament per mm of the move (inf on a closed span)
        shift = np.where(off > 0, off / rate, 0.0)
    miss = np.maximum(distance, np.nan_to_num(shift, nan=np.inf))
    miss[(length2 == 0) & (laid > 0)] = np.inf  # filament over a standstill: keep a vertex
    worst = np.maximum.reduceat(miss, offset)
    at = np.flatnonzero(miss == worst[span])
    first = np.unique(span[at], return_index=True)[1]
    return k[at[first]], worst
