"""The job on the printer: its program, its streamer and the clock of its print time."""

from __future__ import annotations

from dataclasses import dataclass

from hostd.jobs.store import Job
from hostd.printer.program import Program
from hostd.printer.streamer import Streamer


@dataclass
class Active:
    """The job on the printer and its live figures."""

    job: Job
    program: Program
    streamer: Streamer
    started: float
    paused_at: float | None = None
    paused_total: float = 0.0
    last_persist: float = 0.0
    last_event: float = 0.0
    last_layer: tuple[int | None, int | None] = (None, None)
    filament_base: float = 0.0
    rate_mark: tuple[float, float] | None = None
    """(elapsed s, progress) where the measured rate starts: the first acknowledged line of a
    layer, so the start script's heat-up (or a resume's reheat) does not count as slow
    printing; None before it."""

    _layer_counts: dict[int, int] | None = None

    def layers_of(self, subpart: int | None) -> int | None:
        """How many layers sub-part ``subpart`` of the program has (``None`` before the
        first)."""
        if subpart is None:
            return None
        if self._layer_counts is None:
            counts: dict[int, int] = {}
            for mark in self.program.layers:
                counts[mark.subpart] = counts.get(mark.subpart, 0) + 1
            self._layer_counts = counts
        return self._layer_counts.get(subpart, 0)

    def elapsed(self, now: float) -> float:
        paused = self.paused_total + (now - self.paused_at if self.paused_at else 0.0)
        return max(0.0, now - self.started - paused)

    def pause_clock(self, now: float) -> None:
        """The print time stops at ``now`` (the job paused)."""
        self.paused_at = now

    def resume_clock(self, now: float) -> None:
        """The print time runs again from ``now`` (the job resumed)."""
        if self.paused_at is not None:
            self.paused_total += now - self.paused_at
            self.paused_at = None
