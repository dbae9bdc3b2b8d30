"""Line framing of the Marlin serial protocol: ``N<n> <cmd>*<cs>`` with an XOR checksum.

Everything here is pure: no I/O, no clock.
"""

from __future__ import annotations

import re

_COMMENT = re.compile(r"\([^)]*\)")
CONTROL = re.compile(r"[\x00-\x08\x0b-\x1f\x7f]")
"""Control characters, which no firmware takes inside a command (tab aside)."""


FOLD_BYTES = 128  # longest text folded at once; Marlin's lines are at most 96 bytes
MAX_CMD_SIZE = 96  # Marlin's line buffer (Configuration_adv.h), its terminator included
COMMAND_MAX = MAX_CMD_SIZE - 1 - len("N9999999 ") - len("*255")
"""Longest command (82 characters) that still fits the firmware's buffer once framed with a
line number of up to seven digits and its checksum. Marlin drops the characters past its
buffer, so a longer line fails its checksum on every resend and the print stalls."""


def checksum(text: str) -> int:
    """XOR of the bytes of ``text`` (ASCII), as Marlin computes it over ``N<n> <cmd>``.

    Parameters
    ----------
    text
        The framed line up to, not including, the ``*``.

    Returns
    -------
    int
        The checksum, 0..255.
    """
    return xor_bytes(text.encode("ascii", "replace"))


def xor_bytes(data: bytes) -> int:
    """XOR of all of ``data``'s bytes, 0..255.

    The bytes are read as one integer and folded onto themselves, halves first: after the
    folds by 64, 32, ..., 1 bytes, the lowest byte is the XOR of the lowest 128 (the bytes
    above it hold partial sums, masked off). Seven integer operations instead of a Python
    step per byte; a longer text is folded in pieces of 128 bytes.
    """
    cs = 0
    for start in range(0, len(data), FOLD_BYTES):
        x = int.from_bytes(data[start:start + FOLD_BYTES], "little")
        x ^= x >> 512
        x ^= x >> 256
        x ^= x >> 128
        x ^= x >> 64
        x ^= x >> 32
        x ^= x >> 16
        x ^= x >> 8
        cs ^= x & 0xFF
    return cs


def frame(number: int, command: str) -> str:
    """Frame ``command`` as line ``number``: ``N<number> <command>*<checksum>`` (no newline)."""
    body = f"N{number} {command}"
    return f"{body}*{checksum(body)}"


def framed(number: int, command: str) -> bytes:
    """The wire bytes of ``command`` as line ``number``: :func:`frame`, encoded, newline."""
    body = f"N{number} {command}".encode("ascii", "replace")
    return b"%s*%d\n" % (body, xor_bytes(body))


def encode(line: str) -> bytes:
    """The bytes that go on the wire for one framed or raw line, newline included."""
    return line.encode("ascii", "replace") + b"\n"


def strip_gcode(line: str) -> str | None:
    """A G-code line without comments and surrounding blanks, or ``None`` if nothing is left.

    ``;`` comments and ``( ... )`` comments are removed, as are an existing ``N<n>`` prefix and
    ``*<cs>`` suffix (the link numbers lines itself). The command letters are upper-cased.

    Examples
    --------
    >>> strip_gcode("G1 X10 ; move")
    'G1 X10'
    >>> strip_gcode("   ; only a comment") is None
    True
    """
    text = line.split(";", 1)[0]
    text = _COMMENT.sub("", text)
    if "*" in text:
        text = text.split("*", 1)[0]
    text = text.strip()
    if text[:1] in ("N", "n"):
        head, _, rest = text.partition(" ")
        if head[1:].isdigit():
            text = rest.strip()
    if not text:
        return None
    return _upper_command(text)


FREE_TEXT = frozenset({"M23", "M28", "M30", "M32", "M117", "M118", "M928"})
"""Commands whose argument is text (a message, a file name): kept as written."""


def _upper_command(text: str) -> str:
    """Upper-case the command word (``g1`` → ``G1``), and the parameter letters of every
    command but those taking text (:data:`FREE_TEXT`): stock Marlin reads only upper-case
    parameters (``G1 x20`` does not move), while hostd's modal tracker and travel checks
    would take ``x20`` for X20. A tab between words becomes a blank, as Marlin expects."""
    word, *more = text.split(None, 1)
    word = word.upper()
    if not more:
        return word
    rest = more[0]
    if word not in FREE_TEXT:
        if not rest.isupper():  # (the usual line has upper-case letters only)
            rest = rest.upper()
        if "\t" in rest:
            rest = rest.replace("\t", " ")
    return word + " " + rest
