"""Seeded fault injection of the emulator: bit flips, lost oks, busy periods."""

from __future__ import annotations

import random

from hostd.sim.settings import SimSettings


class Faults:
    """Random faults drawn from one seeded generator, so a schedule is reproducible."""

    def __init__(self, settings: SimSettings) -> None:
        self.settings = settings
        self.rng = random.Random(settings.seed)
        self.flipped = 0
        self.lost_oks = 0
        self.busy_periods = 0

    def corrupt(self, line: bytes) -> bytes:
        """``line`` (without newline), with one bit flipped with probability ``bit_flip_prob``.

        The flip never creates a line end, so line boundaries survive, as they mostly do on a
        real wire where a flipped newline merges two lines into one rejected line anyway.
        """
        if not line or self.rng.random() >= self.settings.bit_flip_prob:
            return line
        data = bytearray(line)
        while True:
            i = self.rng.randrange(len(data))
            flipped = data[i] ^ (1 << self.rng.randrange(7))
            if flipped not in (10, 13):
                break
        data[i] = flipped
        self.flipped += 1
        return bytes(data)

    def lose_ok(self) -> bool:
        """Whether the ``ok`` about to be sent is lost."""
        lost = self.rng.random() < self.settings.lost_ok_prob
        self.lost_oks += lost
        return lost

    def busy_for(self) -> float:
        """Simulated seconds of a busy period starting now (0 for none)."""
        if self.rng.random() >= self.settings.busy_prob:
            return 0.0
        self.busy_periods += 1
        return self.settings.busy_seconds
