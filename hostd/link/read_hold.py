"""When to read a real port next: at once, or after a hold while replies come quickly.

Every wake-up of the event loop costs more than the line an ``ok`` frees, so while the wire is
the bottleneck hostd reads the port in batches: after data, it leaves the port unread for a
share of the time the bytes already written still need on the wire (a clock of the wire at
the configured baud, advanced by every write). The lines still on their way keep the wire busy
meanwhile, and a hold shrinks by itself when replies are late, since less is left on the wire
by then, and it always leaves a margin of queued wire time for a late timer. A hold is taken
only when it is likely to collect another reply: it must last at least half the mean gap
between replies (refusing holds a little short of one gap only moved the next read to a
moment later, for the reply then due). So when replies come slowly (the firmware's planner,
not the wire, sets the pace) the port is read the moment a reply arrives. Receive buffers
too small to hold more than one reply's worth of lines get no holds at all
(:func:`hostd.link.transport.read_hold`).

The holds last a millisecond or two, so they need asyncio's own loop: uvloop (tried on
2026-12-02 with ``bench/daemon.py``) rounds its timers to whole milliseconds, and the holds
then collected fewer replies per read and the daemon spent more CPU, not less. asyncio's
epoll loop also waits in whole milliseconds, rounded up, and the shares above are tuned with
that: a ``select()`` loop, whose waits are exact to the microsecond, collected 1.36–1.51
lines per read against epoll's 1.88–1.89, and the daemon spent 10.4–11.1 % of a core
streaming against 9.0–9.3 % (later that day, alternate runs: ``select()`` twice each with
the share at 0.7 and 0.85, epoll twice at 0.7).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

READ_HOLD_MAX_S = 0.01  # a reply never waits longer than this
READ_HOLD_MARGIN_S = 0.001  # wire time left when a held read is due: a late timer, the reply
HOLD_GAPS = 0.5  # a hold must last half the mean gap between replies, or it is not taken
HOLD_MIN_BUFFER = 120  # receive buffer bytes for holds: 2.5 framed five-axis lines of 48
SMOOTHING = 0.25  # weight of the newest read in the mean gap between replies


@dataclass
class ReadHold:
    """The wire's clock, the mean gap between replies and the hold decision (pure: the
    caller passes the time).

    Attributes
    ----------
    share
        Share of the wire time still queued that the port may be left unread.
    byte_s
        Wire seconds per byte (10 bits per byte at the baud rate).
    hold_max
        Longest hold, s.
    wire_free
        When the bytes written so far will have left on the wire (loop time, s).
    last_data
        When data last arrived (loop time, s).
    span, replies
        Smoothed seconds between two reads that found data, and replies per such read:
        their ratio is the mean gap between replies (a ratio of means, so holds that
        catch one reply or two do not bias it). It starts long, so nothing is held until
        replies come quickly; a pause counts as at most ``4 * hold_max``.
    """

    share: float
    byte_s: float
    hold_max: float = READ_HOLD_MAX_S
    wire_free: float = -math.inf
    last_data: float = -math.inf
    span: float = 4 * READ_HOLD_MAX_S
    replies: float = 1.0

    def wrote(self, now: float, nbytes: int) -> None:
        """``nbytes`` were written at ``now``: they leave after what is queued before them."""
        self.wire_free = max(self.wire_free, now) + nbytes * self.byte_s

    def after_data(self, now: float, replies: int) -> float:
        """``replies`` lines arrived at ``now`` (and were handled): seconds to leave the port
        unread, or 0 to watch it."""
        since, self.last_data = min(now - self.last_data, 4 * self.hold_max), now
        self.span += (since - self.span) * SMOOTHING
        self.replies += (replies - self.replies) * SMOOTHING
        queued = self.wire_free - now
        hold = min(self.share * queued, queued - READ_HOLD_MARGIN_S, self.hold_max)
        return hold if hold * self.replies >= self.span * HOLD_GAPS else 0.0
