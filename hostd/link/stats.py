"""Counters and round-trip statistics of the link, kept by the protocol."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from hostd.stats import RTT_BOUNDS, Buckets


@dataclass
class LinkCounters:
    """Monotonic counters since the link object was created."""

    lines_sent: int = 0
    lines_acked: int = 0
    lines_resent: int = 0
    lines_withdrawn: int = 0  # lines taken back unsent (a pause or cancel)
    lines_split: int = 0  # lines whose first part went out ahead of the credit for the rest
    reads: int = 0  # batches of replies handled together: one port read each
    resend_requests: int = 0
    duplicate_resends: int = 0
    checksum_errors: int = 0
    line_errors: int = 0
    timeouts: int = 0
    starve_nudges: int = 0  # nudges of lines starved of credit with no ok (protocol: Starved)
    resyncs: int = 0  # M110s sent because a resend request was out of step with the lines
    resets: int = 0
    waits: int = 0

    def as_dict(self) -> dict[str, int]:
        """Plain dictionary for the status snapshot (every field is an int: a shallow copy
        is a copy; ``dataclasses.asdict`` recurses and costs as much as the rest of the
        snapshot)."""
        return dict(vars(self))


@dataclass
class RoundTrip:
    """Time from sending a line to its ``ok``: last, mean and largest, in seconds, and the
    histogram (whose count and sum are the round trips' count and total)."""

    last: float = 0.0
    largest: float = 0.0
    buckets: Buckets = field(default_factory=lambda: Buckets(RTT_BOUNDS))

    def add(self, seconds: float) -> None:
        """Record one round trip (once per ``ok``: kept to a few steps)."""
        self.buckets.observe(seconds)
        self.last = seconds
        if seconds > self.largest:
            self.largest = seconds

    def add_many(self, seconds: Sequence[float]) -> None:
        """:meth:`add` each of ``seconds`` (at least one), in one call."""
        self.buckets.observe_many(seconds)
        self.last = seconds[-1]
        self.largest = max(self.largest, *seconds)

    def as_dict(self) -> dict[str, object]:
        """Milliseconds, plus the cumulative histogram in seconds, for the status snapshot."""
        b = self.buckets
        mean = b.total / b.n if b.n else 0.0
        return {"count": b.n, "last_ms": round(self.last * 1e3, 3),
                "mean_ms": round(mean * 1e3, 3), "max_ms": round(self.largest * 1e3, 3),
                "histogram": b.snapshot()}
