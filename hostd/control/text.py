"""One line of text: the characters that break it (a job name must not hold them, and
``hostctl`` escapes them in what it prints)."""

from __future__ import annotations

import unicodedata

CONTROL_CATEGORIES = frozenset({"Cc", "Zl", "Zp"})
"""Unicode categories that break a line of text: C0/C1 controls (newline, tab, escape, DEL)
and the line and paragraph separators."""


def control_character(text: str) -> int | None:
    """The index of the first control character in ``text``, or ``None``."""
    return next((i for i, ch in enumerate(text)
                 if unicodedata.category(ch) in CONTROL_CATEGORIES), None)
