"""Bookkeeping of the lines sent and not yet answered: window credit and resend epochs."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass


@dataclass(slots=True)
class Item:
    """One command to transmit: its submission number and, once sent, its line number.

    ``data`` is the line framed as number ``framed_as`` (its wire bytes): framed ahead, when
    submitted, with the number it will most likely get; framed again at the first
    transmission if another line took that number meanwhile (a nudge, a new connection).
    """

    command: str
    seq: int | None  # submission order (None for the handshake and nudges)
    kind: str  # line | query | handshake | nudge
    number: int | None = None  # N, given at the first transmission
    data: bytes = b""
    framed_as: int = -1  # the number data was framed with (-1: not framed)


@dataclass(slots=True)
class Sent:
    """One transmission of an item (a resent line is transmitted more than once)."""

    item: Item
    number: int  # the line number on the wire (the item's)
    epoch: int
    sent_at: float
    written: int  # bytes on the wire so far (fewer than the line's while it goes in parts)
    counted: bool = True  # still holds window credit


class InFlight:
    """Transmissions not yet answered by an ``ok``, in transmission order.

    ``bytes`` and ``lines`` count only transmissions that still hold window credit; a line
    going out in parts holds the credit of the bytes written so far.
    """

    def __init__(self) -> None:
        self._entries: deque[Sent] = deque()
        self._ascending = True  # line numbers ascend along _entries (no rewind among them)
        self.bytes = 0
        self.lines = 0

    def __bool__(self) -> bool:
        return bool(self._entries)

    def add(self, sent: Sent) -> None:
        """Record a transmission."""
        entries = self._entries
        if entries and entries[-1].number >= sent.number:
            self._ascending = False
        entries.append(sent)
        self.bytes += sent.written
        self.lines += 1

    def extend(self, sent: Sent, count: int) -> None:
        """``count`` more bytes of the line ``sent`` went out."""
        sent.written += count
        if sent.counted:
            self.bytes += count

    def after_first(self, number: int) -> tuple[int, int]:
        """Lines and bytes holding credit after the first transmission of line ``number``.

        Everything up to that transmission is known to have left the firmware's receive
        buffer; without such a transmission nothing is left out.
        """
        entries = iter(self._entries)
        for sent in entries:
            if sent.number == number:
                rest = [s for s in entries if s.counted]  # the ones after it
                return len(rest), sum(s.written for s in rest)
        return self.lines, self.bytes

    def first_from(self, number: int) -> Sent | None:
        """The oldest transmission of a line numbered ``number`` or higher."""
        for sent in self._entries:
            if sent.number >= number:
                return sent
        return None

    def release_from(self, number: int, keep: Sent | None = None) -> None:
        """Release the credit of the oldest transmission of a line numbered ``number`` or
        higher that still holds it (other than ``keep``); the entry stays."""
        for sent in self._entries:
            if sent.number >= number and sent.counted and sent is not keep:
                self._release(sent)
                return

    def remove(self, sent: Sent) -> None:
        """Forget one transmission (it was answered)."""
        self._entries.remove(sent)
        self._release(sent)

    def drop_through(self, number: int) -> Sent | None:
        """Forget every transmission of lines up to ``number`` (they have been executed);
        returns the latest transmission of ``number`` itself, if any."""
        entries = self._entries
        if self._ascending:  # the lines to forget are at the front
            latest = None
            while entries and entries[0].number <= number:
                latest = entries.popleft()
                self._release(latest)
            return latest if latest is not None and latest.number == number else None
        keep: deque[Sent] = deque()
        latest = None
        for sent in self._entries:
            if sent.number > number:
                keep.append(sent)
                continue
            if sent.number == number:
                latest = sent
            if sent.counted:
                sent.counted = False
                self.bytes -= sent.written
                self.lines -= 1
        self._entries = keep
        numbers = [s.number for s in keep]
        self._ascending = numbers == sorted(set(numbers))
        return latest

    def pop_run(self, first: int, last: int) -> list[Sent] | None:
        """:meth:`drop_through` of ``first``, then of each line up to ``last``, in one step:
        the transmissions of lines ``first`` .. ``last`` that each of those calls would
        return, in order. Only while the line numbers ascend (else ``None``, nothing done)."""
        if not self._ascending:
            return None
        entries = self._entries
        out = []
        while entries and entries[0].number <= last:
            sent = entries.popleft()
            if sent.counted:
                sent.counted = False
                self.bytes -= sent.written
                self.lines -= 1
            if sent.number >= first:
                out.append(sent)
        return out

    def uncount(self, keep: Sent | None = None) -> None:
        """Release the credit of every transmission but ``keep`` (the firmware's buffer is
        known empty of every line it had whole)."""
        for sent in self._entries:
            if sent is not keep:
                sent.counted = False
        self.bytes = self.lines = 0
        if keep is not None and keep.counted and any(s is keep for s in self._entries):
            self.bytes, self.lines = keep.written, 1

    def clear(self) -> None:
        """Forget everything."""
        self._entries.clear()
        self._ascending = True
        self.bytes = 0
        self.lines = 0

    def _release(self, sent: Sent) -> None:
        if sent.counted:
            sent.counted = False
            self.bytes -= sent.written
            self.lines -= 1
