"""The emulated motion planner: a bounded queue of blocks executed one after another."""

from __future__ import annotations

from collections import deque


class Planner:
    """Blocks with durations on the simulated clock; the head runs, the rest wait."""

    def __init__(self, blocks: int) -> None:
        self.capacity = blocks
        self._ends: deque[float] = deque()

    def retire(self, now: float) -> None:
        """Drop the blocks finished by ``now``."""
        while self._ends and self._ends[0] <= now:
            self._ends.popleft()

    def free(self, now: float) -> int:
        """Free blocks at ``now``."""
        self.retire(now)
        return self.capacity - len(self._ends)

    def add(self, duration: float, now: float) -> None:
        """Queue a block of ``duration`` seconds (the caller checked :meth:`free`)."""
        start = max(now, self._ends[-1]) if self._ends else now
        self._ends.append(start + duration)

    def next_free_at(self) -> float:
        """When the head block ends (the next slot frees)."""
        return self._ends[0]

    def idle_at(self, now: float) -> float:
        """When every queued block has finished."""
        return self._ends[-1] if self._ends else now

    def clear(self) -> None:
        """Forget every block (reset)."""
        self._ends.clear()
