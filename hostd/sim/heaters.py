"""First-order heater model on the simulated clock."""

from __future__ import annotations

import math
from dataclasses import dataclass

AMBIENT = 22.0


@dataclass
class Heater:
    """A heater that approaches its target exponentially with time constant ``tau`` (s)."""

    tau: float
    target: float = 0.0
    start_temp: float = AMBIENT
    start_time: float = 0.0

    def temperature(self, now: float) -> float:
        """Measured temperature at simulated time ``now``."""
        goal = max(self.target, AMBIENT)
        return goal + (self.start_temp - goal) * math.exp(-(now - self.start_time) / self.tau)

    def set_target(self, target: float, now: float) -> None:
        """Change the target at ``now``."""
        self.start_temp = self.temperature(now)
        self.start_time = now
        self.target = target

    def reached_at(self, now: float, window: float = 1.0) -> float:
        """Simulated time at which the temperature is within ``window`` °C of the target."""
        goal = max(self.target, AMBIENT)
        gap = abs(self.temperature(now) - goal)
        if gap <= window:
            return now
        return now + self.tau * math.log(gap / window)

    def power(self, now: float) -> int:
        """PWM 0..127 as Marlin reports it: proportional to the remaining gap."""
        if self.target <= 0:
            return 0
        return int(max(0.0, min(127.0, (self.target - self.temperature(now)) * 4 + 20)))
