"""The event bus: components publish, the control server (and metrics) subscribe.

Handlers are plain callables run synchronously in :meth:`EventBus.publish`; one that raises is
logged and counted, and the others still run. Handlers must not block (the server's handler only
puts the event on each subscribed client's queue).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

log = logging.getLogger(__name__)

Handler = Callable[[str, dict[str, Any]], None]

EVENT_NAMES = (
    "job.state",         # {"job": {...}, "old": str, "new": str, "reason": str}
    "job.progress",      # {"job_id", "acked", "total", "progress", "subpart", "layer", "eta_s"}
    "job.slicing",       # {"job_id", "name", "stage", "percent"}: a slice's stage started
    "job.subpart",       # {"job_id", "subpart", "layer"}: the sub-part being printed changed
    "subpart_started",   # {"job_id", "subpart", "parent", "a", "c", "line"}: a transition passed
    "transition_failed",  # {"job_id", "subpart", "reason", "expected", "measured"}
    "printer.temperatures",  # {"heaters": {...}}
    "printer.state",     # {"state": ..., "reason": ...}
    "queue.state",       # {"held": bool, "reason": str | None}: the hold was set or lifted
    "storage",           # {"failing": bool, "error", "since", "heaters_off"}: the job database
)                        # refused a write (a full disk), turned the heaters off, or is back


class EventError(Exception):
    """A subscription that names unknown events."""


@dataclass
class _Subscription:
    handler: Handler
    names: frozenset[str] | None


class EventBus:
    """Publish/subscribe with failure isolation between handlers."""

    def __init__(self) -> None:
        self._subs: dict[int, _Subscription] = {}
        self._next = 0
        self.published = 0
        self.handler_errors = 0

    def subscribe(self, handler: Handler, names: Iterable[str] | None = None) -> Callable[[], None]:
        """Call ``handler(name, data)`` for every event (or only ``names``); returns unsubscribe."""
        wanted = None if names is None else check_names(names)
        key = self._next
        self._next += 1
        self._subs[key] = _Subscription(handler, wanted)

        def unsubscribe() -> None:
            self._subs.pop(key, None)

        return unsubscribe

    def publish(self, name: str, data: dict[str, Any]) -> None:
        """Deliver one event to every interested handler; a failing handler harms no other."""
        self.published += 1
        for sub in list(self._subs.values()):
            if sub.names is not None and name not in sub.names:
                continue
            try:
                sub.handler(name, data)
            except Exception:  # isolation: one broken subscriber must not break the others
                self.handler_errors += 1
                log.exception("event handler failed on %s", name)

    def status(self) -> dict[str, Any]:
        return {"subscribers": len(self._subs), "published": self.published,
                "handler_errors": self.handler_errors}


def check_names(names: Iterable[str]) -> frozenset[str]:
    """``names`` as a set; :class:`EventError` naming those that are no event's."""
    wanted = frozenset(names)
    unknown = wanted - set(EVENT_NAMES)
    if unknown:
        raise EventError(f"unknown events: {', '.join(sorted(unknown))} "
                         f"(known: {', '.join(EVENT_NAMES)})")
    return wanted
