"""The error of a part that cannot be printed."""

from __future__ import annotations


class MeshError(ValueError):
    """A part that cannot be printed; ``str()`` is a one-line reason naming the file."""
