"""A G-code file as the streamer sees it: numbered commands plus the HOSTD markers.

Pure: text in, :class:`Program` out. Markers (``;HOSTD_SUBPART {json}``, ``;HOSTD_LAYER``,
``;HOSTD_ESTIMATE``, ``;HOSTD_TRANSITION`` … ``;HOSTD_TRANSITION_END``; their names, payloads
and parsing in :mod:`slicer.gcode.markers`) are attached to the index of the next command, so
progress, checkpoints and resume points are command indices.
"""

from __future__ import annotations

import bisect
import math
import re
from dataclasses import dataclass, field
from typing import Any

from hostd.link.framing import COMMAND_MAX, CONTROL, MAX_CMD_SIZE, checksum, strip_gcode
from hostd.printer.errors import ProgramError
from hostd.printer.modal import ModalState
from slicer.gcode.markers import (
    ESTIMATE,
    KINEMATICS,
    LAYER,
    PREFIX,
    SUBPART,
    TRANSITION,
    TRANSITION_END,
    PayloadError,
    marlin_words,
    parse_marker,
    parse_payload,
    split_words,
)

MESSAGES = frozenset({"M117", "M118", "M23", "M28", "M30", "M32", "M928"})
"""Commands whose argument is text, not numbers."""
_SCREEN = bytes.maketrans(b"0123456789." + bytes([*range(0, 9), *range(11, 32), 127]),
                          b"#" * 11 + b"\0" * 31)
"""Digits and the point to ``#``, control characters (tab and newline aside) to NUL."""
_MARKS = (b"\0", b"#e", b"nan", b"inf")
_COMMAND = re.compile(r"[GMT][0-9]")  # what a command starts with (strip_gcode upper-cases)
_ODD_LINE = re.compile(r"\n(?![GMTgmt][0-9]|[;\n]|$)")  # a line starting as no command
_ODD_FIRST = re.compile(r"(?![GMTgmt][0-9]|[;\n]|$)")  # does (or with a blank): the first
RESERVED = {"M110": "line numbers are hostd's to set", "M112": "use hostctl estop",
            "M999": "use hostctl firmware-restart"}
"""Commands a file or raw G-code may not send: the link numbers lines itself, and a stop or
a restart of the firmware goes through hostd (the job's state follows)."""
_RESERVED_LINE = re.compile(  # and a code of five digits or more, which may wrap to one
    r"(?:^|\n)(?:[Mm]0*(?:110|112|999)(?![0-9])|[GMTgmt][0-9]{5})")


@dataclass(frozen=True)
class Transition:
    """A rotate/return block: commands ``start`` .. ``end - 1`` move to ``target``."""

    start: int
    end: int
    subpart: int
    parent: int | None
    target: dict[str, float]  # X Y Z A C the block must reach (keys present only)
    source_line: int
    safe_z: float | None = None  # the Z the block lifts to before it turns (its marker's)


@dataclass(frozen=True)
class LayerMark:
    index: int  # first command of the layer
    subpart: int
    layer: int


@dataclass
class Program:
    """Commands (comment-free) with their file line numbers and the marker tables."""

    commands: list[str] = field(default_factory=list)
    source_lines: list[int] = field(default_factory=list)
    layers: list[LayerMark] = field(default_factory=list)
    subparts: dict[int, int] = field(default_factory=dict)  # sub-part → first command index
    parents: dict[int, int | None] = field(default_factory=dict)
    transitions: list[Transition] = field(default_factory=list)
    estimate: dict[str, float] = field(default_factory=dict)
    kinematics: dict[str, Any] = field(default_factory=dict)  # ;HOSTD_KINEMATICS, if any
    _starts: list[int] = field(default_factory=list, repr=False, compare=False)
    _by_start: dict[int, Transition] = field(default_factory=dict, repr=False, compare=False)

    @property
    def total(self) -> int:
        return len(self.commands)

    def transition_at(self, index: int) -> Transition | None:
        """The transition block starting at command ``index`` (a dict look-up per line)."""
        if len(self._by_start) != len(self.transitions):
            self._by_start = {t.start: t for t in self.transitions}
        return self._by_start.get(index)

    @property
    def transition_z(self) -> float | None:
        """The highest machine Z a transition of the file lifts to before it turns the
        platform: the slicer's clearance for the whole part (``None`` without transitions).
        A marker's ``safe_z`` is that lift; where a marker has none, its target Z (the
        approach) is all the file says."""
        return max((z for t in self.transitions for z in (t.safe_z, t.target.get("Z"))
                    if z is not None), default=None)

    def next_transition_start(self, index: int) -> int:
        """The first command after ``index`` that starts a transition block (``total`` if
        none)."""
        return min((t.start for t in self.transitions if t.start > index), default=self.total)

    def layer_at(self, index: int) -> LayerMark | None:
        """The layer that command ``index`` belongs to (``None`` before the first).

        A binary search over the layer starts.
        """
        k = bisect.bisect_right(self._layer_starts(), index)
        return self.layers[k - 1] if k else None

    def next_layer_start(self, index: int) -> int:
        """The first command after ``index`` that starts a layer (``total`` if none): up to
        it, :meth:`layer_at` stays what it is at ``index``."""
        starts = self._layer_starts()
        k = bisect.bisect_right(starts, index)
        return starts[k] if k < len(starts) else self.total

    def _layer_starts(self) -> list[int]:
        if len(self._starts) != len(self.layers):
            self._starts = [mark.index for mark in self.layers]
        return self._starts

    def resume_index(self, index: int, scope: str) -> int:
        """Where to restart when ``index`` was interrupted: start of its ``layer`` or
        ``subpart``, or ``index`` itself for ``line``."""
        if scope == "line":
            return index
        mark = self.layer_at(index)
        if mark is None:
            return 0
        if scope == "layer":
            return mark.index
        if scope == "subpart":
            first = [m.index for m in self.layers if m.subpart == mark.subpart]
            return min(first)
        raise ProgramError(f"unknown resume scope {scope!r} (line, layer or subpart)")

    def modal_before(self, index: int) -> ModalState:
        """The modal state the file leaves before command ``index`` runs."""
        state = ModalState()
        state.apply_many(self.commands[:index])
        return state


def parse_program(text: str) -> Program:
    """Read a G-code file; :class:`ProgramError` for malformed markers."""
    prog = Program()
    open_tr: dict[str, Any] | None = None
    subpart = 0
    check = _needs_line_checks(text)
    for lineno, raw in enumerate(text.splitlines(), 1):
        stripped = raw.strip()
        if stripped.startswith(PREFIX):
            open_tr, subpart = _marker(prog, stripped, lineno, open_tr, subpart)
            continue
        cmd = strip_gcode(raw)
        if cmd is None:
            continue
        if check:
            check_command(cmd, lineno)
            _check_own_checksum(raw, lineno)
        prog.commands.append(cmd)
        prog.source_lines.append(lineno)
    if open_tr is not None:
        raise ProgramError(f"line {open_tr['line']}: HOSTD_TRANSITION without an END")
    _check_lengths(prog)
    return prog


def _check_lengths(prog: Program) -> None:
    """Refuse a command longer than :data:`~hostd.link.framing.COMMAND_MAX` (the firmware
    would truncate it, and its checksum would fail on every resend)."""
    if max(map(len, prog.commands), default=0) <= COMMAND_MAX:
        return
    at = next(i for i, cmd in enumerate(prog.commands) if len(cmd) > COMMAND_MAX)
    cmd = prog.commands[at]
    raise ProgramError(
        f"line {prog.source_lines[at]}: command of {len(cmd)} characters ({cmd[:24]}...) is "
        f"longer than the firmware's line buffer takes ({COMMAND_MAX} with its line number "
        f"and checksum, Marlin MAX_CMD_SIZE {MAX_CMD_SIZE}); comments do not count")


def _marker(prog: Program, text: str, lineno: int, open_tr: dict[str, Any] | None,
            subpart: int) -> tuple[dict[str, Any] | None, int]:
    marker = parse_marker(text)
    if marker is None:  # a comment that only starts like a marker
        return open_tr, subpart
    name, payload = marker
    index = len(prog.commands)
    if name == TRANSITION_END:
        if open_tr is None:
            raise ProgramError(f"line {lineno}: HOSTD_TRANSITION_END without a start")
        prog.transitions.append(Transition(
            open_tr["start"], index, open_tr["to"], open_tr["from"], open_tr["target"],
            open_tr["line"], open_tr["safe_z"]))
        return None, subpart
    data = _json(payload, lineno, name)
    if name == SUBPART:
        subpart = _int(data, "index", lineno)
        prog.subparts.setdefault(subpart, index)
        prog.parents[subpart] = data.get("parent")
    elif name == LAYER:
        subpart = _int(data, "subpart", lineno) if "subpart" in data else subpart
        prog.layers.append(LayerMark(index, subpart, _int(data, "index", lineno)))
    elif name == KINEMATICS:
        prog.kinematics = data
    elif name == ESTIMATE:
        prog.estimate = {k: float(v) for k, v in data.items()
                         if isinstance(v, int | float) and math.isfinite(v)}
    elif name == TRANSITION:
        if open_tr is not None:
            raise ProgramError(f"line {lineno}: nested HOSTD_TRANSITION")
        target = {k.upper(): _number(data, k, lineno) for k in ("x", "y", "z", "a", "c", "X",
                                                                "Y", "Z", "A", "C") if k in data}
        safe_z = _number(data, "safe_z", lineno) if "safe_z" in data else None
        return {"start": index, "to": _int(data, "to", lineno), "from": data.get("from"),
                "target": target, "line": lineno, "safe_z": safe_z}, subpart
    return open_tr, subpart


def _json(payload: str, lineno: int, name: str) -> dict[str, Any]:
    try:
        return parse_payload(payload)
    except PayloadError as exc:
        raise ProgramError(f"line {lineno}: HOSTD_{name}: {exc.reason}") from None


def _number(data: dict[str, Any], key: str, lineno: int) -> float:
    value = data[key]
    if not isinstance(value, int | float) or isinstance(value, bool) or not math.isfinite(value):
        raise ProgramError(f"line {lineno}: marker needs a finite number {key!r}")
    return float(value)


def _needs_line_checks(text: str) -> bool:
    """Whether a command of ``text`` may be one :func:`check_command` refuses: then every
    command gets that closer look (which costs more than the parse). A screen in C passes
    finds what such a command must hold (a control character, ``nan``, ``inf``, a number's
    exponent); only the lines holding one are looked at, alone, and a comment's ``infill`` or
    a header's ``1.3e-16`` spares the rest of the file. Text beyond ASCII is looked at whole
    (``float`` reads other scripts' digits, and ``splitlines`` breaks lines at more than
    ``\\n``)."""
    if (not text.isascii() or _ODD_FIRST.match(text) or _ODD_LINE.search(text)
            or _RESERVED_LINE.search(text)):
        return True  # a line starting as no command does (a comment in parentheses, an N
    data = text.encode("ascii")  # prefix, a stray word): rare in any real file
    screened = data.translate(_SCREEN).lower()
    for mark in _MARKS:
        at = screened.find(mark)
        while at >= 0:
            start = data.rfind(b"\n", 0, at) + 1
            end = data.find(b"\n", at)
            end = len(data) if end < 0 else end
            if not _passes_alone(data[start:end].decode("ascii")):
                return True
            at = screened.find(mark, end)
    return False


def _passes_alone(line: str) -> bool:
    """Whether one line is surely accepted (a control character anywhere in it, also one that
    would split it in two, leaves it to the closer look)."""
    if CONTROL.search(line):
        return False
    cmd = strip_gcode(line)
    if cmd is None:
        return True
    try:
        check_command(cmd, 0)
    except ProgramError:
        return False
    return True


def _check_own_checksum(raw: str, lineno: int) -> None:
    """A line written framed (``N12 G1 X1*34``, a file from another host) must carry its own
    checksum right: a wrong one means the file was damaged (hostd frames lines afresh)."""
    body, star, rest = raw.split(";", 1)[0].strip().partition("*")
    if not star or body[:1] not in ("N", "n"):
        return
    try:
        given = int(rest.strip())
    except ValueError:
        raise ProgramError(f"line {lineno}: checksum {rest.strip()!r} is not a number") from None
    if given != checksum(body):
        raise ProgramError(f"line {lineno}: checksum {given} does not match the line "
                           f"({checksum(body)}): the file is damaged")


def check_command(cmd: str, lineno: int) -> None:
    """Refuse a command a firmware would misread: a control character, a first word that is
    no G/M/T code (``hello``, ``X10``, ``%``), or an argument such as ``X1e400`` or ``Xnan``
    that is no finite number (messages aside: ``M117 info``)."""
    if bad := CONTROL.search(cmd):
        raise ProgramError(f"line {lineno}: control character {bad[0]!r} in {cmd!r}")
    if not _COMMAND.match(cmd):  # a text file, or a word the firmware does not know
        raise ProgramError(f"line {lineno}: {cmd.split()[0][:20]!r} is not a G-code "
                           "command (a G, M or T code and its number)")
    code, words = split_words(cmd)
    if (why := RESERVED.get(marlin_words(cmd)[0])) is not None:  # M0110, M110N0, M65646
        raise ProgramError(f"line {lineno}: {code} is not allowed in a job or raw G-code "
                           f"({why})")
    if code.upper() in MESSAGES:
        return
    for letter, text in words:
        try:
            value = float(text)
        except ValueError:
            continue  # not a number (a file name, a flag): the firmware's to judge
        if not math.isfinite(value):
            raise ProgramError(f"line {lineno}: {letter}{text} is not a finite number")


def _int(data: dict[str, Any], key: str, lineno: int) -> int:
    value = data.get(key)
    if not isinstance(value, int) or isinstance(value, bool):
        raise ProgramError(f"line {lineno}: marker needs an integer {key!r}")
    return value
