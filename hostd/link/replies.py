"""Parse lines from Marlin-dialect firmware into typed reply events.

:func:`parse_reply` is pure and total: every line gives exactly one event, unknown lines an
:class:`Other`. It accepts the variants different Marlin builds and emulators print: ``ok`` with
or without ``N``/``P``/``B`` fields (ADVANCED_OK) or a temperature report, ``Resend: 12`` and
``rs N12``, ``echo:busy: processing`` and ``busy:``, ``Error:`` texts, ``!!``, temperature
reports with or without blanks around ``/``, ``M114`` positions with A and C, ``M115``
capability lines and the start banner.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

_INT = re.compile(r"-?\d+")
_OK_FIELD = re.compile(r"(?:^|\s)([NPB])(-?\d+)(?=\s|$)")
_HEATER = re.compile(
    r"(?:^|\s)(T\d*|B|C|P|L|R)\s*:\s*(-?\d+(?:\.\d*)?)(?:\s*/\s*(-?\d+(?:\.\d*)?))?")
_POWER = re.compile(r"(?:^|\s)(T\d*|B|C)?@\s*:\s*(-?\d+(?:\.\d*)?)")
_AXIS = re.compile(r"(?:^|\s)([XYZABCUVWE])\s*:\s*(-?\d+(?:\.\d*)?)")
_TEMP_START = re.compile(r"^(?:ok\s+)?T\d*\s*:\s*-?\d|^B\s*:\s*-?\d.*T\d*\s*:")
_KEY = re.compile(r"(?:^|\s)([A-Z][A-Z0-9_]+):")
_WAITING = re.compile(r"(?:^|\s)W\s*:\s*(?:\?|-?\d)")
_HALT_WORDS = ("halted", "kill", "stopped", "m999")


@dataclass(frozen=True)
class HeaterReading:
    """One heater of a temperature report: measured and target °C, PWM power if reported."""

    actual: float
    target: float | None = None
    power: float | None = None


@dataclass(frozen=True)
class Temperatures:
    """A temperature report (``M105`` answer, ``M155`` autoreport, ``M109`` progress).

    ``heaters`` maps ``T``, ``T0``, ``B`` … to their readings. ``waiting``: the report ends
    in Marlin's ``W:`` field (the residency countdown, ``?`` before it starts), which only the
    once-a-second line of an ``M109``/``M190`` wait carries.
    """

    heaters: dict[str, HeaterReading] = field(default_factory=dict)
    waiting: bool = False


@dataclass(frozen=True)
class Ok:
    """``ok``, with the ADVANCED_OK fields and an ``M105`` report when the firmware adds them.

    Attributes
    ----------
    line
        ``N``: the line number of the acknowledged command.
    planner_free
        ``P``: free planner blocks.
    buffer_free
        ``B``: free command-queue slots.
    temperatures
        A temperature report on the same line (``ok T:…``), i.e. the answer to an M105.
    position
        A position on the same line (``ok X:… Y:…``, as some emulators answer M114).
    """

    line: int | None = None
    planner_free: int | None = None
    buffer_free: int | None = None
    temperatures: Temperatures | None = None
    position: Position | None = None


@dataclass(frozen=True)
class Resend:
    """``Resend: N`` or ``rs N``: the firmware wants line ``line`` and all after it again."""

    line: int


@dataclass(frozen=True)
class Busy:
    """``busy:`` / ``echo:busy:``: the firmware is working, do not time out."""

    reason: str


@dataclass(frozen=True)
class Wait:
    """``wait``: the firmware's command queue is empty and it waits for input."""


@dataclass(frozen=True)
class Echo:
    """Informational ``echo:`` text."""

    text: str


@dataclass(frozen=True)
class ErrorReply:
    """An ``Error:`` line that does not stop the firmware.

    ``kind`` is ``checksum``, ``line_number``, ``no_checksum``, ``no_line_number`` or ``other``;
    ``last_line`` is the ``Last Line:`` number when given.
    """

    text: str
    kind: str
    last_line: int | None = None


@dataclass(frozen=True)
class Halted:
    """The firmware stopped (``Error:Printer halted``, ``kill()``, ``!!``): the job fails."""

    text: str


@dataclass(frozen=True)
class Position:
    """An ``M114`` answer: axis letter to position (mm or degrees), before ``Count``."""

    axes: dict[str, float]


@dataclass(frozen=True)
class FirmwareInfo:
    """The ``M115`` line: ``FIRMWARE_NAME:… KEY:value …``."""

    name: str
    fields: dict[str, str]


@dataclass(frozen=True)
class Capability:
    """One ``Cap:NAME:0|1`` line of the ``M115`` answer."""

    name: str
    enabled: bool


@dataclass(frozen=True)
class Banner:
    """The firmware's start banner (``start``, ``Marlin …``): it has (re)booted."""

    text: str


@dataclass(frozen=True)
class Other:
    """Any line not understood."""

    text: str


Reply = (Ok | Resend | Busy | Wait | Echo | ErrorReply | Halted | Temperatures | Position
         | FirmwareInfo | Capability | Banner | Other)


def parse_reply(line: str) -> Reply:
    """Classify one line received from the firmware (without its newline).

    Parameters
    ----------
    line
        The received text; surrounding blanks and ``\\r`` are ignored.

    Returns
    -------
    Reply
        The typed event; :class:`Other` when the line is not recognised.
    """
    text = line.strip()
    if text == "ok":  # by far the most frequent line: no fields to look for
        return PLAIN_OK
    low = text.lower()
    for parser in _PARSERS:
        event = parser(text, low)
        if event is not None:
            return event
    return Other(text)


def _ok(text: str, low: str) -> Ok | None:
    if low != "ok" and not low.startswith("ok ") and not low.startswith("ok:"):
        return None
    rest = text[3:].strip()
    position = _position(rest, rest.lower())
    if position is not None:
        return Ok(position=position)
    temps = parse_temperatures(rest) if _HEATER.search(rest) and "T" in rest else None
    found = {k: int(v) for k, v in _OK_FIELD.findall(rest)} if temps is None else {}
    return Ok(found.get("N"), found.get("P"), found.get("B"), temps)


def _resend(text: str, low: str) -> Resend | None:
    if not (low.startswith("resend") or low.startswith("rs ") or low.startswith("rs:")):
        return None
    number = _INT.search(text.split(":", 1)[-1] if ":" in text else text[2:])
    return Resend(int(number.group())) if number else None


def _halted(text: str, low: str) -> Halted | None:
    if text.startswith("!!"):
        return Halted(text)
    if low.startswith("error") and any(w in low for w in _HALT_WORDS):
        return Halted(text)
    return None


def _error(text: str, low: str) -> ErrorReply | None:
    if not low.startswith("error"):
        return None
    body = text.split(":", 1)[1].strip() if ":" in text else text[5:].strip()
    last = re.search(r"last line\s*:?\s*(-?\d+)", low)
    return ErrorReply(body, _error_kind(low), int(last.group(1)) if last else None)


def _error_kind(low: str) -> str:
    if "checksum mismatch" in low or "wrong checksum" in low:
        return "checksum"
    if "line number is not" in low or "expected line" in low:
        return "line_number"
    if "no checksum" in low or "missing checksum" in low:
        return "no_checksum"
    if "no line number" in low:
        return "no_line_number"
    return "other"


def _busy(text: str, low: str) -> Busy | None:
    for prefix in ("echo:busy:", "busy:"):
        if low.startswith(prefix):
            return Busy(text[len(prefix):].strip())
    return None


def _wait(text: str, low: str) -> Wait | None:
    return Wait() if low == "wait" else None


def _banner(text: str, low: str) -> Banner | None:
    if low == "start" or re.match(r"^(echo:\s*)?marlin[\s_-]", low):
        return Banner(text)
    return None


def _firmware(text: str, low: str) -> FirmwareInfo | Capability | None:
    if text.startswith("Cap:"):
        parts = text[4:].rsplit(":", 1)
        return Capability(parts[0].strip(), len(parts) == 2 and parts[1].strip() == "1")
    if not text.startswith("FIRMWARE_NAME:"):
        return None
    fields = parse_key_values(text)
    return FirmwareInfo(fields.get("FIRMWARE_NAME", ""), fields)


def _echo(text: str, low: str) -> Echo | None:
    return Echo(text[5:].strip()) if low.startswith("echo:") else None


def _position(text: str, low: str) -> Position | None:
    head = text.split("Count", 1)[0]
    if not re.match(r"^X\s*:", head) or "Y" not in head:
        return None
    return Position({k: float(v) for k, v in _AXIS.findall(head)})


def _temperatures(text: str, low: str) -> Temperatures | None:
    return parse_temperatures(text) if _TEMP_START.search(text) else None


PLAIN_OK = Ok()  # the reply every plain ``ok`` parses to (shared: it is frozen)
_ADVANCED_OK_TEXT = re.compile(r"ok N(\d+) P(\d+) B(\d+)\r?")
_ADVANCED_OK_BYTES = re.compile(rb"ok N(\d+) P(\d+) B(\d+)\r?")


def parse_advanced_ok(line: str | bytes) -> Ok | None:
    """Marlin's ADVANCED_OK reply to a numbered line, ``ok N<n> P<p> B<b>`` exactly, in one
    regular-expression match: the :class:`Ok` :func:`parse_reply` gives for it, or ``None``
    for any other line (``parse_reply`` reads every form)."""
    match: re.Match[bytes] | re.Match[str] | None
    if isinstance(line, bytes):
        match = _ADVANCED_OK_BYTES.fullmatch(line)
    else:
        match = _ADVANCED_OK_TEXT.fullmatch(line)
    if match is None:
        return None
    number, planner, slots = match.groups()
    return Ok(int(number), int(planner), int(slots))


_PARSERS = (_ok, _resend, _halted, _error, _busy, _wait, _banner, _firmware, _echo,
            _position, _temperatures)


def parse_temperatures(text: str) -> Temperatures:
    """Parse ``T:210.0 /210.0 B:60.0 /60.0 @:127 B@:0`` (blanks optional) into readings."""
    powers = {(k or "T"): float(v) for k, v in _POWER.findall(text)}
    heaters: dict[str, HeaterReading] = {}
    for name, actual, target in _HEATER.findall(text):
        if name in heaters:
            continue
        heaters[name] = HeaterReading(float(actual), float(target) if target else None,
                                      powers.get(name))
    return Temperatures(heaters, _WAITING.search(text) is not None)


def parse_key_values(text: str) -> dict[str, str]:
    """Split ``KEY:value KEY2:value with blanks`` at upper-case ``KEY:`` words."""
    marks = list(_KEY.finditer(text))
    out: dict[str, str] = {}
    for i, m in enumerate(marks):
        end = marks[i + 1].start() if i + 1 < len(marks) else len(text)
        out[m.group(1)] = text[m.end():end].strip()
    return out
