"""Move lines as text, the whole file at once.

A move line is ``G0``/``G1`` followed by the words it writes, in the order X Y Z A C E F, each
a letter and a fixed-point number (:data:`DECIMALS`). Python's ``%`` formatting costs about a
microsecond per number, which for a 50k-face part (half a million lines) is most of the
writer's time. Here the numbers are printed as bytes with numpy: each value becomes the integer
``k = |v|·10^d`` (exact, since ``v`` was already rounded to d decimals), its digits are one
integer division per digit position over all rows, and the lines are one byte matrix whose
unused cells (words a line does not write, leading blanks of short numbers) are dropped in one
pass. The text is exactly what ``"%.{d}f" % v`` gives (including ``-0.000`` for a negative
zero), which :func:`format_moves_reference` states and the tests compare against.
"""

from __future__ import annotations

import numpy as np

LETTERS = "XYZACEF"
DECIMALS = (3, 3, 3, 4, 4, 5, 0)
WORDS = tuple(f"{c}%.{d}f" for c, d in zip(LETTERS, DECIMALS, strict=True))
_BLANK = 0  # a cell dropped from the text


def _digits(ints: np.ndarray, count: int) -> np.ndarray:
    """Decimal digits of non-negative integers, most significant first, as characters.

    Parameters
    ----------
    ints : (n,) int64
    count : int
        Digits per number (leading zeros included).

    Returns
    -------
    (count, n) uint8
        Row j holds the j-th digit of every number.
    """
    small = len(ints) == 0 or int(ints.max()) < 2**31  # int32 division by 10 is the fastest
    rest: np.ndarray = ints.astype(np.int32 if small else np.int64)
    out = np.empty((count, len(ints)), dtype=np.uint8)
    for j in range(count - 1, -1, -1):
        q = rest // 10
        out[j] = rest - q * 10
        rest = q
    out += np.uint8(ord("0"))
    return out


def _number(values: np.ndarray, decimals: int) -> np.ndarray:
    """``"%.{decimals}f"`` of values already rounded to ``decimals``, as a byte matrix.

    Parameters
    ----------
    values : (n,) float
        Finite, below 1e12 in magnitude.
    decimals : int

    Returns
    -------
    (n, w) uint8
        Characters of each number, right-aligned, padded on the left with blanks (0).
    """
    n = len(values)
    scaled = np.rint(np.abs(values) * 10.0**decimals).astype(np.int64)
    whole = scaled // 10**decimals
    width = len(str(int(whole.max())))
    lead = np.full(n, width - 1)  # blank cells left of the whole part (it has ≥ 1 digit)
    for j in range(1, width):
        lead -= whole >= 10**j
    digits = _digits(scaled, width + decimals)
    out = np.zeros((n, width + 1 + (decimals > 0) + decimals), dtype=np.uint8)
    out[:, 1:width + 1] = (digits[:width] * (np.arange(width)[:, None] >= lead)).T
    out[np.arange(n), lead] = np.where(np.signbit(values), ord("-"), _BLANK)
    if decimals:
        out[:, width + 1] = ord(".")
        out[:, width + 2:] = digits[width:].T
    return out


def format_moves(vals: np.ndarray, mask: np.ndarray, g1: np.ndarray) -> list[str]:
    """Move lines of printed values.

    Parameters
    ----------
    vals : (n, 7) float
        X Y Z A C E F as printed (already rounded to :data:`DECIMALS`; anything where
        ``mask`` is False).
    mask : (n, 7) bool
        Which words each line writes.
    g1 : (n,) bool
        ``G1`` (else ``G0``).

    Returns
    -------
    list of str
        n lines, without newlines.
    """
    n = len(vals)
    if n == 0:
        return []
    words = []  # (rows, letter, number matrix) per written word
    for k, (letter, decimals) in enumerate(zip(LETTERS, DECIMALS, strict=True)):
        used = mask[:, k]
        rows: np.ndarray | slice  # the rows that write this word: some, or every one
        rows = np.flatnonzero(used)
        if 2 * len(rows) > n:  # most lines write it: format every row, blank the others
            rows = slice(None)
            values = np.where(used, vals[:, k], 0.0)
        elif len(rows):
            values = vals[rows, k]
        else:
            continue
        words.append((rows, letter, _number(values, decimals), used))
    cells = np.zeros((n, 3 + sum(2 + w.shape[1] for _, _, w, _ in words)), dtype=np.uint8)
    cells[:, 0] = ord("G")
    cells[:, 1] = np.where(g1, ord("1"), ord("0"))
    at = 2
    for rows, letter, number, used in words:
        end = at + 2 + number.shape[1]
        cells[rows, at], cells[rows, at + 1] = ord(" "), ord(letter)
        cells[rows, at + 2:end] = number
        if isinstance(rows, slice):
            cells[~used, at:end] = _BLANK
        at = end
    cells[:, -1] = ord("\n")
    flat = cells.ravel()
    return flat[flat != _BLANK].tobytes().decode("ascii").split("\n")[:-1]


def format_moves_reference(vals: np.ndarray, mask: np.ndarray, g1: np.ndarray) -> list[str]:
    """:func:`format_moves` with Python's ``%`` per line (the definition; slow)."""
    out = []
    for row, used, g in zip(vals.tolist(), mask.tolist(), g1.tolist(), strict=True):
        words = [WORDS[k] % row[k] for k in range(len(WORDS)) if used[k]]
        out.append(" ".join(["G1" if g else "G0", *words]))
    return out
