"""The serial protocol as a pure, deterministic state machine: events in, actions out.

No I/O, no clock: every entry point takes ``now`` (seconds, any monotonic origin) and returns
the :mod:`hostd.link.actions` the shell must carry out, in order.

Model
-----
Every line transmitted is answered by exactly one ``ok`` (after execution, or after the
``Error``/``Resend`` pair that rejected it), so the lines in flight form a FIFO that each
``ok`` pops from the head. ``Resend: N`` rewinds transmission to line ``N`` and marks every
line ``>= N`` in flight *void* (the firmware rejects them; their ``ok`` acknowledges nothing).
A resend request caused by a void line, or by one sent before the latest rewind, is a
duplicate and ignored. Two resynchronisations recover from lost ``ok``s: an ``ok N<n>``
(ADVANCED_OK) acknowledges everything up to line ``n``; an ``ok T:…`` answers the oldest
``M105`` in flight, and since the firmware executes in order it acknowledges everything
before it. Acknowledgements are cumulative and never run ahead of the firmware: a lost
``ok`` only delays them.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any, ClassVar

from hostd.link import errors
from hostd.link.actions import Acked, Action, Answer, Connected, Failed, Write
from hostd.link.framing import encode, frame
from hostd.link.observed import Observed
from hostd.link.replies import (
    Banner,
    Busy,
    ErrorReply,
    Halted,
    Ok,
    Reply,
    Resend,
    Wait,
    parse_reply,
)
from hostd.link.settings import LinkSettings
from hostd.link.stats import LinkCounters, RoundTrip
from hostd.link.window import SendWindow

HANDSHAKE = "M110 N0"
NUDGE = "M105"


@dataclass
class _Item:
    command: str
    seq: int | None  # submission order (None for the handshake and nudges)
    kind: str  # line | query | handshake | nudge
    number: int | None = None  # N, given at the first transmission
    data: bytes = b""


@dataclass
class _Sent:
    item: _Item
    epoch: int
    sent_at: float
    void: bool = False
    replies: list[Reply] = field(default_factory=list)


class Protocol:
    """Numbering, checksums, window, resends and timeouts of one connection.

    States: ``disconnected`` → ``handshake`` → ``ready``; ``halted`` after a halt or M112;
    ``lost`` after a timeout. A firmware reset in ``ready`` fails the job and starts a new
    handshake.
    """

    def __init__(self, settings: LinkSettings) -> None:
        self.settings = settings
        self.counters = LinkCounters()
        self.rtt = RoundTrip()
        self.observed = Observed()
        self.state = "disconnected"
        self.window = SendWindow(settings.flow_control, settings.rx_buffer_bytes)
        self._out: list[Action] = []
        self._clear(0.0)

    # -- entry points -------------------------------------------------------------------

    def start(self, now: float) -> list[Action]:
        """Begin (or restart) the connection: forget all lines, send ``N0 M110 N0``."""
        self._restart(now)
        return self._flush()

    def submit(self, command: str, now: float, kind: str = "line") -> tuple[int, list[Action]]:
        """Queue ``command`` (already stripped); returns its submission number ``seq``.

        Submission numbers count from 1 on each connection; acknowledgements
        (:class:`~hostd.link.actions.Acked`) are given in them. The line number ``N`` on the
        wire is chosen at the first transmission. ``kind`` is ``line`` or ``query`` (a
        query's collected replies come back in an :class:`~hostd.link.actions.Answer`).
        """
        if self.state != "ready":
            raise errors.NotConnected(f"link is {self.state}", self.last_acked)
        self._seq += 1
        self._pending.append(_Item(command, self._seq, kind))
        self._pump(now)
        return self._seq, self._flush()

    def receive(self, line: str, now: float) -> list[Action]:
        """Handle one line received from the firmware."""
        reply = parse_reply(line)
        self.observed.update(reply)
        handler = self._handlers.get(type(reply))
        if handler is not None:
            handler(self, reply, now)
        elif self.state == "ready":
            self._collect(reply)
        self._pump(now)
        return self._flush()

    def tick(self, now: float) -> list[Action]:
        """Handle the passage of time: call at (or after) :meth:`deadline`."""
        due = self.deadline()
        if due is not None and now >= due:
            if self.state == "handshake":
                self._handshake_timeout(now)
            elif self.state == "ready":
                self._ok_timeout(now)
        self._pump(now)
        return self._flush()

    def deadline(self) -> float | None:
        """When :meth:`tick` must next be called, or ``None`` if nothing is awaited."""
        if self.state == "handshake":
            return self._progress + self.settings.handshake_timeout
        if self.state == "ready" and self._inflight:
            return self._progress + self.settings.ok_timeout
        return None

    def emergency_stop(self, now: float) -> list[Action]:
        """Send ``M112`` at once, ahead of the window and the queue, and fail the job."""
        self._out.append(Write(encode("M112")))
        self._fail(errors.EmergencyStop("emergency stop (M112) sent", self.last_acked), "halted")
        return self._flush()

    def disconnected(self, reason: str, now: float) -> list[Action]:
        """The port went away: fail everything outstanding."""
        if self.state in ("ready", "handshake"):
            self._fail(errors.LinkLost(f"port lost: {reason}", self.last_acked), "disconnected")
        self.state = "disconnected"
        return self._flush()

    @property
    def last_acked(self) -> int:
        """The highest submission number acknowledged on this connection (0 if none)."""
        return self._acked

    def snapshot(self) -> dict[str, Any]:
        """Plain, JSON-able state for :meth:`SerialLink.status`."""
        return {
            "state": self.state,
            "connected": self.state == "ready",
            **self.observed.as_dict(),
            **self.counters.as_dict(),
            "last_acked": self._acked,
            "window_bytes": self.window.size if self.window.mode == "window" else 0,
            "flow_control": self.window.mode,
            "inflight_lines": len(self._inflight),
            "inflight_bytes": self._bytes,
            "queued_lines": len(self._pending) + len(self._resend),
            "ok_rtt": self.rtt.as_dict(),
        }

    # -- state --------------------------------------------------------------------------

    def _clear(self, now: float) -> None:
        self._next = 1
        self._seq = 0
        self._acked = 0
        self._sent_max = 0
        self._epoch = 0
        self._rewind_target = 0
        self._history: dict[int, _Item] = {}
        self._history_low = 0
        self._pending: deque[_Item] = deque()
        self._resend: deque[_Item] = deque()
        self._inflight: deque[_Sent] = deque()
        self._bytes = 0
        self._after_resend = False
        self._nudged = False
        self._progress = now
        self._attempts = 0
        self._resend_counts: dict[int, int] = {}
        self.window = SendWindow(self.settings.flow_control, self.settings.rx_buffer_bytes)

    def _restart(self, now: float) -> None:
        self._clear(now)
        self.state = "handshake"
        self._attempts = 1
        self._send_handshake(now)

    def _flush(self) -> list[Action]:
        out, self._out = self._out, []
        return out

    def _fail(self, error: errors.LinkError, state: str) -> None:
        self._out.append(Failed(error))
        self._pending.clear()
        self._resend.clear()
        self._inflight.clear()
        self._bytes = 0
        self.state = state

    # -- sending ------------------------------------------------------------------------

    def _send_handshake(self, now: float) -> None:
        item = _Item(HANDSHAKE, None, "handshake", 0, encode(frame(0, HANDSHAKE)))
        self._inflight.clear()
        self._bytes = 0
        self._transmit(item, now)

    def _pump(self, now: float) -> None:
        if self.state != "ready":
            return
        while True:
            queue = self._resend or self._pending
            if not queue:
                return
            item = queue[0]
            if not self.window.fits(len(self._inflight), self._bytes, len(item.data)):
                return
            queue.popleft()
            self._transmit(item, now)

    def _transmit(self, item: _Item, now: float) -> None:
        if item.number is None:
            item.number = self._next
            self._next += 1
            item.data = encode(frame(item.number, item.command))
            self._history[item.number] = item
        if not self._inflight:
            self._progress = now
        self._out.append(Write(item.data))
        self._inflight.append(_Sent(item, self._epoch, now))
        self._bytes += len(item.data)
        if item.kind == "handshake":
            return
        self.counters.lines_sent += 1
        if item.number <= self._sent_max:
            self.counters.lines_resent += 1
        self._sent_max = max(self._sent_max, item.number)

    # -- replies ------------------------------------------------------------------------

    def _on_ok(self, ok: Ok, now: float) -> None:
        if not self._inflight:
            return
        self._progress = now
        self._nudged = False
        if self.state == "handshake":
            self._handshake_ok(now)
            return
        count = self._ok_span(ok)
        self._after_resend = False
        popped = [self._pop() for _ in range(count)]
        self._acknowledge(popped, ok, now)

    def _ok_span(self, ok: Ok) -> int:
        """How many lines in flight this ``ok`` answers (more than one after lost oks)."""
        if ok.temperatures is not None:
            for i, sent in enumerate(self._inflight):
                if not sent.void and sent.item.command.split()[0] == NUDGE:
                    return i + 1
        elif ok.line is not None and not self._after_resend:
            for i, sent in enumerate(self._inflight):
                if not sent.void and sent.item.number == ok.line:
                    return i + 1
        return 1

    def _pop(self) -> _Sent:
        sent = self._inflight.popleft()
        self._bytes -= len(sent.item.data)
        return sent

    def _acknowledge(self, popped: list[_Sent], ok: Ok, now: float) -> None:
        good = [s for s in popped if not s.void and s.item.kind != "handshake"]
        if popped and not popped[-1].void:
            self.rtt.add(now - popped[-1].sent_at)
        if not good:
            return
        self.window.grow()
        for sent in good:
            if sent.item.kind == "query":
                replies = [*sent.replies, ok] if sent is popped[-1] else sent.replies
                self._out.append(Answer(sent.item.seq or 0, tuple(replies)))
        top = max(s.item.seq or 0 for s in good)
        if top > self._acked:
            self.counters.lines_acked += top - self._acked
            self._acked = top
            self._out.append(Acked(top))
        self._forget(max(s.item.number or 0 for s in good))

    def _forget(self, acked: int) -> None:
        limit = acked - self.settings.history_size
        while self._history_low <= limit:
            self._history.pop(self._history_low, None)
            self._history_low += 1
        for n in [n for n in self._resend_counts if n <= acked]:
            del self._resend_counts[n]

    def _on_resend(self, resend: Resend, now: float) -> None:
        self.counters.resend_requests += 1
        self._after_resend = True
        head = self._inflight[0] if self._inflight else None
        if self.state == "handshake":
            if head is not None:
                head.void = True
            return
        if self._is_duplicate(head, resend.line):
            self.counters.duplicate_resends += 1
            return
        self._rewind(resend.line)

    def _is_duplicate(self, head: _Sent | None, line: int) -> bool:
        if line > self._sent_max:
            return True
        if head is None:
            return False
        stale = head.void or head.epoch < self._epoch
        return stale and line >= self._rewind_target

    def _rewind(self, line: int) -> None:
        missing = [n for n in range(line, self._sent_max + 1) if n not in self._history]
        if missing:
            self._fail(errors.HistoryExhausted(
                f"firmware asked for line {line}, no longer in the resend history",
                self._acked), "halted")
            return
        count = self._resend_counts.get(line, 0) + 1
        self._resend_counts[line] = count
        if count > self.settings.resend_limit:
            self._fail(errors.ResendLoop(
                f"firmware asked for line {line} {count} times (limit "
                f"{self.settings.resend_limit}): the link is too noisy", self._acked), "halted")
            return
        self._epoch += 1
        self._rewind_target = line
        for sent in self._inflight:
            if sent.item.number is not None and sent.item.number >= line:
                sent.void = True
        self._resend = deque(self._history[n] for n in range(line, self._sent_max + 1))
        self.window.shrink()

    def _on_error(self, error: ErrorReply, now: float) -> None:
        if error.kind == "checksum":
            self.counters.checksum_errors += 1
        if error.kind != "other":
            self.counters.line_errors += 1
        elif self.state == "ready":
            self._collect(error)

    def _on_busy(self, busy: Busy, now: float) -> None:
        self._progress = now

    def _on_wait(self, wait: Wait, now: float) -> None:
        self.counters.waits += 1

    def _on_halted(self, halted: Halted, now: float) -> None:
        if self.state in ("ready", "handshake"):
            self._fail(errors.FirmwareHalted(f"firmware halted: {halted.text}", self._acked),
                       "halted")

    def _on_banner(self, banner: Banner, now: float) -> None:
        if self.state == "handshake":
            # The board (re)booted while we wait: our M110 may or may not have reached it.
            # Resending now could earn two oks, so give it a full timeout first.
            self._progress = now
            return
        if self.state != "ready":
            return
        self.counters.resets += 1
        self._fail(errors.FirmwareReset(
            f"firmware reset ({banner.text!r}) after line {self._acked}", self._acked),
            "handshake")
        self._restart(now)

    def _collect(self, reply: Reply) -> None:
        for sent in self._inflight:
            if sent.item.kind == "query":
                sent.replies.append(reply)

    # -- timeouts -----------------------------------------------------------------------

    def _handshake_ok(self, now: float) -> None:
        sent = self._pop()
        if sent.void:
            self._send_handshake(now)
            return
        self.state = "ready"
        self._after_resend = False
        self._out.append(Connected())

    def _handshake_timeout(self, now: float) -> None:
        if self._attempts >= self.settings.handshake_attempts:
            self._fail(errors.LinkLost(
                f"no answer to {HANDSHAKE} after {self._attempts} attempts"), "lost")
            return
        self._attempts += 1
        self._send_handshake(now)

    def _ok_timeout(self, now: float) -> None:
        self.counters.timeouts += 1
        if self._nudged:
            self._fail(errors.LinkLost(
                f"no ok for {self.settings.ok_timeout:g} s, even after an {NUDGE} nudge",
                self._acked), "lost")
            return
        self._nudged = True
        self._transmit(_Item(NUDGE, None, "nudge"), now)
        self._progress = now

    _handlers: ClassVar[dict[type, Any]] = {
        Ok: _on_ok, Resend: _on_resend, ErrorReply: _on_error, Busy: _on_busy,
        Wait: _on_wait, Halted: _on_halted, Banner: _on_banner,
    }
