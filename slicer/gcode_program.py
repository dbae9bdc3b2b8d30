"""A G-code program under construction: comment lines interleaved with numeric move blocks.

The writer (:mod:`slicer.gcode`) emits whole blocks of joint-space moves at once (numpy rows),
so estimating and formatting stay vectorised. Every move row holds the pose it ends at and
the filament it pushes; the program formats them as ``G0``/``G1`` lines with absolute X Y Z A C
(G90) and relative E (M83), writing an axis only when its printed value changes.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

# columns of a move row
X, Y, Z, A, C, E, F, G, SUB = range(9)
NCOL = 9
XYZ_DECIMALS = 3
AC_DECIMALS = 4
E_DECIMALS = 5


@dataclass
class Program:
    """Lines and move blocks in file order.

    Attributes
    ----------
    items : list of str or (k, 9) float array
        Comment/raw lines, or blocks of move rows ``[X, Y, Z, A, C, E, F, G, SUB]`` with the end
        pose (mm, degrees), relative E (mm of filament), feed (mm/s, degrees/s for rotary-only
        moves), G (0 travel, 1 extrude) and the sub-part the move belongs to.
    pose : (5,) float
        Joint pose after the last move (NaN for axes never set).
    """

    items: list[str | np.ndarray] = field(default_factory=list)
    pose: np.ndarray = field(default_factory=lambda: np.full(5, np.nan))
    subpart: int = -1

    def line(self, text: str) -> None:
        """Append raw lines (comments, M-codes); ``text`` may hold several."""
        self.items.extend(text.splitlines())

    def moves(self, poses: np.ndarray, e: np.ndarray | float, feed: np.ndarray | float,
              g: int) -> None:
        """Append moves ending at ``poses`` (k, 5) with filament ``e`` and feed ``feed``."""
        p = np.asarray(poses, dtype=float).reshape(-1, 5)
        if len(p) == 0:
            return
        block = np.empty((len(p), NCOL))
        block[:, :5] = p
        block[:, E] = e
        block[:, F] = feed
        block[:, G] = g
        block[:, SUB] = self.subpart
        self.items.append(block)
        self.pose = p[-1].copy()

    def extrude_only(self, e: float, feed: float) -> None:
        """A retract (e < 0) or unretract (e > 0) without moving the axes."""
        self.moves(self.pose[None, :], e, feed, 1)

    def blocks(self) -> np.ndarray:
        """All move rows in order, (n, 9)."""
        arrays = [b for b in self.items if isinstance(b, np.ndarray)]
        return np.concatenate(arrays) if arrays else np.empty((0, NCOL))

    def start_poses(self) -> np.ndarray:
        """The pose each move starts from (NaN where unknown), (n, 5)."""
        rows = self.blocks()
        start = np.full((len(rows), 5), np.nan)
        if len(rows):
            start[1:] = rows[:-1, :5]
        return start

    def lines(self) -> Iterator[str]:
        """The program as G-code lines (no trailing newlines)."""
        prev = np.full(7, np.nan)  # printed X Y Z A C and feed, last G
        for item in self.items:
            if isinstance(item, str):
                yield item
            else:
                yield from _format_block(item, prev)

    def words(self) -> Iterator[str | MoveWords]:
        """What :meth:`lines` writes, with move lines as arrays: raw lines, and per block the
        printed values, written-word mask and G1 flag of the rows that become a line (a row
        with no word to write is not written)."""
        prev = np.full(7, np.nan)
        for item in self.items:
            if isinstance(item, str):
                yield item
            else:
                vals, mask, g1 = _block_words(item, prev)
                kept = mask.any(axis=1)
                yield vals[kept], mask[kept], g1[kept]


def _rounded(block: np.ndarray) -> np.ndarray:
    out = np.empty((len(block), 6))
    out[:, :3] = np.round(block[:, :3], XYZ_DECIMALS)
    out[:, 3:5] = np.round(block[:, 3:5], AC_DECIMALS)
    out[:, 5] = np.round(block[:, F] * 60.0, 0)
    return out


_WORDS = ("X%.3f", "Y%.3f", "Z%.3f", "A%.4f", "C%.4f", "E%.5f", "F%.0f")


MoveWords = tuple[np.ndarray, np.ndarray, np.ndarray]


def _block_words(block: np.ndarray, prev: np.ndarray) -> MoveWords:
    """Printed values (k, 7: X Y Z A C E F), which words are written (k, 7) and G1 (k,) of
    a block's rows; updates ``prev``."""
    r = _rounded(block)
    before = np.vstack([prev[None, :6], r[:-1]])
    changed = ~(r == before) & np.isfinite(r)  # NaN before: written; NaN now: never
    e = np.round(block[:, E], E_DECIMALS)
    vals = np.column_stack([r[:, :5], e, r[:, 5]])
    mask = np.column_stack([changed[:, :5], e != 0.0, changed[:, 5]])
    prev[:6] = r[-1]
    return vals, mask, block[:, G] != 0


def _format_block(block: np.ndarray, prev: np.ndarray) -> list[str]:
    """Format rows, writing only axes whose printed value changes; updates ``prev``.

    Rows are grouped by which words they carry, and each group is formatted with one
    ``%`` template: no per-word Python work.
    """
    vals, mask, g1 = _block_words(block, prev)
    code = mask.astype(np.int64) @ (1 << np.arange(7)) + 128 * g1
    out = np.empty(len(block), dtype=object)
    for c in np.unique(code):
        idx = np.flatnonzero(code == c)
        cols = [k for k in range(7) if (c >> k) & 1]
        if not cols:
            continue
        fmt = ("G1 " if c & 128 else "G0 ") + " ".join(_WORDS[k] for k in cols)
        out[idx] = [fmt % tuple(row) for row in vals[np.ix_(idx, cols)].tolist()]
    return [line for line in out.tolist() if line is not None]
