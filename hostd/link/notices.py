"""The link's warnings for the journal, without flooding it on a noisy line.

Every ``ok`` timeout is logged: each stands for seconds of a stalled print. Resends come in
hundreds on a bad cable, so at most one is logged per :data:`RESEND_INTERVAL`; the next one
logged says how many were held back meanwhile (the counters and metrics keep the full count).
Starve nudges (an ``M105`` after a second without an ``ok`` while lines wait for credit: a
lost ``ok``, or just a long move) are logged at info level, as seldom as resends.
"""

from __future__ import annotations

import logging
import math

from hostd.link.actions import Notice

log = logging.getLogger(__name__)
RESEND_INTERVAL = 60.0  # s between two logged resends
THROTTLED = {"resend": RESEND_INTERVAL, "starved": RESEND_INTERVAL, "resync": RESEND_INTERVAL}
LEVELS = {"starved": logging.INFO}  # warning for the other kinds


class NoticeLog:
    """Logs :class:`Notice` s naming ``port``, as warnings unless :data:`LEVELS` says
    otherwise, throttled by kind (pure apart from the logging: the caller passes the time)."""

    def __init__(self, port: str) -> None:
        self.port = port
        self._last: dict[str, float] = {}
        self._held: dict[str, int] = {}

    def notice(self, notice: Notice, now: float) -> None:
        """Log ``notice``, unless another of its kind was logged less than its interval ago."""
        interval = THROTTLED.get(notice.kind, 0.0)
        if now - self._last.get(notice.kind, -math.inf) < interval:
            self._held[notice.kind] = self._held.get(notice.kind, 0) + 1
            return
        held = self._held.pop(notice.kind, 0)
        more = f" ({held} more since the last one logged)" if held else ""
        self._last[notice.kind] = now
        log.log(LEVELS.get(notice.kind, logging.WARNING), "%s: %s%s", self.port,
                notice.message, more)
