"""G-code: a print plan written as joint-space G-code, and read back.

* :mod:`~slicer.gcode.writer`: :func:`draft` and :func:`write_gcode`, a
  :class:`~slicer.plan.PrintPlan` as self-describing G-code (headers, markers, moves);
  :class:`MachineSetup`, what the writer knows of the machine.
* :mod:`~slicer.gcode.markers`: the ``;HOSTD_`` markers (names, payloads, their lines made
  and parsed) and the words of a command, for the writer, both readers (this package's and
  ``hostd.printer.program``) and the firmware emulator. No numpy.
* :mod:`~slicer.gcode.transitions`: the moves between sub-parts (lift, rotate, travel,
  approach) clear of the part and the platform.
* :mod:`~slicer.gcode.extrusions`: every path as one run of vertices, with its filament and
  joint poses; :mod:`~slicer.gcode.merge`: the vertices a longer move passes within the
  linearisation tolerance, left out.
* :mod:`~slicer.gcode.program`: a program under construction (comment lines and numeric move
  blocks); :mod:`~slicer.gcode.format`: move lines as text, the whole file at once.
* :mod:`~slicer.gcode.estimate`: filament and time of the moves.
* :mod:`~slicer.gcode.reader`: :func:`read_gcode`, a file's moves as arrays with its headers
  and markers (what the replay check reads).

The other stages import what they need from here, not from the modules. Each name is
imported from its module when first asked for (``__getattr__``), so that importing
:mod:`slicer.gcode.markers`, which the daemon does, loads no numpy.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from slicer.gcode.estimate import MotionLimits, estimate_moves
    from slicer.gcode.program import E
    from slicer.gcode.reader import (
        GcodeFormatError,
        ParsedGcode,
        parse_lines,
        parse_words,
        read_gcode,
    )
    from slicer.gcode.writer import (
        Draft,
        GcodeError,
        MachineSetup,
        draft,
        filament_area,
        write_gcode,
    )

__all__ = [
    "Draft",
    "E",
    "GcodeError",
    "GcodeFormatError",
    "MachineSetup",
    "MotionLimits",
    "ParsedGcode",
    "draft",
    "estimate_moves",
    "filament_area",
    "parse_lines",
    "parse_words",
    "read_gcode",
    "write_gcode",
]

_HOMES = {
    "estimate": ("MotionLimits", "estimate_moves"),
    "program": ("E",),
    "reader": ("GcodeFormatError", "ParsedGcode", "parse_lines", "parse_words", "read_gcode"),
    "writer": ("Draft", "GcodeError", "MachineSetup", "draft", "filament_area", "write_gcode"),
}
"""The module of every name above (the imports for type checkers say the same)."""
_MODULE_OF = {name: module for module, names in _HOMES.items() for name in names}


def __getattr__(name: str) -> Any:
    module = _MODULE_OF.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(import_module(f"{__name__}.{module}"), name)
    globals()[name] = value  # asked once
    return value
