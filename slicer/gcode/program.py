"""A G-code program under construction: comment lines interleaved with numeric move blocks.

The writer (:mod:`slicer.gcode.writer`) emits whole blocks of joint-space moves at once (numpy
rows), so estimating and formatting stay vectorised. Every move row holds the pose it ends at
and the filament it pushes; the program formats them as ``G0``/``G1`` lines with absolute X Y Z
A C (G90) and relative E (M83), writing an axis only when its printed value changes.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from slicer.gcode.format import format_moves

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
    _table: WordTable | None = field(default=None, init=False, repr=False)
    _table_items: int = field(default=-1, init=False, repr=False)

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
        return self.table().rows

    def table(self) -> WordTable:
        """The printed words of every move row (computed once per set of items)."""
        if self._table is None or self._table_items != len(self.items):
            self._table, self._table_items = WordTable.of(self.items), len(self.items)
        return self._table

    def lines(self) -> list[str]:
        """The program as G-code lines (no trailing newlines)."""
        tab = self.table()
        text = format_moves(*tab.written())
        out: list[str] = []
        done = 0
        for line, k in zip(tab.texts, tab.kept_before(), strict=True):
            out.extend(text[done:k])
            out.append(line)
            done = k
        out.extend(text[done:])
        return out

    def words(self) -> Iterator[str | MoveWords]:
        """What :meth:`lines` writes, with move lines as arrays: raw lines, and per run of
        moves between them the printed values, written-word mask and G1 flag of the rows that
        become a line (a row with no word to write is not written)."""
        tab = self.table()
        vals, mask, g1 = tab.written()
        done = 0
        for line, k in zip(tab.texts, tab.kept_before(), strict=True):
            if k > done:
                yield vals[done:k], mask[done:k], g1[done:k]
            yield line
            done = k
        if len(vals) > done:
            yield vals[done:], mask[done:], g1[done:]


MoveWords = tuple[np.ndarray, np.ndarray, np.ndarray]


@dataclass(frozen=True)
class WordTable:
    """A program's move rows with what each line prints, for the whole file at once.

    Attributes
    ----------
    rows : (n, 9) float
        Every move row in file order.
    vals : (n, 7) float
        Printed values X Y Z A C E F (rounded as written; F in mm/min).
    mask : (n, 7) bool
        Which words a row writes (an axis or feed only when its printed value changes, E when
        not zero).
    g1 : (n,) bool
    texts : list of str
        The raw lines, in order.
    at : (m,) int
        Rows before each raw line.
    """

    rows: np.ndarray
    vals: np.ndarray
    mask: np.ndarray
    g1: np.ndarray
    texts: list[str]
    at: np.ndarray

    @classmethod
    def of(cls, items: list[str | np.ndarray]) -> WordTable:
        """The table of a program's items (raw lines and (k, 9) move blocks)."""
        texts, at, arrays, n = [], [], [], 0
        for item in items:
            if isinstance(item, str):
                texts.append(item)
                at.append(n)
            else:
                arrays.append(item)
                n += len(item)
        rows = np.concatenate(arrays) if arrays else np.empty((0, NCOL))
        return cls(rows, *_words(rows), texts, np.asarray(at, dtype=np.int64))

    @property
    def kept(self) -> np.ndarray:
        """Rows that become a line (they write at least one word), (n,) bool."""
        # numpy types any(axis=...) as scalar-or-array whatever the shape; (n, 7) gives (n,)
        return self.mask.any(axis=1)  # type: ignore[return-value]

    def written(self) -> MoveWords:
        """vals, mask and g1 of the rows that become a line."""
        kept = self.kept
        return self.vals[kept], self.mask[kept], self.g1[kept]

    def kept_before(self) -> list[int]:
        """Move lines before each raw line."""
        count = np.r_[0, np.cumsum(self.kept)]
        return count[self.at].tolist()


def _rounded(rows: np.ndarray) -> np.ndarray:
    out = np.empty((len(rows), 6))
    out[:, :3] = np.round(rows[:, :3], XYZ_DECIMALS)
    out[:, 3:5] = np.round(rows[:, 3:5], AC_DECIMALS)
    out[:, 5] = np.round(rows[:, F] * 60.0, 0)
    return out


def _words(rows: np.ndarray) -> MoveWords:
    """Printed values (n, 7: X Y Z A C E F), which words are written (n, 7) and G1 (n,) of
    consecutive move rows from an unknown pose."""
    r = _rounded(rows)
    before = np.vstack([np.full((1, 6), np.nan), r[:-1]])
    changed = ~(r == before) & np.isfinite(r)  # NaN before: written; NaN now: never
    e = np.round(rows[:, E], E_DECIMALS)
    vals = np.column_stack([r[:, :5], e, r[:, 5]])
    mask = np.column_stack([changed[:, :5], e != 0.0, changed[:, 5]])
    return vals, mask, rows[:, G] != 0
