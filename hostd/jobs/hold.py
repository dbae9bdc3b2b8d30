"""The queue hold: no new job starts while a printed part may be on the platform
(``daemon.next_job: after_clear``) or the operator held the queue, until ``hostctl queue
start``. The reason is kept in the job database (the hold survives a restart) and each change
is logged and published as ``queue.state``."""

from __future__ import annotations

from typing import Any

from hostd.events import EventBus
from hostd.jobs.joblog import log
from hostd.jobs.store import JobStore

HOLD_KEY = "queue_hold"  # store setting: why the queue is held (absent: it runs)


class QueueHold:
    """Why no new job starts (``reason``), or ``None`` while the queue runs."""

    def __init__(self, store: JobStore, bus: EventBus, after_print: bool) -> None:
        self.store = store
        self.bus = bus
        self.after_print = after_print
        self.reason: str | None = store.setting(HOLD_KEY)

    def set(self, reason: str | None) -> None:
        """Hold the queue for ``reason`` (``None``: let it run)."""
        if reason == self.reason:
            return
        self.store.set_setting(HOLD_KEY, reason)
        self.reason = reason
        log.info("queue %s", f"held: {reason}" if reason else "runs")
        self.bus.publish("queue.state", {"held": reason is not None, "reason": reason})

    def after(self, job_id: int, how: str) -> None:
        """After job ``job_id`` left a part on the platform (``daemon.next_job:
        after_clear``), hold the queue until the operator clears it."""
        if not self.after_print:
            return
        todo = ("resume it, or clear the platform and run hostctl queue start"
                if "interrupted" in how else "clear the platform, then hostctl queue start")
        self.set(f"job {job_id} {how}: {todo}")

    def names(self, job_id: int) -> bool:
        """Whether the queue is held for job ``job_id``'s part."""
        return self.reason is not None and self.reason.startswith(f"job {job_id} ")

    def status(self, ready: int) -> dict[str, Any]:
        """``queue.status``: held or not and why, with ``ready`` jobs waiting."""
        return {"held": self.reason is not None, "reason": self.reason, "ready": ready,
                "next_job": "after_clear" if self.after_print else "at_once"}
