"""Tasks for the worker process of ``test_decompose_ahead`` (importable by name, as a
spawned worker needs them)."""

from __future__ import annotations

import os
import threading


def square(i: int) -> tuple[int, int]:
    """``i`` squared, and the process that computed it."""
    return i * i, os.getpid()


def square_then_hang(i: int) -> tuple[int, int]:
    """:func:`square` for 1; for later ``i``, never returns (a long attempt)."""
    if i > 1:
        threading.Event().wait()
    return square(i)


def die(i: int) -> tuple[int, int]:
    """The worker process ends (killed for its memory, say)."""
    os._exit(3)
