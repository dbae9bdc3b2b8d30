"""Move lines as text, the whole file at once.

A move line is ``G0``/``G1`` followed by the words it writes, in the order X Y Z A C E F, each
with a fixed number of decimals. Rows are grouped by which words they carry and each group is
formatted with one ``%`` over all its values: no per-line or per-word Python work.
"""

from __future__ import annotations

import numpy as np

WORDS = ("X%.3f", "Y%.3f", "Z%.3f", "A%.4f", "C%.4f", "E%.5f", "F%.0f")


def format_moves(vals: np.ndarray, mask: np.ndarray, g1: np.ndarray) -> list[str]:
    """Move lines of printed values.

    Parameters
    ----------
    vals : (n, 7) float
        X Y Z A C E F as printed (already rounded).
    mask : (n, 7) bool
        Which words each line writes (at least one per line).
    g1 : (n,) bool
        ``G1`` (else ``G0``).

    Returns
    -------
    list of str
        n lines, without newlines.
    """
    code = mask.astype(np.int64) @ (1 << np.arange(len(WORDS))) + (1 << len(WORDS)) * g1
    out = np.empty(len(vals), dtype=object)
    for c in np.unique(code).tolist():
        idx = np.flatnonzero(code == c)
        cols = [k for k in range(len(WORDS)) if (c >> k) & 1]
        fmt = ("G1 " if c >> len(WORDS) else "G0 ") + " ".join(WORDS[k] for k in cols)
        flat = vals[np.ix_(idx, cols)].ravel().tolist()
        out[idx] = ("\n".join([fmt] * len(idx)) % tuple(flat)).split("\n")
    return out.tolist()
