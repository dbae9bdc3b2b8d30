"""Cumulative bucket counts kept by components for their ``status()`` snapshots.

Components never touch prometheus-client: they count into a :class:`Buckets` and publish its
:meth:`Buckets.snapshot`; the metrics exporter turns that into a Prometheus histogram.
"""

from __future__ import annotations

import bisect
from collections.abc import Sequence
from dataclasses import dataclass, field


@dataclass
class Buckets:
    """A cumulative histogram over fixed upper bounds (the last bucket is +Inf)."""

    bounds: Sequence[float]
    counts: list[int] = field(default_factory=list)
    total: float = 0.0
    n: int = 0

    def __post_init__(self) -> None:
        if list(self.bounds) != sorted(self.bounds):
            raise ValueError("bucket bounds must ascend")
        self.counts = [0] * (len(self.bounds) + 1)

    def observe(self, value: float) -> None:
        self.counts[bisect.bisect_left(self.bounds, value)] += 1
        self.total += value
        self.n += 1

    def observe_many(self, values: Sequence[float]) -> None:
        """:meth:`observe` each of ``values``, in one call."""
        counts, bounds, where = self.counts, self.bounds, bisect.bisect_left
        total = self.total
        for value in values:
            counts[where(bounds, value)] += 1
            total += value  # in order, as observe() would: the same float sum
        self.total = total
        self.n += len(values)

    def snapshot(self) -> dict[str, object]:
        """``{"buckets": [[le, cumulative], ...], "sum": s, "count": n}`` with le "+Inf" last.

        The last bound is the string ``"+Inf"`` so that the snapshot stays plain JSON.
        """
        cum, out = 0, []
        bounds: list[float | str] = [*self.bounds, "+Inf"]
        for bound, c in zip(bounds, self.counts, strict=True):
            cum += c
            out.append([bound, cum])
        return {"buckets": out, "sum": self.total, "count": self.n}


RTT_BOUNDS = (0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0)
SLICE_BOUNDS = (0.1, 0.25, 0.5, 1.0, 2.0, 5.0, 10.0, 30.0, 60.0, 120.0, 300.0)
