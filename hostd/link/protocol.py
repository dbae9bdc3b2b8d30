"""The serial protocol as a pure, deterministic state machine: events in, actions out.

No I/O, no clock: every entry point takes ``now`` (seconds, any monotonic origin) and returns
the :mod:`hostd.link.actions` the shell must carry out, in order.

Model
-----
Marlin accepts numbered lines strictly in sequence and executes them in that order, so the
``i``-th *success* ``ok`` after ``M110 N0`` means line ``i`` has been executed. A line it
rejects (bad checksum, wrong number) is answered at once, out of order, by ``Error:``,
``Resend: k`` and an *error* ``ok``; the ``ok`` right after a resend request is that error
``ok``. So:

- acknowledgements count success ``ok``s along the line numbers (conservative: a lost ``ok``
  delays them, never advances them); ``ok N<n>`` (ADVANCED_OK) and ``ok T:`` (the answer to
  a numbered ``M105``, executed in order) resynchronise the count after lost ``ok``s;
- ``Resend: k`` rewinds transmission, after a *drain*: nothing new goes out until every
  transmission holding credit has had its answer (an ``ok``, or an error ``ok``; those sent
  before a timeout were answered or their answers lost), so that the ``ok`` s counted then
  say exactly which lines the firmware took. A drain that an ``ok`` lost on the wire leaves
  short ends at the ok timeout: the request is taken as it came (an ``M110`` is sent again).
  Every line before ``k`` taken (Marlin's case): transmission goes on from ``k``. A request
  for a line not yet sent, or out of step with the lines taken (a firmware whose count of
  lines slipped, as OctoPrint's virtual printer's does after the lines a window had in
  flight were refused): the numbering is resynchronised with ``N<e> M110 N<e>``, ``e`` the
  last line taken, sent alone, and transmission goes on from ``e + 1`` once it is answered.
  So it is too when the firmware refused more than the one line it asked for (the lines a
  window had in flight after it): a firmware that counts those as received (OctoPrint's
  virtual printer) would ask for a line ahead at its next error; ``M110`` sets its count
  back. Requests during the drain are answers to it, not new ones; a loop guard counts
  rewinds per line;
- window credit is the bytes of transmissions not yet answered: a success ``ok`` frees every
  transmission of the lines it executed, an error ``ok`` the oldest transmission at or after
  ``k`` (the one rejected), and after a whole timeout of silence all credit is released but
  a line's going out in parts (an error ``ok`` after that also frees a line sent since: see
  ``_error_ok``);
- with ADVANCED_OK, lines waiting in the firmware's command queue no longer use its receive
  buffer. Marlin sends ``ok N<k> P<p> B<b>`` after processing line ``k`` while ``k`` still
  holds its queue slot, so ``BUFSIZE - b`` slots hold ``k`` and the ``BUFSIZE - b - 1`` lines
  after it. The host does not know ``BUFSIZE``; the largest ``B`` seen on such an ``ok`` is at
  most ``BUFSIZE - 1``, so ``k + max B - b`` never exceeds the last line the main loop has
  read out of the receive buffer. The receive buffer is a FIFO, so every transmission up to
  the first transmission of that line has left it too (the accepted one is that one or a
  later one). That bound only grows: between two ``ok`` s the firmware can only read more,
  so a stale bound errs on the safe side. Error ``ok`` s (their fields, when old firmware
  adds any, describe no processed line) and plain ``ok`` s teach nothing, and without
  ADVANCED_OK the credit stays within the receive buffer alone;
- on a timeout the next line (or a numbered ``M105``) is sent as a nudge; a second timeout
  without any ``ok`` declares the link lost. ``busy:`` and the temperature line an ``M109``
  or ``M190`` prints each second while it waits (``W:``) put the timeout off.

Starved: a lost ``ok`` leaves one line counted in flight that the firmware has executed, so
the credit is short by that line's bytes. With long lines that is enough for the next line to
wait for credit, or go out only in part while the firmware, having executed everything it got
whole, waits in silence for the rest: nothing would move until the timeout. So when lines
wait for credit and ``starve_timeout`` passes without progress (an ``ok``, ``busy:``, ``W:``),
the link nudges without releasing any credit (the firmware may be busy rather than idle, a
long move with the planner full, its receive buffer then really as full as counted):

- a line going out in parts is finished past the credit, then an ``M105`` follows, whose
  ``ok T:`` resynchronises the count. A line in parts that is itself an ``M105`` needs no
  other, nor does one finishing a resend (a new number would be out of turn);
- with no line in parts (whole lines only, ping-pong) an ``M105`` goes out past the credit,
  or the next line of a resend under way.

What goes past the credit is at most what a busy firmware's buffer surely has free: the
oldest line counted in flight has been read out of it (every line before it was answered, so
it is in the command queue, or executed and its ``ok`` lost). If the rest of the line in
parts does not fit, nothing goes out and the timeout follows as before; if the ``M105`` after
it does not, it goes first in the queue, in credit (the ``ok`` of the finished line frees
what it needs). While an ``M105`` sent is still to be answered no other is sent (were its
``ok T:`` lost, each new one's would be taken for the one before's, a stall at every line):
the next line goes instead, or nothing.

One such nudge per stretch: the next waits for an ``ok`` (a keepalive every 2 s during a long
command would otherwise bring one each time). It is no step towards a lost link: the
timeout's clock and its nudge count are untouched. A long move (over ``starve_timeout`` while
lines wait) is nudged too: one ``M105`` more in the stream.

Lines in parts (``partial_lines``, window mode)
-----------------------------------------------
The receive buffer holds bytes, not lines, so when the credit is short of the next line its
first part goes out at once and the rest follows as answers free credit (character counting,
as Grbl's streaming protocol). The part written holds credit like a whole line; the firmware
acts only on complete lines, so nothing else goes on the wire until the line is whole:

- it counts as transmitted (history, line number, epoch) from its first byte. A ``Resend: k``
  always names a line before it (the firmware has not seen it whole), so the rewind replays
  ``k`` up to and including it *after* its rest has gone out: the finished old copy is then
  rejected like every other line of the old epoch, and its ``Resend`` is a duplicate;
- no ``ok`` can be for it or a later line, nor can ``ok N.. B..`` show it read out, until it
  is whole;
- a timeout releases all credit but its own: the rest goes out, then the ``M105`` nudge (an
  ``M105`` going out in parts is answered before the nudge, so the first ``ok T:`` is its
  own). Its answer is still to come: with its credit released, the error ``ok`` rejecting it
  would be taken for a line sent since, and a drain would end one answer early, taking the
  last answer for the ``M110``'s and running the acknowledgements one line ahead. If the
  firmware swallowed it (a board fallen silent), the drain ends at the next timeout;
- ``M112`` goes out right after the rest of the line. Ending the line early with a newline
  would be a byte or two faster, but it puts a truncated line in front of the firmware and
  relies on every dialect rejecting it (Marlin does: a prefix of a numbered line has no
  valid checksum); the finished line is one the firmware expects anyway;
- after a firmware reset (or a lost port) the rest is dropped, never sent: the rebooted board
  must not get the tail of an old line, which without its ``N`` and with its ``*`` cut off
  could pass as a command. A prefix that reached the new board joins the ``M110`` handshake
  into one line with a ``*`` and no valid number or checksum, which is rejected, and the
  handshake timeout sends ``M110`` again;
- when it is the only line holding credit, the rest goes out whatever the window (the
  firmware has answered everything before it, so its main loop is reading): as a whole line
  longer than the window goes out when nothing else is in flight.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from typing import Any, ClassVar

from hostd.link import errors
from hostd.link.actions import Acked, Action, Answer, Connected, Failed, Notice, Write
from hostd.link.framing import encode, framed
from hostd.link.inflight import InFlight, Item, Sent
from hostd.link.observed import Observed
from hostd.link.replies import (
    PLAIN_OK,
    Banner,
    Busy,
    ErrorReply,
    Halted,
    Ok,
    Reply,
    Resend,
    Temperatures,
    Wait,
    parse_advanced_ok,
    parse_reply,
)
from hostd.link.settings import LinkSettings
from hostd.link.stats import LinkCounters, RoundTrip
from hostd.link.window import SendWindow

HANDSHAKE = "M110 N0"
# received lines that parse to PLAIN_OK, as texts and as the bytes the port gives
_PLAIN_OK = frozenset(("ok", "ok\r", b"ok", b"ok\r"))
NUDGE = "M105"


class Protocol:
    """Numbering, checksums, window, resends and timeouts of one connection.

    States: ``disconnected`` → ``handshake`` → ``ready``; ``halted`` after a halt or M112;
    ``lost`` after a timeout. A firmware reset in ``ready`` fails the job and starts a new
    handshake.
    """

    _seq: int  # the submission number of the last line submitted (0 after _clear)
    _pending: deque[Item]  # submitted, not yet sent (in order; a withdraw takes some back)

    def __init__(self, settings: LinkSettings) -> None:
        self.settings = settings
        self.counters = LinkCounters()
        self.rtt = RoundTrip()
        self.observed = Observed()
        self.state = "disconnected"
        self.window = SendWindow(settings.flow_control, settings.rx_buffer_bytes)
        self._out: list[Action] = []
        # the wait before a starve nudge; 0: off (one at or after the ok timeout never comes)
        self._starve_timeout = settings.starve_timeout \
            if settings.starve_timeout < settings.ok_timeout else 0.0
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
        number = self._next + len(self._pending)  # its number if nothing else takes one
        self._pending.append(Item(command, self._seq, kind, None, framed(number, command),
                                  number))
        if len(self._pending) == 1 and not self._resend:
            # only a new head can go out: the lines ahead of it already wait for credit,
            # which only replies and time give back (and both pump)
            self._pump(now)
        return self._seq, self._flush()

    def submit_many(self, commands: Sequence[str], now: float) -> tuple[int, list[Action]]:
        """:meth:`submit` each of ``commands`` (lines, at least one) in order; returns the
        submission number of the first (the others follow it)."""
        if self.state != "ready":
            raise errors.NotConnected(f"link is {self.state}", self.last_acked)
        first = self._seq + 1
        pending = self._pending
        idle = not pending and not self._resend
        # framed here, in one loop, rather than one or two at a time as replies free credit
        number = self._next + len(pending) - first
        for seq, command in enumerate(commands, first):
            pending.append(Item(command, seq, "line", None, framed(number + seq, command),
                                number + seq))
        self._seq = first + len(commands) - 1
        if idle:
            self._pump(now)
        return first, self._flush()

    def withdraw(self, first: int, last: int) -> int:
        """Take back the lines submitted as ``first`` .. ``last`` that no byte of has gone
        out yet; returns how many (they are the last ones of the range: lines go out in
        order). They will never be acknowledged; the lines after them are numbered on the
        wire as if they had never been submitted. Queries and nudges are never taken back,
        nor a line already sent (or going out in parts), which the firmware may execute or
        ask for again."""
        pending = self._pending
        kept = deque(item for item in pending
                     if item.kind != "line" or item.seq is None or not first <= item.seq <= last)
        taken = len(pending) - len(kept)
        if taken:
            self._pending = kept
            self.counters.lines_withdrawn += taken
        return taken

    def receive(self, line: str, now: float) -> list[Action]:
        """Handle one line received from the firmware."""
        return self.receive_lines([line], now)

    def receive_lines(self, lines: Sequence[str | bytes], now: float) -> list[Action]:
        """Handle lines received together; the lines they free go out after all of them.

        Lines may be texts or the bytes read from the port (without the newline, decoded
        here as ASCII with replacement characters: plain ``ok`` s need no decoding).
        """
        self.counters.reads += 1
        run: list[Ok] = []  # oks not handled yet, each executing the next line: nine in ten
        for line in lines:
            if self.state == "ready" and self._after_resend is None and self._resync is None:
                if line in _PLAIN_OK:
                    run.append(PLAIN_OK)
                    continue
                ok = parse_advanced_ok(line)
                if ok is not None and ok.line == self._executed + len(run) + 1 \
                        and ok.line <= self._whole_max():
                    run.append(ok)
                    continue
            if run:
                self._ok_run(run, now)
                run = []
            if isinstance(line, bytes):
                line = line.decode("ascii", "replace")
            reply = parse_reply(line)
            self.observed.update(reply)
            handler = self._handlers.get(type(reply))
            if handler is not None:
                handler(self, reply, now)
            elif self.state == "ready":
                self._collect(reply)
        if run:
            self._ok_run(run, now)
        self._pump(now)
        return self._flush()

    def tick(self, now: float) -> list[Action]:
        """Handle the passage of time: call at (or after) :meth:`deadline`."""
        due = self.deadline()
        if due is not None and now >= due:
            if self.state == "handshake":
                self._handshake_timeout(now)
            elif self.state == "ready":
                if now >= self._progress + self.settings.ok_timeout:
                    self._ok_timeout(now)
                else:  # the earlier deadline is the starve nudge's
                    self._starve_nudge(now)
        self._pump(now)
        return self._flush()

    def deadline(self) -> float | None:
        """When :meth:`tick` must next be called, or ``None`` if nothing is awaited."""
        if self.state == "handshake":
            return self._progress + self.settings.handshake_timeout
        if self.state == "ready" and (self._sent_max > self._executed or self._inflight
                                      or self._resync is not None):
            if self._starve_wait and self._resync is None and (
                    self._partial is not None or self._pending or self._resend):
                return self._progress + self._starve_wait  # lines wait for credit: "Starved"
            return self._progress + self.settings.ok_timeout
        return None

    def emergency_stop(self, now: float) -> list[Action]:
        """Send ``M112`` at once, ahead of the window and the queue, and fail the job.

        A line going out in parts is finished first (see the module docstring).
        """
        self._halt_board()
        self._fail(errors.EmergencyStop("emergency stop (M112) sent", self.last_acked), "halted")
        return self._flush()

    def _halt_board(self) -> None:
        """``M112`` now, past the window: the board stops with its heaters off. Sent too when
        the host gives the link up as too noisy to go on, so that a board the host can no
        longer drive is not left heating (``halted``: a firmware restart brings it back)."""
        self._finish_partial()
        self._out.append(Write(encode("M112")))

    def disconnected(self, reason: str, now: float) -> list[Action]:
        """The port went away: fail everything outstanding."""
        if self.state in ("ready", "handshake"):
            self._fail(errors.LinkLost(f"port lost: {reason}", self.last_acked), "disconnected")
        self.state = "disconnected"
        return self._flush()

    @property
    def inflight_bytes(self) -> int:
        """Bytes of the transmissions not yet answered that still hold credit."""
        return self._inflight.bytes

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
            "last_executed_line": self._executed,
            "window_bytes": self.window.size if self.window.mode == "window" else 0,
            "flow_control": self.window.mode,
            "inflight_lines": self._inflight.lines,
            "inflight_bytes": self.inflight_bytes,
            "queued_lines": len(self._pending) + len(self._resend),
            "ok_rtt": self.rtt.as_dict(),
        }

    # -- state --------------------------------------------------------------------------

    def _clear(self, now: float) -> None:
        self._next = 0
        self._seq = 0
        self._acked = 0
        self._acked_number = 0
        self._executed = 0
        self._sent_max = 0
        self._epoch = 0
        self._rewind_target = 0
        self._resync: str | None = None  # "drain", then "m110" (sent, awaiting its ok)
        self._drain_left = 0  # answers the drain still waits for
        self._drain_refused = 0  # error oks among them
        self._resync_line = 0  # the line the firmware asked for
        self._resync_sent = 0  # M110s sent for this resync
        self._history: dict[int, Item] = {}
        self._history_low = 0
        self._pending = deque()
        self._resend: deque[Item] = deque()
        self._inflight = InFlight()
        self._partial: Sent | None = None  # the line going out in parts, if any
        self._after_resend: int | None = None
        self._nudged = 0
        self._starve_wait = self._starve_timeout  # 0 once a nudge went out, until an ok
        self._progress = now
        self._attempts = 0
        self._resend_counts: dict[int, int] = {}
        self._since_ok: list[Reply] = []
        self._m105: deque[int] = deque()  # M105 transmissions awaiting their ok T:
        self._slots_seen = 0  # largest B of a success ok: at most BUFSIZE - 1
        self._read_through = 0  # lines up to this one have left the firmware's receive buffer
        self.window = SendWindow(self.settings.flow_control, self.settings.rx_buffer_bytes)

    def _restart(self, now: float) -> None:
        self._clear(now)
        self.observed.forget_machine()  # a board that (re)starts has its heaters off
        self.state = "handshake"
        self._attempts = 1
        self._send_handshake(now)

    def _flush(self) -> list[Action]:
        out, self._out = self._out, []
        return out

    def _fail(self, error: errors.LinkError, state: str) -> None:
        self._out.append(Failed(error))
        self.observed.forget_machine()  # halted (heaters off), reset, or out of reach
        self._pending.clear()
        self._resend.clear()
        self._inflight.clear()
        self._partial = None  # its rest is never sent (see the module docstring)
        self.state = state

    # -- sending ------------------------------------------------------------------------

    def _send_handshake(self, now: float) -> None:
        self._inflight.clear()
        self._after_resend = None
        self._next = 0
        self._transmit(Item(HANDSHAKE, None, "handshake"), now)

    def _pump(self, now: float) -> None:
        if self.state != "ready":
            return
        # lines and bytes that may still be in the firmware's receive buffer; every
        # transmission below adds one line and its bytes
        if self._read_through > self._executed:
            lines, nbytes = self._inflight.after_first(self._read_through)
        else:
            lines, nbytes = self._inflight.lines, self._inflight.bytes
        if self._partial is not None:
            nbytes += self._continue_partial(lines, nbytes)
            if self._partial is not None:
                return
        if self._resync is not None:
            return  # nothing new goes out until the firmware's count is known
        credit = self.window.credit()  # the window does not change while it pumps
        while True:
            queue = self._resend or self._pending
            if not queue:
                return
            item = queue[0]
            if item.number is None and item.framed_as != self._next:
                self._frame(item)
            if lines and nbytes + len(item.data) > credit:
                room = credit - nbytes if self.settings.partial_lines else 0
                if room <= 0:
                    return
                queue.popleft()
                nbytes += self._transmit(item, now, room)  # framed, it may fit whole
                if self._partial is not None:
                    return
            else:
                queue.popleft()
                nbytes += self._transmit(item, now)
            lines += 1

    def _transmit(self, item: Item, now: float, room: int | None = None) -> int:
        """Write ``item`` (only its first ``room`` bytes if the whole line is longer);
        returns the bytes written."""
        number = item.number
        if number is None:
            if item.framed_as != self._next:
                self._frame(item)
            number = item.number = self._next
            self._next += 1
            self._history[number] = item
        if self._sent_max <= self._executed and not self._inflight:
            self._progress = now
        data = item.data
        sent = Sent(item, number, self._epoch, now, len(data))
        if room is not None and room < sent.written:
            data = data[:room]
            sent.written = room
            self._partial = sent
            self.counters.lines_split += 1
        self._out.append(Write(data))
        self._inflight.add(sent)
        if item.command[:4] == NUDGE and _is_m105(item.command):
            self._m105.append(number)
        if item.kind == "handshake":
            return sent.written
        self.counters.lines_sent += 1
        if number <= self._sent_max:
            self.counters.lines_resent += 1
        self._sent_max = max(self._sent_max, number)
        return sent.written

    def _frame(self, item: Item) -> None:
        """Frame ``item`` as the next line number (the one framed ahead was taken)."""
        item.data = framed(self._next, item.command)
        item.framed_as = self._next

    def _continue_partial(self, lines: int, nbytes: int) -> int:
        """Write what the credit (``lines`` and ``nbytes`` used) allows of the line going out
        in parts; returns the credit that took."""
        sent = self._partial
        assert sent is not None
        data = sent.item.data
        start = sent.written
        count = len(data) - start
        if sent.counted and lines > 1:  # else it alone holds credit: the rest goes out
            count = min(count, self.window.room(nbytes))
        if count <= 0:
            return 0
        self._out.append(Write(data[start:start + count]))
        self._inflight.extend(sent, count)
        if start + count == len(data):
            self._partial = None
        return count if sent.counted else 0

    def _finish_partial(self) -> None:
        """Write the rest of the line going out in parts, whatever the credit."""
        sent = self._partial
        if sent is not None:
            self._out.append(Write(sent.item.data[sent.written:]))
            self._inflight.extend(sent, len(sent.item.data) - sent.written)
            self._partial = None

    def _whole_max(self) -> int:
        """The highest line number the firmware may have received whole (and so executed)."""
        return self._sent_max if self._partial is None else self._partial.number - 1

    # -- ok -----------------------------------------------------------------------------

    def _on_ok(self, ok: Ok, now: float) -> None:
        self._progress = now
        self._nudged = 0
        self._starve_wait = self._starve_timeout
        if self.state == "handshake":
            self._handshake_ok(now)
            return
        if self._resync is not None:
            self._resync_ok(ok, now)
            return
        if self._after_resend is not None:
            self._error_ok(self._after_resend)
            self._after_resend = None
            return
        if ok.line is not None and ok.buffer_free is not None:
            self._note_queue(ok.line, ok.buffer_free)
        line = self._executed_by(ok)
        if line <= self._executed:
            return
        self._execute_through(line, ok, now)

    def _error_ok(self, line: int) -> None:
        """The error ``ok`` after ``Resend: line`` answers the oldest transmission of ``line``
        or later, the one rejected (not a line going out in parts: not seen whole).

        If a timeout already released that transmission's credit, the firmware had answered
        everything sent before the timeout or lost the answers, so the rejection is of a line
        sent since: the credit of the oldest such is released too (the entries stay as they
        are, for telling duplicate requests apart)."""
        rejected = self._inflight.first_from(line)
        if rejected is None or rejected is self._partial:
            return
        released = not rejected.counted
        self._inflight.remove(rejected)
        if released:
            self._inflight.release_from(line, keep=self._partial)

    def _ok_run(self, oks: list[Ok], now: float) -> None:
        """:meth:`_on_ok` for a run of ``oks`` in a row, in ``ready`` with no resend pending,
        each executing the next line sent whole, if any: plain ``ok`` s, and ADVANCED_OK's
        ``ok N<n> P<p> B<b>`` numbered in sequence (``receive_lines`` checks ``n``).

        The short path of the daemon's every read. While the transmissions are in line order
        and no reply came since the last ``ok``, the lines are executed in one step that
        leaves what one :meth:`_execute_through` per ``ok`` would: the round trip of each
        line, the window grown once per line, every query answered and the acknowledgements
        in the same order (a run of lines acknowledged at once, as by ``ok N``).
        """
        self._progress = now
        self._nudged = 0
        self._starve_wait = self._starve_timeout
        for ok in oks:
            if ok.line is not None and ok.buffer_free is not None:  # in order, as _on_ok
                self.observed.update(ok)
                self._note_queue(ok.line, ok.buffer_free)
        first = self._executed + 1
        line = min(self._executed + len(oks), self._whole_max())
        if line < first:
            return
        sents = None if self._since_ok else self._inflight.pop_run(first, line)
        if sents is None:
            for number in range(first, line + 1):
                self._execute_through(number, oks[number - first], now)
            return
        if sents:
            self.rtt.add_many([now - sent.sent_at for sent in sents])
        self._executed = line
        self.window.grow(line - first + 1)
        self._ack_run(first, line, oks)
        self._trim(line)

    def _ack_run(self, first: int, line: int, oks: list[Ok]) -> None:
        """Answer the queries among lines ``first`` .. ``line`` (each executed by its ok in
        ``oks``, no reply before it) and acknowledge them all, in :meth:`_execute_through`'s
        order."""
        history = self._history
        seq = 0
        for number in range(first, line + 1):
            item = history.get(number)
            if item is not None and item.seq is not None:
                if item.kind == "query":
                    self._ack(seq)
                    self._out.append(Answer(item.seq, (oks[number - first],)))
                seq = item.seq
        self._ack(seq)

    def _note_queue(self, line: int, free: int) -> None:
        """ADVANCED_OK ``ok N<line> B<free>``: see the module docstring for why it is sound."""
        self._slots_seen = max(self._slots_seen, free)
        # never beyond the lines sent: a later first transmission would be counted as read
        queued = min(line + self._slots_seen - free, self._whole_max())
        self._read_through = max(self._read_through, queued)

    def _executed_by(self, ok: Ok) -> int:
        """The line number this success ``ok`` shows executed."""
        # not the line going out in parts, nor any later one (see _whole_max)
        limit = self._sent_max if self._partial is None else self._partial.number - 1
        if ok.line is not None:
            return ok.line if self._executed < ok.line <= limit else self._executed
        if ok.temperatures is not None:
            while self._m105 and self._m105[0] <= self._executed:
                self._m105.popleft()
            if self._m105 and self._m105[0] <= limit:
                return self._m105.popleft()
        return min(self._executed + 1, limit)

    def _execute_through(self, line: int, ok: Ok, now: float) -> None:
        sent = self._inflight.drop_through(line)
        if sent is not None:
            self.rtt.add(now - sent.sent_at)
        first = self._executed + 1
        self._executed = line
        self.window.grow()
        if first == line:  # one line, as every plain ok: no loops
            item = self._history.get(line)
            if item is not None and item.seq is not None:
                if item.kind == "query":
                    self._out.append(Answer(item.seq, (*self._since_ok, ok)))
                self._ack(item.seq)
        else:
            self._answer_queries(first, line, ok)
            self._advance_ack(first, line)
        if self._since_ok:
            self._since_ok = []
        self._trim(line)

    def _answer_queries(self, first: int, line: int, ok: Ok) -> None:
        """An :class:`Answer` for each query among lines ``first`` .. ``line``.

        One ``ok`` executed them all, so which reply since the last ``ok`` answered which
        query is unknown: each gets them all and the ``ok`` (a query's ``ok T:`` can arrive
        after a timeout's nudge was sent, and then executes the nudge's line too)."""
        replies = (*self._since_ok, ok)
        for number in range(first, line + 1):
            item = self._history.get(number)
            if item is not None and item.kind == "query" and item.seq is not None:
                self._out.append(Answer(item.seq, replies))

    def _advance_ack(self, first: int, line: int) -> None:
        for number in range(line, first - 1, -1):
            item = self._history.get(number)
            if item is not None and item.seq is not None:
                self._ack(item.seq)
                return

    def _ack(self, seq: int) -> None:
        """Every submission up to ``seq`` is acknowledged."""
        if seq > self._acked:
            self.counters.lines_acked += seq - self._acked
            self._acked = seq
            self._out.append(Acked(seq))

    def _trim(self, executed: int) -> None:
        """Trim the history back to ``history_size`` lines, an eighth of it at a time."""
        if (executed - self.settings.history_size - self._history_low
                >= self.settings.history_size >> 3) or self._resend_counts:
            self._forget(executed)

    def _forget(self, executed: int) -> None:
        limit = executed - self.settings.history_size
        while self._history_low <= limit:
            self._history.pop(self._history_low, None)
            self._history_low += 1
        if self._resend_counts:
            for n in [n for n in self._resend_counts if n <= executed]:
                del self._resend_counts[n]

    # -- resend -------------------------------------------------------------------------

    def _on_resend(self, resend: Resend, now: float) -> None:
        self.counters.resend_requests += 1
        self._after_resend = resend.line
        if self.state != "ready":
            return
        if self._resync is not None:  # during a drain: an answer to a line it waits for
            self.counters.duplicate_resends += 1
            return
        if self._is_duplicate(resend.line):
            self.counters.duplicate_resends += 1
            return
        self._rewind(resend.line)

    def _is_duplicate(self, line: int) -> bool:
        if line > self._sent_max:
            return False  # a line never sent: the firmware's count is out of step
        rejected = self._inflight.first_from(line)
        if rejected is None:
            return False
        return rejected.epoch < self._epoch and line >= self._rewind_target

    def _rewind(self, line: int) -> None:
        missing = [n for n in range(min(line, self._executed + 1), self._sent_max + 1)
                   if n not in self._history]
        if missing:
            self._halt_board()
            self._fail(errors.HistoryExhausted(
                f"firmware asked for line {line}, no longer in the resend history",
                self._acked), "halted")
            return
        count = self._resend_counts.get(line, 0) + 1
        self._resend_counts[line] = count
        if count > self.settings.resend_limit:
            self._halt_board()
            self._fail(errors.ResendLoop(
                f"firmware asked for line {line} {count} times (limit "
                f"{self.settings.resend_limit}): the link is too noisy", self._acked), "halted")
            return
        self._epoch += 1
        self._rewind_target = line
        self._out.append(Notice("resend", f"firmware asked for line {line} again: resending "
                                f"{max(self._sent_max - line + 1, 1)} line(s)"))
        self._resend = deque()
        self._resync, self._resync_line, self._resync_sent = "drain", line, 0
        # the answers still to come: of the transmissions holding credit (those sent before
        # a timeout were answered, or their answers lost), the request's own error ok first
        self._drain_left = self._inflight.lines
        self._drain_refused = 0
        self.window.shrink()

    # -- resync: the drain, and M110 when the firmware's count is out of step -------------

    def _resync_ok(self, ok: Ok, now: float) -> None:
        """An ``ok`` during a resync: an answer the drain counts, or the M110's."""
        refused, self._after_resend = self._after_resend, None
        if self._resync == "m110":
            if refused is not None:  # the M110 itself was refused (noise): again, alone
                self._send_m110(now)
            else:
                self._resend_from(self._executed + 1)
            return
        if refused is not None:  # the rejected transmission's credit goes back, so that
            self._drain_refused += 1  # a line going out in parts can be finished
            self._error_ok(refused)
        else:
            line = self._executed_by(ok)
            if line > self._executed:
                self._execute_through(line, ok, now)
        self._drain_left -= 1
        if self._drain_left <= 0 and self._partial is None:
            self._drained(now)

    def _drained(self, now: float) -> None:
        """Every transmission is answered: the ``ok`` s counted are the lines taken. Those
        left unanswered were sent before a timeout: their answers were lost, and the lines
        before the one asked for were taken, as the firmware says (not sent again)."""
        unanswered = self._inflight.first_from(self._executed + 1)
        if unanswered is not None and unanswered.number < self._resync_line <= self._sent_max + 1:
            self._execute_through(self._resync_line - 1, PLAIN_OK, now)
        self._inflight.clear()
        if self._resync_line == self._executed + 1 and self._drain_refused <= 1:
            self._resend_from(self._resync_line)  # as Marlin asks: every line before taken
        else:
            self.counters.resyncs += 1
            self._out.append(Notice("resync", (
                f"firmware asked for line {self._resync_line}, out of step with the "
                f"{self._executed} lines it took ({self._sent_max} sent): M110 N"
                f"{self._executed}, then resending from line {self._executed + 1}")))
            self._send_m110(now)

    def _send_m110(self, now: float) -> None:
        self._resync_sent += 1
        if self._resync_sent > self.settings.resend_limit:
            self._halt_board()
            self._fail(errors.ResendLoop(
                f"M110 N{self._executed} refused {self._resync_sent - 1} times (limit "
                f"{self.settings.resend_limit}): the link is too noisy", self._acked), "halted")
            return
        self._resync = "m110"
        self._progress = now
        number = self._executed
        self._out.append(Write(framed(number, f"M110 N{number}")))

    def _resend_from(self, line: int) -> None:
        """The resync is over: transmission goes on from ``line`` (numbered as before)."""
        self._resync = None
        self._rewind_target = line
        self._resend = deque(self._history[n] for n in range(line, self._sent_max + 1))

    def _resync_timeout(self) -> None:
        """No answer for a whole timeout during a resync (an ``ok`` lost on the wire): the
        request is taken as it came, as a rewind before drains did; an M110 is sent again."""
        if self._resync == "m110" or self._resync_line > self._sent_max:
            self._inflight.clear()
            self._send_m110(self._progress)
        else:
            self._resend_from(self._resync_line)

    # -- other replies ------------------------------------------------------------------

    def _on_error(self, error: ErrorReply, now: float) -> None:
        if error.kind == "checksum":
            self.counters.checksum_errors += 1
        if error.kind != "other":
            self.counters.line_errors += 1
        else:
            self._since_ok.append(error)

    def _on_busy(self, busy: Busy, now: float) -> None:
        self._progress = now

    def _on_temperatures(self, temps: Temperatures, now: float) -> None:
        """A temperature report: collected for a query; the once-a-second line of an
        ``M109``/``M190`` wait (``W:``) also shows the firmware at work, like ``busy:``
        (Marlin prints it even without its busy keepalive, where a long heat-up would
        otherwise run into the ok timeout). Autoreports (``M155``) and ``M105`` answers
        carry no ``W:``, so a board that lost an ``ok`` still times out while it reports."""
        if temps.waiting:
            self._progress = now
        if self.state == "ready":
            self._collect(temps)

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
        self._since_ok.append(reply)
        del self._since_ok[:-16]

    # -- handshake and timeouts ---------------------------------------------------------

    def _handshake_ok(self, now: float) -> None:
        if self._after_resend is not None:
            # The error ok of a stale line (or of a garbled M110: the timeout retries it).
            self._after_resend = None
            return
        self._inflight.clear()
        self._next = 1
        self.state = "ready"
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
        if self._resync is not None and self._nudged < self.settings.nudges:
            self._nudged += 1
            self._progress = now
            self._out.append(Notice("timeout", (
                f"no ok for {self.settings.ok_timeout:g} s while resynchronising after a "
                f"request for line {self._resync_line}")))
            self._inflight.uncount(keep=self._partial)  # as below
            self._resync_timeout()
            return
        if self._nudged >= self.settings.nudges:
            self._fail(errors.LinkLost(
                f"no ok for {self.settings.ok_timeout:g} s, even after {self._nudged} {NUDGE} "
                f"nudge(s)",
                self._acked), "lost")
            return
        self._nudged += 1
        self._progress = now
        self._starve_wait = 0.0  # this nudge's ok T: resynchronises as a starve nudge's
        self._out.append(Notice("timeout", (
            f"no ok for {self.settings.ok_timeout:g} s (line {self._executed + 1} awaited, "
            f"{self._sent_max} sent): {NUDGE} nudge {self._nudged} of {self.settings.nudges}")))
        # The firmware has been quiet for a whole timeout: it has answered whatever it was
        # going to answer, or the answers are lost. Its buffer is empty, so the lines in
        # flight no longer hold credit. A line being resent is the tickle it waits for;
        # otherwise a numbered M105, whose ``ok T:`` also resynchronises the ok count. The
        # line going out in parts is the exception: the firmware has not had it whole, so
        # its answer is still to come (it keeps its credit: the error ``ok`` of a resend
        # request is then not taken for a later line's), and if it is an M105 its
        # ``ok T:`` is the first.
        self._inflight.uncount(keep=self._partial)
        partial = self._partial
        self._m105.clear()
        if partial is not None and _is_m105(partial.item.command):
            self._m105.append(partial.number)
        self._finish_partial()
        if not self._resend:
            pending = self._pending
            # a starve nudge's M105 still queued is this nudge: one M105, not two
            queued = pending[0].kind == "nudge" if pending else False
            self._transmit(pending.popleft() if queued else Item(NUDGE, None, "nudge"), now)

    def _starve_nudge(self, now: float) -> None:
        """Lines have waited for credit ``starve_timeout`` without progress: see "Starved" in
        the module docstring. Once until the next ``ok``, whether it sends or not (an ``M105``
        it queued and could not send goes out in turn)."""
        self._starve_wait = 0.0
        room = self._starve_room()
        partial = self._partial
        if partial is not None:
            rest = len(partial.item.data) - partial.written
            if rest > room:
                return  # a buffer this full may be busy: the timeout will tell
            self._finish_partial()
            room -= rest
            # the M105 after it, if one is due; it waits in the queue if it does not fit
            tickle = None if self._resend or self._m105_due() else self._tickle()
        else:
            tickle = self._tickle()
            if tickle is None or len(tickle.data) > room:
                return
        if tickle is not None and len(tickle.data) <= room:
            queue = self._resend or self._pending
            if queue and queue[0] is tickle:
                queue.popleft()
            self._transmit(tickle, now)
        self.counters.starve_nudges += 1
        self._out.append(Notice("starved", (
            f"no ok for {self._starve_timeout:g} s while lines wait for credit (line "
            f"{self._executed + 1} awaited, {self._sent_max} sent): nudged past the credit "
            f"(a lost ok, or a long move)")))

    def _m105_due(self) -> bool:
        """Whether an ``M105`` sent is still to be answered (the line in parts, if one).

        Its ``ok T:`` will resynchronise the count, or was lost; then the answer of an
        ``M105`` sent now would be taken for the lost one's (the oldest due), leaving the
        count one behind again at every nudge."""
        m105 = self._m105
        return bool(m105) and m105[-1] > self._executed

    def _queue_nudge(self) -> None:
        """Put a numbered ``M105`` first in the queue, unless one is there already."""
        pending = self._pending
        if not (pending and _is_m105(pending[0].command)):
            pending.appendleft(Item(NUDGE, None, "nudge"))

    def _tickle(self) -> Item | None:
        """What the starve nudge sends past the credit when no line is in parts: the next
        line of a resend under way (any other number would be rejected as out of turn), an
        ``M105`` (the first queued line if it is one), or while one is still to be answered
        (:meth:`_m105_due`), the next line."""
        if self._resend:
            return self._resend[0]
        if not self._m105_due():
            self._queue_nudge()
        if not self._pending:
            return None
        item = self._pending[0]
        if item.number is None and item.framed_as != self._next:
            self._frame(item)
        return item

    def _starve_room(self) -> int:
        """Bytes the firmware's receive buffer surely has free were it busy, not starved:
        the buffer less the bytes counted in flight, bar the transmission of the oldest
        line (every line before it was answered, so the firmware has read it out into its
        command queue). With ADVANCED_OK the lines known read out are left out already."""
        if self._read_through > self._executed:
            return self.settings.rx_buffer_bytes \
                - self._inflight.after_first(self._read_through)[1]
        nbytes = self._inflight.bytes
        oldest = self._inflight.first_from(self._executed + 1)
        if oldest is not None and oldest.number == self._executed + 1 and oldest.counted \
                and oldest is not self._partial:
            nbytes -= oldest.written
        return self.settings.rx_buffer_bytes - nbytes

    _handlers: ClassVar[dict[type, Any]] = {
        Ok: _on_ok, Resend: _on_resend, ErrorReply: _on_error, Busy: _on_busy,
        Wait: _on_wait, Halted: _on_halted, Banner: _on_banner, Temperatures: _on_temperatures,
    }


def _is_m105(command: str) -> bool:
    """Whether ``command`` is an ``M105`` (answered by ``ok T:…``)."""
    return command.startswith(NUDGE) and command[4:5] in ("", " ")
