"""Small pages for numpy's large arrays while a part is sliced.

On Linux, numpy asks the kernel for transparent huge pages (``madvise(MADV_HUGEPAGE)``) for
every array of 4 MB or more. A slice allocates and frees such arrays by the thousand (the
replay's samples, KD-tree answers, toolpath blocks), and each one comes back from the kernel
as fresh pages that must be zeroed. Zeroing them as 2 MB huge pages cost a sixth of a
50k-face slice's CPU on the development VM (``perf record`` of ``bench/ab_slice.py --one``:
``clear_page_erms`` under ``do_huge_pmd_anonymous_page``); with small pages, about one
percent (figures in ``docs/slicing.md``).

numpy documents the switch as the ``NUMPY_MADVISE_HUGEPAGE`` environment variable, read when
numpy is imported; a slice turns it off for its own duration (its forked workers inherit
the setting) unless that variable is set, which then decides. The setting is the process's:
with slices on several threads at once, the first to start turns huge pages off and the last
to finish restores the setting found by the first.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from numpy._core import multiarray

ENV = "NUMPY_MADVISE_HUGEPAGE"


def _switch() -> Callable[[bool], bool] | None:
    """numpy's setter (returns the previous setting), or None in a numpy without it."""
    return getattr(multiarray, "_set_madvise_hugepage", None)


class _Holders:
    """How many blocks hold huge pages off, and the setting found by the first."""

    lock = threading.Lock()
    count = 0
    before = True


@contextmanager
def small_pages() -> Iterator[None]:
    """Large arrays without huge pages inside the block; the previous setting once the last
    such block (of any thread) has ended."""
    switch = _switch()
    if switch is None or ENV in os.environ:
        yield
        return
    with _Holders.lock:
        if _Holders.count == 0:
            _Holders.before = switch(False)
        _Holders.count += 1
    try:
        yield
    finally:
        with _Holders.lock:
            _Holders.count -= 1
            if _Holders.count == 0:
                switch(_Holders.before)
