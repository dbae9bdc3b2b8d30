"""The send window: how many bytes may be unacknowledged, shrinking after errors (AIMD)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class SendWindow:
    """Buffer-credit window of ``limit`` bytes, halved on each resend, regrown per clean ok.

    In ``pingpong`` mode one line is in flight at a time. In ``window`` mode the bytes of the
    unacknowledged lines stay within ``size`` (at most the firmware's receive buffer); a line
    longer than the window is still sent when nothing else is in flight.
    """

    mode: str
    limit: int
    growth: int = 4
    size: int = 0

    def __post_init__(self) -> None:
        self.size = self.limit

    def credit(self) -> int:
        """Bytes the lines in flight may hold beside a first one: a line of ``length`` bytes
        fits when nothing is in flight or ``inflight_bytes + length <= credit()`` (-1 in
        ping-pong: never beside another)."""
        return self.size if self.mode == "window" else -1

    def room(self, inflight_bytes: int) -> int:
        """Bytes of a line that may go out now beside ``inflight_bytes`` (none in ping-pong)."""
        return self.size - inflight_bytes if self.mode == "window" else 0

    def shrink(self) -> None:
        """Halve the window after an error (never below one line in flight)."""
        self.size = max(0, self.size // 2)

    def grow(self, acks: int = 1) -> None:
        """Widen the window by ``growth`` bytes per clean acknowledgement."""
        if self.size < self.limit:
            self.size = min(self.limit, self.size + self.growth * acks)
