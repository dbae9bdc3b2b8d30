"""The words of hostd's G-code lines: the ``;HOSTD_`` markers and a command's words.

A marker is a comment line ``;HOSTD_<NAME> <payload>``: the name in capitals and
underscores, the payload one JSON object (none for :data:`TRANSITION_END`).
``docs/gcode-format.md`` describes each. The slicer's writer (:mod:`slicer.gcode.writer`)
makes them with :func:`marker_line`; the two readers, the slicer's
(:mod:`slicer.gcode.reader`, for the replay check) and the daemon's
(``hostd.printer.program``, for streaming), find them with :func:`parse_marker` and read
their payload with :func:`parse_payload`. A command's words (``G1 X1 Y-2.5``) are split by
:func:`split_words`, for those readers, the daemon's modal tracker and the firmware emulator
alike; what a value that is no number means stays each one's to say.

Plain Python, no numpy: the daemon imports this module (its program reader and the
emulator), and the daemon never loads numpy; :mod:`slicer.gcode` loads its other modules
only when asked for them.
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from typing import Any, TypedDict

PREFIX = ";HOSTD_"
"""What every marker line starts with."""

# The headers, once each at the top of a sliced file.
KINEMATICS = "KINEMATICS"
"""The machine geometry (``kinematics.machine.MachineGeometry.header``), the platform radius
and the printhead: what a replay of the file needs of the machine."""
PROCESS = "PROCESS"
"""The process values the beads were sized with (``ProcessSettings.header``)."""
PLACEMENT = "PLACEMENT"
"""The STL → platform matrix (:class:`PlacementPayload`)."""
ESTIMATE = "ESTIMATE"
"""Filament, mass and time of the file (``Estimate.header``)."""
HEADERS = (KINEMATICS, PROCESS, PLACEMENT, ESTIMATE)

# The markers, each before the moves it tags.
SUBPART = "SUBPART"
"""A sub-part starts (:class:`SubpartPayload`)."""
LAYER = "LAYER"
"""A layer starts (:class:`LayerPayload`)."""
INTERFACE = "INTERFACE"
"""The layer is one of a parent's solid layers under a child's base (:class:`InterfacePayload`)."""
TRANSITION = "TRANSITION"
"""The moves to the next sub-part start (:data:`TransitionPayload`): lift, rotate, travel,
approach, up to :data:`TRANSITION_END`."""
TRANSITION_END = "TRANSITION_END"
"""The transition's moves end (no payload)."""


class PlacementPayload(TypedDict):
    matrix: list[list[float]]  # 4 × 4, STL file frame → platform frame


class SubpartPayload(TypedDict):
    index: int
    parent: int | None  # None for the root


class LayerPayload(TypedDict):
    subpart: int
    index: int  # counted from the sub-part's first layer


class InterfacePayload(TypedDict):
    parent: int
    child: int


TransitionPayload = TypedDict("TransitionPayload", {
    "from": int | None,  # the sub-part printed before (None: the first)
    "to": int,  # the sub-part the moves lead to
    "a": float, "c": float,  # platform angles at the approach, degrees
    "x": float, "y": float, "z": float,  # machine position at the approach, mm
    "safe_z": float,  # machine Z the moves lift to before the platform turns, mm
})

_MARKER = re.compile(r";HOSTD_([A-Z_]+)\s*(.*)$")


def marker_line(name: str, payload: Mapping[str, Any] | None = None) -> str:
    """The line of marker ``name``: ``;HOSTD_LAYER {"subpart": 0, "index": 3}`` (JSON with
    blanks after commas and colons), or ``;HOSTD_TRANSITION_END`` without a payload."""
    if payload is None:
        return PREFIX + name
    return f"{PREFIX}{name} {json.dumps(payload, separators=(', ', ': '))}"


def parse_marker(line: str) -> tuple[str, str] | None:
    """``(name, payload text)`` of a marker line (given without surrounding blanks), or None
    for any other line: ``';HOSTD_LAYER {"subpart": 0, "index": 3}'`` → ``("LAYER",
    '{"subpart": 0, "index": 3}')``. A comment that starts with ``;HOSTD_`` but names no
    marker in capitals is no marker."""
    found = _MARKER.match(line)
    return None if found is None else (found[1], found[2].strip())


class PayloadError(ValueError):
    """A marker's payload that is no JSON object. ``reason``: ``bad JSON`` or ``expected a
    JSON object``; ``str()`` adds the parser's words to the first."""

    def __init__(self, reason: str, detail: str | None = None) -> None:
        super().__init__(reason if detail is None else f"{reason}: {detail}")
        self.reason = reason


def parse_payload(text: str) -> dict[str, Any]:
    """A marker's payload text as a dict (``{}`` for none); :class:`PayloadError` for one
    that is not a JSON object."""
    if not text:
        return {}
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise PayloadError("bad JSON", exc.msg) from None
    except ValueError as exc:  # a number too long for int()
        raise PayloadError("bad JSON", str(exc)) from None
    if not isinstance(data, dict):
        raise PayloadError("expected a JSON object")
    return data


def split_words(command: str) -> tuple[str, list[tuple[str, str]]]:
    """A command's first word, and every other word as its first character and the rest.

    ``"G1 X1 y-2.5 E"`` → ``("G1", [("X", "1"), ("y", "-2.5"), ("E", "")])``; words are
    separated by blanks (any white space), nothing is upper-cased and no value is read: the
    modal tracker skips a value that is no number, the file reader refuses it, the emulator
    reads the number it starts with. An empty command gives ``("", [])``.
    """
    first, *rest = command.split() or [""]
    return first, [(word[0], word[1:]) for word in rest]
