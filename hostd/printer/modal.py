"""A pure tracker of the firmware's modal state as the streamed G-code leaves it.

It follows G90/G91, M82/M83, G92, G0/G1 targets (X Y Z A C E F), G28, temperatures and the part
fan, so a pause can record exactly what must be restored, and a resume from any line can
rebuild the state by replaying the file up to it.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from slicer.gcode.markers import marlin_words

AXES = ("X", "Y", "Z", "A", "C")
NAN = float("nan")
JOIN_LINES = 4096  # commands joined into one text by ModalState.apply_many
# a run of plain moves, one per line, each word a letter and a number float() reads as
# words() does: these change only positions, E and F (see ModalState.apply_many)
_PLAIN_MOVES = re.compile(r"(?:G[01](?: [XYZACEF][-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+))*\n)*")
_E_WORD = re.compile(r" E([^ \n]+)(?=[^E\n]*\n)")  # a move's last E word, as in words()


def words(command: str) -> tuple[str, dict[str, float]]:
    """``"G1 X1 Y-2.5"`` → ``("G1", {"X": 1.0, "Y": -2.5})``: the command and its parameters
    as the firmware reads them (:func:`slicer.gcode.markers.marlin_words`: ``G1 X 5`` moves
    X to 5, ``M104S200`` heats); a letter without a value is NaN (``G28 X``), a repeated one
    keeps its last value, and a line the firmware takes for no command gives ``("", {})``."""
    code, parts = marlin_words(command)
    return code, {letter: NAN if value is None else value for letter, value in parts}


@dataclass
class ModalState:
    """The modal state of the machine; every field JSON-friendly."""

    absolute: bool = True
    e_absolute: bool = True
    position: dict[str, float] = field(default_factory=lambda: dict.fromkeys((*AXES, "E"), 0.0))
    feedrate: float | None = None
    hotend: float = 0.0
    bed: float = 0.0
    fan: int = 0
    homed: bool = False
    extruded: float = 0.0  # net filament fed (mm), retractions included

    def apply(self, command: str) -> None:
        """Update from one (comment-free) G-code command."""
        code, args = words(command)
        handler = _HANDLERS.get(code)
        if handler is not None:
            handler(self, args)

    def apply_many(self, commands: Sequence[str]) -> None:
        """:meth:`apply` each command in order, with the same result to the last bit.

        Runs of plain ``G0``/``G1`` moves in absolute mode (nearly every line a print
        streams) are read with a few string searches over their joined text instead of a
        word split per line (:meth:`_plain_moves`); the other commands one by one. A long
        file (a resume) is joined :data:`JOIN_LINES` commands at a time, not all at once.
        """
        for start in range(0, len(commands), JOIN_LINES):
            self._apply_joined(commands[start:start + JOIN_LINES])

    def _apply_joined(self, commands: Sequence[str]) -> None:
        text = "\n".join(commands) + "\n"
        if text.count("\n") != len(commands):  # a command of several lines: one by one
            for command in commands:
                self.apply(command)
            return
        pos = index = 0
        while index < len(commands):
            end = _plain_run_end(text, pos) if self.absolute else pos
            if end > pos:
                self._plain_moves(text[pos:end])
                index += text.count("\n", pos, end)
                pos = end
            else:
                self.apply(commands[index])
                pos += len(commands[index]) + 1
                index += 1

    def _plain_moves(self, text: str) -> None:
        """Apply ``text``, plain moves one per line (each ending in a newline): an axis ends
        at its last value, and E is summed move by move as :meth:`_move` does."""
        position = self.position
        for axis in AXES:
            value = _last_value(text, " " + axis)
            if value is not None:
                position[axis] = value
        feedrate = _last_value(text, " F")
        if feedrate is not None:
            self.feedrate = feedrate
        e, extruded, relative = position["E"], self.extruded, not self.e_absolute
        for word in _E_WORD.findall(text):
            new = e + float(word) if relative else float(word)
            extruded += new - e
            e = new
        position["E"], self.extruded = e, extruded

    def _move(self, args: dict[str, float]) -> None:
        args = _valued(args)  # a letter without a value moves nothing (Marlin's seenval)
        for axis in AXES:
            if axis in args:
                self.position[axis] = (args[axis] if self.absolute
                                       else self.position[axis] + args[axis])
        if "E" in args:
            new = args["E"] if self.e_absolute else self.position["E"] + args["E"]
            self.extruded += new - self.position["E"]
            self.position["E"] = new
        if "F" in args:
            self.feedrate = args["F"]

    def _set_position(self, args: dict[str, float]) -> None:
        args = _valued(args)
        for axis in (*AXES, "E"):
            if axis in args:
                self.position[axis] = args[axis]

    def _home(self, args: dict[str, float]) -> None:
        named = [a for a in AXES if a in args] or list(AXES)
        for axis in named:
            self.position[axis] = 0.0
        self.homed = True

    def _abs(self, _args: dict[str, float]) -> None:
        self.absolute = self.e_absolute = True

    def _rel(self, _args: dict[str, float]) -> None:
        self.absolute = self.e_absolute = False

    def _e_abs(self, _args: dict[str, float]) -> None:
        self.e_absolute = True

    def _e_rel(self, _args: dict[str, float]) -> None:
        self.e_absolute = False

    def _hotend(self, args: dict[str, float]) -> None:
        self.hotend = _valued(args).get("S", self.hotend)

    def _bed(self, args: dict[str, float]) -> None:
        self.bed = _valued(args).get("S", self.bed)

    def _fan_on(self, args: dict[str, float]) -> None:
        self.fan = int(_valued(args).get("S", 255))

    def _fan_off(self, _args: dict[str, float]) -> None:
        self.fan = 0

    def snapshot(self) -> dict[str, Any]:
        """Every field, the position copied (``dataclasses.asdict``'s result, without its
        recursion: the job's progress is written with it several times a second)."""
        return {**vars(self), "position": dict(self.position)}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ModalState:
        state = cls()
        for key, value in data.items():
            if hasattr(state, key):
                setattr(state, key, dict(value) if isinstance(value, dict) else value)
        return state

    def copy(self) -> ModalState:
        return ModalState.from_dict(self.snapshot())

    # -- command sequences -----------------------------------------------------------------

    def pause_commands(self, retract: float, lift: float, z_max: float, retract_f: float,
                       lift_f: float) -> list[str]:
        """Retract and lift along machine Z only (A and C stay where they are)."""
        z = min(self.position["Z"] + lift, z_max)
        return ["M400", "M83", f"G1 E{-retract:.4f} F{retract_f:.0f}",
                "G90", f"G1 Z{z:.4f} F{lift_f:.0f}", "M400"]

    def resume_commands(self, retract: float, retract_f: float, travel_f: float,
                        lift_f: float) -> list[str]:
        """Come back over the recorded point, lower, unretract, restore every mode."""
        p = self.position
        out = ["G90", f"G1 X{p['X']:.4f} Y{p['Y']:.4f} F{travel_f:.0f}",
               f"G1 Z{p['Z']:.4f} F{lift_f:.0f}", "M83", f"G1 E{retract:.4f} F{retract_f:.0f}"]
        out += self.mode_commands()
        return out

    def mode_commands(self) -> list[str]:
        """Commands that put the modes (not the position) back: G90/G91, M82/M83, E, F, fan."""
        out = ["G90" if self.absolute else "G91", "M82" if self.e_absolute else "M83",
               f"G92 E{self.position['E']:.5f}"]
        if self.feedrate is not None:
            out.append(f"G1 F{self.feedrate:.0f}")
        out.append(f"M106 S{self.fan}" if self.fan else "M107")
        return out

    def restart_commands(self, safe_z: float, travel_f: float, rotary_f: float,
                         lift_f: float, home: bool = True) -> list[str]:
        """From a cold or reset machine (or one moved by hand: ``home`` False) to this state:
        re-home, reheat, safe height, rotate, approach the recorded X/Y, lower to Z, restore
        the modes."""
        p = self.position
        out = ["G28"] if home else []
        out += self.heat_commands()
        out += ["G90", f"G0 Z{max(safe_z, p['Z']):.4f} F{lift_f:.0f}",
                f"G0 A{p['A']:.4f} C{p['C']:.4f} F{rotary_f:.0f}",
                f"G0 X{p['X']:.4f} Y{p['Y']:.4f} F{travel_f:.0f}",
                f"G0 Z{p['Z']:.4f} F{lift_f:.0f}"]
        return out + self.mode_commands()

    def heat_commands(self) -> list[str]:
        """Set the heaters' targets (bed first) and wait for them; none if both are off."""
        out = []
        if self.bed:
            out.append(f"M140 S{self.bed:g}")
        if self.hotend:
            out.append(f"M104 S{self.hotend:g}")
        if self.bed:
            out.append(f"M190 S{self.bed:g}")
        if self.hotend:
            out.append(f"M109 S{self.hotend:g}")
        return out

    def heaters_off_commands(self) -> list[str]:
        """Turn off a heater this state has off (one an operator may have turned on)."""
        return [f"{code} S0" for code, target in (("M140", self.bed), ("M104", self.hotend))
                if not target]


def _valued(args: dict[str, float]) -> dict[str, float]:
    """``args`` without the letters given with no value (NaN)."""
    return {k: v for k, v in args.items() if v == v}


def _plain_run_end(text: str, pos: int) -> int:
    """Where the run of plain moves starting at ``pos`` in ``text`` ends (``pos``: none)."""
    run = _PLAIN_MOVES.match(text, pos)
    return run.end() if run else pos


def _last_value(text: str, key: str) -> float | None:
    """The number after the last ``key`` (e.g. ``" X"``) in ``text``, whose words end at a
    blank or a newline; ``None`` if there is none."""
    start = text.rfind(key)
    if start < 0:
        return None
    start += len(key)
    end = text.find(" ", start)
    newline = text.find("\n", start)
    return float(text[start:newline if end < 0 or newline < end else end])


_HANDLERS = {
    "G0": ModalState._move, "G1": ModalState._move, "G2": ModalState._move,
    "G3": ModalState._move, "G92": ModalState._set_position, "G28": ModalState._home,
    "G90": ModalState._abs, "G91": ModalState._rel, "M82": ModalState._e_abs,
    "M83": ModalState._e_rel, "M104": ModalState._hotend, "M109": ModalState._hotend,
    "M140": ModalState._bed, "M190": ModalState._bed, "M106": ModalState._fan_on,
    "M107": ModalState._fan_off,
}
