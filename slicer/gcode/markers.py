"""The words of hostd's G-code lines: the ``;HOSTD_`` markers and a command's words.

A marker is a comment line ``;HOSTD_<NAME> <payload>``: the name in capitals and
underscores, the payload one JSON object (none for :data:`TRANSITION_END`).
``docs/gcode-format.md`` describes each. The slicer's writer (:mod:`slicer.gcode.writer`)
makes them with :func:`marker_line`; the two readers, the slicer's
(:mod:`slicer.gcode.reader`, for the replay check) and the daemon's
(``hostd.printer.program``, for streaming), find them with :func:`parse_marker` and read
their payload with :func:`parse_payload`. A command's words (``G1 X1 Y-2.5``) are split as
written by :func:`split_words`, for those readers, which refuse a value that is no number;
:func:`marlin_words` reads them as the firmware does (``M104 S 400`` heats to 400 °C), for
everything that must agree with the printer: the daemon's modal tracker, its travel and
heater checks of raw G-code and uploads, and the firmware emulator.

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


# -- a command as Marlin reads it ------------------------------------------------------------
#
# Marlin 2.1's GCodeParser::parse (MarlinFirmware/Marlin, Marlin/src/gcode/parser.cpp, with
# parser.h; the line reaches it from GCodeQueue::get_serial_commands in gcode/queue.cpp):
#
# - queue.cpp drops a ``;`` comment with the rest of the line (process_stream_char: PS_EOL)
#   before anything else, and a backslash makes the next character plain text;
# - parse() skips leading spaces and one ``N`` word (``N``, a digit or ``-``, digits, spaces),
#   then takes the command letter (``G``, ``M`` or ``T``; lower case too with
#   GCODE_CASE_INSENSITIVE) and cuts the line at its first ``*`` (a checksum);
# - spaces may stand between the letter and the code number, which is integer digits only
#   (``codenum``, a uint16_t: ``M65640`` is ``M104``); a ``.5`` after it is a sub-code or
#   skipped, and the parameters may follow with no blank (``M104S400``);
# - M23, M28, M30, M117, M118 and M928 take the rest of the line as text: no parameters;
# - each parameter is a letter (upper case only, unless GCODE_CASE_INSENSITIVE), then spaces
#   are skipped ("Skip spaces between parameters & values": ``S 400`` is S400), then a value
#   if it is valid_float: ``[-+]?.?[0-9]`` (``S+400``, ``S.5``; ``S-`` or ``Snan`` has none);
#   unless the next character is an upper-case letter, the characters ``0-9 . + -`` and the
#   spaces after them are skipped, so ``T0S400`` is T0 and S400;
# - a repeated parameter: FASTER_GCODE_PARSER (on by default) keeps the last;
# - value_float() cuts the value at its first ``E`` (no exponents: ``X1E3`` is X1 then E3)
#   and reads it with strtof, which stops at the first character that is no part of a number
#   (``S400.`` and ``S400-5`` are 400) and reads hexadecimal too (``S0x190`` is 400);
#   temperatures are value_celsius(), value_int() (strtol, base 10: never more than
#   value_float reads of a value that is not negative), or value_float with
#   TEMPERATURE_UNITS_SUPPORT; with GCODE_QUOTED_STRINGS a value may be quoted (``S"400"``).
#
# Where builds differ (letter case, quoted values), the reading here is the one that
# executes more: the checks built on it refuse what any of those builds would run, and the
# emulator runs it.

MESSAGE_CODES = frozenset({"M23", "M28", "M30", "M117", "M118", "M928"})
"""Commands whose parameters Marlin takes as one text (a message, a file name)."""
_PLAIN_COMMAND = re.compile(  # the usual line: words read the same by a blank split
    r"([GMT])([0-9]{1,4})((?: [A-Z](?:[-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+))?)*)")
_STRTOF = re.compile(  # what strtof reads at the start of a value cut at its first E
    r"[-+]?(?:0[xX](?:[0-9a-fA-F]+\.?[0-9a-fA-F]*|\.[0-9a-fA-F]+)(?:[pP][-+]?[0-9]+)?"
    r"|[0-9]+\.?[0-9]*|\.[0-9]+)")
_VALID_FLOAT = re.compile(r"[-+]?\.?[0-9]")  # parser.h valid_float: has the word a value
_VALUE_CHARS = frozenset("0123456789.+-")  # skipped after a parameter (DECIMAL_SIGNED)
_DIGITS = frozenset("0123456789")
CODE_WRAP = 65536  # codenum is a uint16_t


def marlin_words(command: str) -> tuple[str, list[tuple[str, float | None]]]:
    """A command as Marlin reads it: its code (``G1``, ``M104``; ``""`` when Marlin finds no
    G, M or T command) and its parameters in order, each an upper-case letter and the value
    the firmware reads (``None``: the letter alone, as ``G28 X``). See the comment above for
    the reading, after Marlin's ``GCodeParser::parse``.

    ``"M104 S 400"`` → ``("M104", [("S", 400.0)])``; ``"g01x5 y+2."`` →
    ``("G1", [("X", 5.0), ("Y", 2.0)])``; ``"G1 X1E3"`` → ``("G1", [("X", 1.0),
    ("E", 3.0)])``. A repeated letter appears as often as written (Marlin uses the last).
    """
    plain = _PLAIN_COMMAND.fullmatch(command)
    if plain is not None:
        code = plain[1] + str(int(plain[2]))
        if code in MESSAGE_CODES:
            return code, []
        return code, [(w[0], float(w[1:]) if len(w) > 1 else None) for w in plain[3].split()]
    return _parse(queued_line(command))


def queued_line(line: str) -> str:
    """The line as Marlin's command queue keeps it (``process_stream_char``): up to a ``;``
    that no backslash makes plain, each backslash dropped and the character after it kept."""
    if ";" not in line and "\\" not in line:
        return line
    out: list[str] = []
    escaped = False
    for ch in line:
        if escaped:
            out.append(ch)
            escaped = False
        elif ch == "\\":
            escaped = True
        elif ch == ";":
            break
        else:
            out.append(ch)
    return "".join(out)


def _parse(line: str) -> tuple[str, list[tuple[str, float | None]]]:
    """:func:`marlin_words` the long way: character by character, as parse() goes."""
    p = _skip_line_number(line.lstrip(" "))
    letter, p = _upper(p[:1]), p[1:]
    star = p.find("*")
    if star >= 0:
        p = p[:star].rstrip(" ")
    if letter not in ("G", "M", "T"):
        return "", []
    p = p.lstrip(" ")
    end = _run(p, 0, _DIGITS)
    if end == 0:
        return "", []
    code = f"{letter}{int(p[max(0, end - 16):end]) % CODE_WRAP}"  # 10**16 is 0 mod 2**16
    if code in MESSAGE_CODES:
        return code, []
    return code, _parameters(p[end:].lstrip(" "))


def _skip_line_number(p: str) -> str:
    """``N12 G1`` → ``G1``: an ``N``, a digit or ``-``, digits, then spaces."""
    if len(p) < 2 or _upper(p[0]) != "N" or not (p[1] in _DIGITS or p[1] == "-"):
        return p
    return p[_run(p, 2, _DIGITS):].lstrip(" ")


def _parameters(p: str) -> list[tuple[str, float | None]]:
    """The parameter loop of parse() over the text after the code."""
    words: list[tuple[str, float | None]] = []
    i, n = 0, len(p)
    while i < n:
        param = _upper(p[i])
        i += 1
        if "A" <= param <= "Z":
            while i < n and p[i] == " ":
                i += 1
            value, i = _value(p, i)
            words.append((param, value))
        if i < n and not "A" <= p[i] <= "Z":  # not another parameter right away
            i = _run(p, i, _VALUE_CHARS)
            while i < n and p[i] == " ":
                i += 1
    return words


def _value(p: str, i: int) -> tuple[float | None, int]:
    """The value at ``p[i:]`` as value_float() reads it (``None`` if it has none), and where
    the parameter loop goes on: after a quoted value's closing quote, else at ``i``."""
    if p[i:i + 1] == '"':  # GCODE_QUOTED_STRINGS: the value is the text between the quotes
        close = p.find('"', i + 1)
        close = len(p) if close < 0 else close
        return _strtof(p[i + 1:close]), close + 1
    return (_strtof(p[i:]) if _VALID_FLOAT.match(p, i) else None), i


def _strtof(text: str) -> float | None:
    """strtof of ``text`` cut at its first ``E``/``e`` (value_float); ``None`` if no number
    starts it."""
    cut = min((k for k in (text.find("E"), text.find("e")) if k >= 0), default=len(text))
    found = _STRTOF.match(text, 0, cut)
    if found is None:
        return None
    number = found[0]
    if "x" in number or "X" in number:
        return float.fromhex(number)
    return float(number)


def _run(p: str, i: int, chars: frozenset[str]) -> int:
    """The end of the run of ``chars`` starting at ``p[i]``."""
    while i < len(p) and p[i] in chars:
        i += 1
    return i


def _upper(ch: str) -> str:
    """An ASCII letter in upper case (GCODE_CASE_INSENSITIVE); any other character as it is."""
    return chr(ord(ch) - 32) if "a" <= ch <= "z" else ch
