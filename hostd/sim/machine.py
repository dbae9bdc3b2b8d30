"""The emulated machine behind the command queue: axes, modes, heaters, fan, motion timing.

Commands run in three steps on the simulated clock: :meth:`Machine.start` (side effects such
as setting a heater target), :meth:`Machine.ready_at` (when the command may complete: a free
planner block, an idle planner, a heater at temperature) and :meth:`Machine.finish` (the
reply lines).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from hostd.sim.heaters import Heater
from hostd.sim.planner import Planner
from hostd.sim.settings import SimSettings
from slicer.gcode.markers import marlin_words

AXES = ("X", "Y", "Z", "A", "C")
LINEAR = ("X", "Y", "Z")
ROTARY = ("A", "C")
STEPS_PER_UNIT = {"X": 80.0, "Y": 80.0, "Z": 400.0, "A": 40.0, "C": 40.0, "E": 420.0}
ROTARY_SPEED = 90.0  # degrees per second
HOME_SECONDS = 2.0
FIRMWARE_NAME = "Marlin 2.1.2-hostd-sim"
CAPABILITIES = ("AUTOREPORT_TEMP", "EMERGENCY_PARSER", "AUTOREPORT_POS", "EXTENDED_M20")


@dataclass
class Command:
    """One command taken from the queue: its line number (if any) and text, read as Marlin
    reads it (:func:`slicer.gcode.markers.marlin_words`, after ``GCodeParser::parse``):
    ``code`` (``""`` for none: an unknown command), ``words`` the parameters with a value
    (the last of a repeated one, as FASTER_GCODE_PARSER keeps), ``seen`` every letter given
    (``G28 X``). Temperatures are read as value_float reads them (a build with
    TEMPERATURE_UNITS_SUPPORT; stock Marlin's value_int reads no more)."""

    number: int | None
    text: str
    started: bool = False
    until: float | None = None  # a dwell's end, fixed when first asked
    code: str = ""
    words: dict[str, float] = field(default_factory=dict)
    seen: frozenset[str] = frozenset()

    def __post_init__(self) -> None:
        self.code, parts = marlin_words(self.text)
        self.words = {letter: value for letter, value in parts if value is not None}
        self.seen = frozenset(letter for letter, _ in parts)


class Machine:
    """Axes, modes, heaters and the planner of the emulated printer."""

    def __init__(self, settings: SimSettings) -> None:
        self.settings = settings
        self.planner = Planner(settings.planner_blocks)
        self.position = dict.fromkeys((*AXES, "E"), 0.0)  # logical (after G92 offsets)
        self.shift = dict.fromkeys(AXES, 0.0)  # machine position less logical (G92)
        self.drift = dict.fromkeys(ROTARY, 0.0)
        self.absolute = True
        self.absolute_e = True
        self.feedrate = 3000.0
        self.fan = 0
        self.steppers_on = False
        self.hotend = Heater(tau=20.0)
        self.bed = Heater(tau=60.0)
        self.autoreport = 0.0
        self.rotary_moves = 0

    # -- the three steps ----------------------------------------------------------------

    def start(self, cmd: Command, now: float) -> None:
        """Side effects that happen when the command begins."""
        heater = {"M104": self.hotend, "M109": self.hotend, "M140": self.bed,
                  "M190": self.bed}.get(cmd.code)
        # M109/M190 take R when there is no S (Marlin: seenval('S') || seenval('R'))
        keys = ("S",) if cmd.code in ("M104", "M140") else ("S", "R")
        target = next((cmd.words[k] for k in keys if k in cmd.words), None)
        if heater is not None and target is not None:
            heater.set_target(target, now)

    def ready_at(self, cmd: Command, now: float) -> float:
        """Simulated time at which ``cmd`` can complete."""
        if cmd.code in ("G0", "G1", "G28"):
            if cmd.code == "G28":
                return self.planner.idle_at(now)
            return now if self.planner.free(now) > 0 else self.planner.next_free_at()
        if cmd.code == "G4":  # the planner drains, then the dwell runs from then on
            if cmd.until is None:
                cmd.until = self.planner.idle_at(now) + (cmd.words.get("P", 0) / 1000.0
                                                         + cmd.words.get("S", 0))
            return cmd.until
        if cmd.code in ("M400", "M84"):
            return self.planner.idle_at(now)
        if cmd.code == "M109":
            return max(now, self.hotend.reached_at(now))
        if cmd.code == "M190":
            return max(now, self.bed.reached_at(now))
        return now

    def finish(self, cmd: Command, now: float) -> tuple[list[str], str | None]:
        """Complete ``cmd``: the lines it prints, and a replacement for its ``ok`` line."""
        handler = _HANDLERS.get(cmd.code)
        if handler is None:
            return [f'echo:Unknown command: "{cmd.text}"'], None
        return handler(self, cmd, now)

    # -- reports ------------------------------------------------------------------------

    def temperature_report(self, now: float) -> str:
        """``T:… /… B:… /… @:… B@:…`` as Marlin prints it."""
        h, b = self.hotend, self.bed
        return (f"T:{h.temperature(now):.2f} /{h.target:.2f} B:{b.temperature(now):.2f} "
                f"/{b.target:.2f} @:{h.power(now)} B@:{b.power(now)}")

    def position_report(self) -> str:
        """The M114 line: reported positions (with any lost steps) and step counts."""
        shown = {k: self.position[k] + self.drift.get(k, 0.0) for k in (*AXES, "E")}
        head = " ".join(f"{k}:{shown[k]:.2f}" for k in (*AXES, "E"))
        counts = " ".join(f"{k}:{round(shown[k] * STEPS_PER_UNIT[k])}" for k in AXES)
        return f"{head} Count {counts}"

    # -- handlers -----------------------------------------------------------------------

    def _move(self, cmd: Command, now: float) -> tuple[list[str], str | None]:
        if "F" in cmd.words and cmd.words["F"] > 0:
            self.feedrate = cmd.words["F"]
        target = dict(self.position)
        for axis in (*AXES, "E"):
            if axis in cmd.words:
                relative = not (self.absolute_e if axis == "E" else self.absolute)
                target[axis] = cmd.words[axis] + (self.position[axis] if relative else 0.0)
        self._count_rotary(target)
        linear = math.dist([self.position[a] for a in LINEAR], [target[a] for a in LINEAR])
        rotary = max(abs(target[a] - self.position[a]) for a in ROTARY)
        extrude = abs(target["E"] - self.position["E"])
        duration = max(linear / (self.feedrate / 60.0), rotary / ROTARY_SPEED,
                       extrude / (self.feedrate / 60.0), 1e-4)
        self.position = target
        self.steppers_on = True
        self.planner.add(duration, now)
        return [], None

    def _count_rotary(self, target: dict[str, float]) -> None:
        s = self.settings
        axis = s.lost_step_axis.upper()
        if axis not in ROTARY or not s.lost_step_at_move or target[axis] == self.position[axis]:
            return
        self.rotary_moves += 1
        if self.rotary_moves == s.lost_step_at_move:
            self.drift[axis] += s.lost_step_degrees

    def _home(self, cmd: Command, now: float) -> tuple[list[str], str | None]:
        axes = [a for a in AXES if a in cmd.seen] or list(AXES)
        for a in axes:
            self.position[a] = self.shift[a] = 0.0  # homing clears G92's offset (Marlin)
            if a in self.drift:
                self.drift[a] = 0.0
        self.planner.add(HOME_SECONDS, now)
        return [], None

    def _set_position(self, cmd: Command, now: float) -> tuple[list[str], str | None]:
        for axis in (*AXES, "E"):
            if axis in cmd.words:
                if axis in self.shift:  # the axis stays where it is: its offset changes
                    self.shift[axis] += self.position[axis] - cmd.words[axis]
                self.position[axis] = cmd.words[axis]
        return [], None

    def machine_position(self) -> dict[str, float]:
        """Where the axes are in machine coordinates (the travel's): G92 offsets undone."""
        return {axis: self.position[axis] + self.shift[axis] for axis in AXES}

    def _modes(self, cmd: Command, now: float) -> tuple[list[str], str | None]:
        if cmd.code in ("G90", "G91"):
            self.absolute = self.absolute_e = cmd.code == "G90"
        else:
            self.absolute_e = cmd.code == "M82"
        return [], None

    def _fan(self, cmd: Command, now: float) -> tuple[list[str], str | None]:
        self.fan = int(cmd.words.get("S", 255)) if cmd.code == "M106" else 0
        return [], None

    def _quiet(self, cmd: Command, now: float) -> tuple[list[str], str | None]:
        if cmd.code == "M84":
            self.steppers_on = False
        return [], None

    def _m105(self, cmd: Command, now: float) -> tuple[list[str], str | None]:
        return [], "ok " + self.temperature_report(now)

    def _m114(self, cmd: Command, now: float) -> tuple[list[str], str | None]:
        return [self.position_report()], None

    def _m115(self, cmd: Command, now: float) -> tuple[list[str], str | None]:
        lines = [f"FIRMWARE_NAME:{FIRMWARE_NAME} SOURCE_CODE_URL:local PROTOCOL_VERSION:1.0 "
                 f"MACHINE_TYPE:five-axis EXTRUDER_COUNT:1 AXIS_COUNT:5 UUID:sim"]
        lines += [f"Cap:{c}:1" for c in CAPABILITIES]
        return lines, None

    def _m155(self, cmd: Command, now: float) -> tuple[list[str], str | None]:
        self.autoreport = max(0.0, cmd.words.get("S", 0.0))
        return [], None


_HANDLERS = {
    "G0": Machine._move, "G1": Machine._move, "G28": Machine._home,
    "G92": Machine._set_position, "G90": Machine._modes, "G91": Machine._modes,
    "M82": Machine._modes, "M83": Machine._modes, "M104": Machine._quiet,
    "M109": Machine._quiet, "M140": Machine._quiet, "M190": Machine._quiet,
    "M106": Machine._fan, "M107": Machine._fan, "M84": Machine._quiet,
    "M400": Machine._quiet, "G4": Machine._quiet, "M105": Machine._m105,
    "M114": Machine._m114, "M115": Machine._m115, "M155": Machine._m155,
    "M110": Machine._quiet,
}
