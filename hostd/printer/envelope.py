"""Whether a G-code file fits this printer: its moves within the machine's travel, and a
file hostd sliced made for this machine's kinematics.

Pure: a :class:`~hostd.printer.program.Program` in, a :class:`ProgramError` naming the
line, axis, value and config key out. The file checker runs it on every G-code job before
it is queued (an upload, or the slicer's own output), so a file made for another machine, or
one whose moves leave the travel, is refused at submission rather than clamped by the
firmware's software endstops halfway through a print.

Every command is read as the firmware reads it (:func:`slicer.gcode.markers.marlin_words`):
``M104 S 400``, ``M104S400``, ``M65640 S400`` (the code wraps at 65536) and ``G1X9999`` are
what they are to Marlin, not words this check would skip. The travel is followed as the
firmware would: ``G90``/``G91``, ``G92`` offsets (so the checked values are machine
coordinates) and ``G28`` (after it an axis' position is the endstop's, unknown here: relative
moves from it are not checked until an absolute one). A block of commands in absolute mode
with none of those, every line of it in the plain form a blank split reads as Marlin does
(nearly every block of a sliced file), is read with one regular-expression search per axis
over its moves; the others command by command. An axis word or heater target repeated in
one command counts every value (Marlin takes the last, a build without FASTER_GCODE_PARSER
the first).
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from hostd.printer.errors import ProgramError
from hostd.printer.modal import AXES, JOIN_LINES
from hostd.printer.program import Program
from slicer.gcode.markers import marlin_words

TRAVEL_TOL = 1e-3  # mm or degrees past a limit still accepted (the slicer's rounding)
KINEMATICS_TOL = 1e-6
RANGE_KEYS = {"X": "machine.x_range", "Y": "machine.y_range", "Z": "machine.z_range",
              "A": "machine.a_limits", "C": "machine.c_limits"}
HEADER_KEYS = {"table_origin": "machine.table_origin", "a_pivot": "machine.a_pivot",
               "a_limits": "machine.a_limits", "c_limits": "machine.c_limits",
               "platform_radius": "machine.platform_radius", "printhead": "printhead.segments"}
_VALUES = {axis: re.compile(rf" {axis}([^ \n]+)") for axis in AXES}
_MOVE_WORDS = re.compile(r"^G0*[0-3](?= |$)([^\n]*)", re.M)  # a move's words, after its code
_PLAIN_BLOCK = re.compile(  # lines a blank split reads as Marlin does: a code of at most four
    r"(?:[GMT][0-9]{1,4}(?: [A-Z][-+]?[0-9]*\.?[0-9]*)*\n"  # digits, words of a letter and
    r"|M0*(?:23|28|30|117|118|928)(?: [^\n]*)?\n)*")  # what float() reads as strtof or refuses
_BY_COMMAND = re.compile(  # commands only a command-by-command reading follows: modes,
    r"^G0*(?:9[01]|28(?= |$)|92 [^\n]*[XYZAC])", re.M)  # homing, offsets of an axis
HEATERS = {"M104": "hotend", "M109": "hotend", "M140": "bed", "M190": "bed", "M303": "hotend"}
HEATER_KEYS = {"hotend": "machine.max_hotend_temp", "bed": "machine.max_bed_temp"}
TARGET_WORDS = ("S", "R", "B")  # set point, wait-for (M109/M190 R), AUTOTEMP's highest (B)
_M_LINE = re.compile(r"^ *(?:[Nn][-0-9][0-9]* *)?[Mm][^\n]*", re.M)  # what may be an M code


@dataclass(frozen=True)
class Envelope:
    """The printer a file must fit.

    Attributes
    ----------
    ranges
        Axis → [min, max] travel (machine coordinates, mm or degrees); an axis left out (a
        continuous C) is not checked.
    kinematics
        The ``;HOSTD_KINEMATICS`` values this printer's config gives (keys of
        :data:`HEADER_KEYS`), compared with a sliced file's header.
    """

    ranges: dict[str, tuple[float, float]]
    kinematics: dict[str, Any]
    heaters: dict[str, float] | None = None
    """Heater (``hotend``, ``bed``) → highest target temperature, °C."""

    def check(self, program: Program) -> None:
        """Raise :class:`ProgramError` when ``program`` does not fit this printer."""
        if program.kinematics:
            self._check_kinematics(program.kinematics)
        self.check_temperatures(program)
        extents = travel_extents(program.commands)
        for axis, (lo, hi) in self.ranges.items():
            low, high = extents.get(axis, (math.inf, -math.inf))
            if low < lo - TRAVEL_TOL or high > hi + TRAVEL_TOL:
                raise ProgramError(self._outside(program, axis))

    def check_temperatures(self, program: Program) -> None:
        """Refuse a heater target above this printer's (``M104``/``M109``/``M140``/``M190``
        ``S`` or ``R``): the firmware would clamp it, or heat to it."""
        if not self.heaters:
            return
        for start in range(0, len(program.commands), JOIN_LINES):
            text = "\n".join(program.commands[start:start + JOIN_LINES])
            for found in _M_LINE.finditer(text):
                self._check_target(program, start + text.count("\n", 0, found.start()),
                                   found.group())

    def _check_target(self, program: Program, index: int, command: str) -> None:
        """Every target ``command`` sets, as the firmware reads it, within the limits."""
        code, args = marlin_words(command)
        heater = HEATERS.get(code)
        if heater is None or not self.heaters:
            return
        if code == "M303" and any(k == "E" and v == -1 for k, v in args):
            heater = "bed"  # M303 E-1 tunes the bed
        limit = self.heaters.get(heater)
        for key, value in args:
            if key not in TARGET_WORDS or value is None:
                continue
            if value < 0:
                raise ProgramError(f"line {program.source_lines[index]}: {code} {key}{value:g}: "
                                   "a negative temperature")
            if limit is not None and value > limit:
                raise ProgramError(
                    f"line {program.source_lines[index]}: {code} {key}{value:g} is above the "
                    f"{heater}'s limit {limit:g} °C ({HEATER_KEYS[heater]})")

    def _check_kinematics(self, header: dict[str, Any]) -> None:
        for key, config_key in HEADER_KEYS.items():
            if key in header and not _same(header[key], self.kinematics.get(key)):
                raise ProgramError(
                    f"sliced for another machine: {key} {_text(header[key])} in the file's "
                    f"HOSTD_KINEMATICS, {_text(self.kinematics.get(key))} in this printer's "
                    f"config ({config_key}); slice it again for this printer")

    def _outside(self, program: Program, axis: str) -> str:
        index, value = first_outside(program.commands, axis, self.ranges[axis])
        lo, hi = self.ranges[axis]
        return (f"line {program.source_lines[index]}: {axis} {value:.4g} is outside the "
                f"machine's travel [{lo:g}, {hi:g}] ({RANGE_KEYS[axis]})")


def envelope_from_config(values: Mapping[str, Any]) -> Envelope:
    """The envelope of a config's dotted ``values``."""
    ranges = {axis: _range(values[key]) for axis, key in RANGE_KEYS.items()
              if values.get(key) is not None}
    segments = [[float(s[k]) for k in ("start", "end", "r_start", "r_end")]
                for s in values["printhead.segments"]]
    kinematics = {key: values[config_key] for key, config_key in HEADER_KEYS.items()
                  if key != "printhead"}
    heaters = {heater: float(values[key]) for heater, key in HEATER_KEYS.items()
               if values.get(key) is not None}
    return Envelope(ranges, {**kinematics, "printhead": segments}, heaters)


def _range(value: Iterable[Any]) -> tuple[float, float]:
    """A config's ``[min, max]`` travel as floats."""
    lo, hi = map(float, value)
    return lo, hi


def _same(a: Any, b: Any) -> bool:
    """Equal JSON values, numbers within :data:`KINEMATICS_TOL`."""
    if isinstance(a, list | tuple) and isinstance(b, list | tuple):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, int | float) and isinstance(b, int | float):
        return abs(float(a) - float(b)) <= KINEMATICS_TOL
    return bool(a == b)


def _text(value: Any) -> str:
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_text(v) for v in value) + "]"
    return f"{value:g}" if isinstance(value, float) else str(value)


class _Travel:
    """Follows the machine position through commands; the extents it reached."""

    def __init__(self) -> None:
        self.absolute = True
        self.pos: dict[str, float | None] = dict.fromkeys(AXES, None)  # logical, None: unknown
        self.offset: dict[str, float | None] = dict.fromkeys(AXES, 0.0)  # machine - logical
        self.low: dict[str, float] = {}
        self.high: dict[str, float] = {}

    def feed(self, commands: Sequence[str]) -> None:
        """Follow a block of commands."""
        text = "\n".join(commands) + "\n"
        plain = (self.absolute and text.count("\n") == len(commands)
                 and _PLAIN_BLOCK.fullmatch(text) is not None
                 and _BY_COMMAND.search(text) is None)
        found = _move_values("\n".join(_MOVE_WORDS.findall(text)) + "\n") if plain else None
        if found is None:
            for command in commands:
                self.one(command)
            return
        for axis, values in found.items():
            self._reach(axis, min(values), max(values))
            self.pos[axis] = values[-1]

    def one(self, command: str) -> None:
        code, args = marlin_words(command)
        if code in ("G0", "G1", "G2", "G3"):
            for axis, value in args:
                if axis in self.pos and value is not None:  # no value: no move
                    self._move(axis, value)
        elif code in ("G90", "G91"):
            self.absolute = code == "G90"
        elif code == "G92":
            for axis, value in args:
                if axis in self.pos and value is not None:
                    self._set(axis, value)
        elif code == "G28":
            named = {axis for axis, _ in args if axis in self.pos}
            for axis in [a for a in AXES if a in named] or AXES:
                self.pos[axis], self.offset[axis] = None, 0.0

    def _move(self, axis: str, value: float) -> None:
        here = self.pos[axis]
        target = value if self.absolute else (None if here is None else here + value)
        self.pos[axis] = target
        if target is not None:
            self._reach(axis, target, target)

    def _set(self, axis: str, value: float) -> None:
        here, offset = self.pos[axis], self.offset[axis]
        if here is not None and offset is not None:
            self.offset[axis] = here + offset - value  # the machine stays where it is
        else:
            self.offset[axis] = None  # logical from here on, its machine place unknown
        self.pos[axis] = value

    def _reach(self, axis: str, low: float, high: float) -> None:
        offset = self.offset[axis]
        if offset is None or math.isnan(low) or math.isnan(high):
            return  # after a G92 from an unknown place, or a bare axis letter
        self.low[axis] = min(self.low.get(axis, math.inf), low + offset)
        self.high[axis] = max(self.high.get(axis, -math.inf), high + offset)


def _move_values(words: str) -> dict[str, list[float]] | None:
    """Axis → the values absolute moves give it, in order, from their ``words`` (a line
    each, the code left out, every word a letter and a plain number or none); None when a
    value is not a finite number (then the block is read command by command)."""
    found = {}
    for axis, pattern in _VALUES.items():
        try:
            values = [float(v) for v in pattern.findall(words)]
        except ValueError:
            return None
        if values:
            if not all(map(math.isfinite, values)):
                return None
            found[axis] = values
    return found


def travel_extents(commands: Sequence[str], block: int = JOIN_LINES
                   ) -> dict[str, tuple[float, float]]:
    """Axis → (lowest, highest) machine coordinate the moves of ``commands`` reach (axes
    never reached at a known place are left out), read ``block`` commands at a time."""
    travel = _Travel()
    for start in range(0, len(commands), block):
        travel.feed(commands[start:start + block])
    return {axis: (travel.low[axis], travel.high[axis]) for axis in travel.low}


def first_outside(commands: Sequence[str], axis: str, limits: tuple[float, float]
                  ) -> tuple[int, float]:
    """The first command whose move takes ``axis`` outside ``limits``, and the value it
    reaches there (command by command: only called once the extents say there is one)."""
    travel = _Travel()
    lo, hi = limits
    for index, command in enumerate(commands):
        travel.one(command)
        low, high = travel.low.get(axis, math.inf), travel.high.get(axis, -math.inf)
        if low < lo - TRAVEL_TOL or high > hi + TRAVEL_TOL:
            return index, low if low < lo - TRAVEL_TOL else high
    raise ProgramError(f"{axis}: no command leaves [{lo:g}, {hi:g}]")
