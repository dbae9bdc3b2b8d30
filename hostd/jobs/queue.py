"""The job queue: every job's state and who waits for it.

:class:`JobQueue` changes a job's state (in the database, counted in memory, logged and
published as ``job.state``), wakes the slice and print loops, holds the waiters of
``job.wait``, ``job.pause`` and ``job.resume``, keeps the queue hold
(:class:`~hostd.jobs.hold.QueueHold`) and knows which job is on the printer and which printed
last. It runs nothing itself: the loops (:mod:`hostd.jobs.slice_loop`,
:mod:`hostd.jobs.print_loop`) do.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from typing import Any

from hostd.events import EventBus
from hostd.jobs.active import Active
from hostd.jobs.figures import JobFigures
from hostd.jobs.hold import QueueHold
from hostd.jobs.joblog import log
from hostd.jobs.states import TERMINAL, WAITING, JobState, JobStateError
from hostd.jobs.store import Job, JobNotFound, JobStore, StoreError

STOPPED = TERMINAL | {JobState.INTERRUPTED}  # states a job.wait returns at
_TROUBLE = (JobState.FAILED, JobState.INTERRUPTED)  # logged as warnings: the operator acts
_FINISHED = ("completed", "failed", "cancelled", "interrupted")


class JobQueue:
    """Job states, their counts and waiters, the hold, and the job on the printer."""

    def __init__(self, store: JobStore, bus: EventBus, hold_after_print: bool) -> None:
        self.store = store
        self.bus = bus
        self.hold = QueueHold(store, bus, hold_after_print)
        self.counts = store.counts()  # jobs per state, kept in memory (status() is a read)
        self.finished = {s: self.counts[s] for s in _FINISHED}
        self.active: Active | None = None
        self.last: JobFigures | None = None  # figures of the last job that printed
        self.stopping = False  # the daemon stops: no new work
        self.wake_print = asyncio.Event()
        self.wake_slice = asyncio.Event()
        self.done: dict[int, asyncio.Event] = {}  # job.wait, cancel: the job stopped
        self.paused: dict[int, asyncio.Event] = {}  # job.pause: the job paused
        self.left: dict[int, asyncio.Event] = {}  # resume() waits for the job's next state

    def recover(self) -> list[int]:
        """After a restart: the jobs the database found cut short (now interrupted or
        failed), logged; the hold for an interrupted job's part; the last job's figures."""
        recovered = []
        for job in self.store.recover():
            recovered.append(job.id)
            if job.state is JobState.INTERRUPTED and job.filament_mm > 0:
                self.hold.after(job.id, "was interrupted when hostd stopped")
            if job.state is JobState.INTERRUPTED:
                self.finished["interrupted"] += 1
            log.warning("job %d %s: %s", job.id, job.state, job.reason)
        self.counts = self.store.counts()
        self.last = self._last_printed()
        return recovered

    def _last_printed(self) -> JobFigures | None:
        """After a restart, the figures of the job that printed last (from the database):
        ``status()`` names it (an interrupted job to resume) as it would have before."""
        ended = [j for j in self.store.list(STOPPED, limit=20, newest=True)
                 if j.started_at is not None]
        if not ended:
            return None
        return JobFigures.stored(max(ended, key=lambda j: j.updated_at))

    # -- states ------------------------------------------------------------------------------

    def added(self, job: Job) -> None:
        """A new job is in the database (queued)."""
        self.counts[job.state.value] += 1
        self._emit_state(job, None, "submitted")

    def set_state(self, job_id: int, new: JobState, reason: str) -> Job:
        old = self.store.get(job_id).state
        job = self.store.transition(job_id, new, reason)
        self.counts[old.value] -= 1
        self.counts[new.value] += 1
        if new.value in self.finished and new is not old:
            self.finished[new.value] += 1
        act = self.active
        if act is not None and act.job.id == job_id:
            act.job = job
        elif self.last is not None and self.last.id == job_id:
            self.last = self.last.with_state(new.value)
        self._emit_state(job, old, reason)
        if new is not old and (left := self.left.pop(job_id, None)) is not None:
            left.set()
        if new in STOPPED:
            self.release_waiters(job_id)
        return job

    def state_of(self, job_id: int) -> JobState | None:
        """The job's state now, ``None`` once it is deleted."""
        try:
            return self.store.get(job_id).state
        except JobNotFound:
            return None

    def forget(self, job: Job) -> None:
        """``job`` was deleted: uncount it, and wake whoever waited for it."""
        self.counts[job.state.value] -= 1
        if self.hold.names(job.id):
            self.hold.set(f"job {job.id} was deleted (its part may still be on the platform):"
                          " clear the platform, then hostctl queue start")
        self.release_waiters(job.id)

    def fail_on_bug(self, job_id: int, stage: str, exc: Exception) -> None:
        """Log an unexpected error with its traceback and fail the job it stopped."""
        log.error("job %d: internal error while %s", job_id, stage, exc_info=exc)
        with contextlib.suppress(StoreError, JobStateError):
            if self.store.get(job_id).state not in STOPPED:
                self.set_state(job_id, JobState.FAILED,
                               f"internal error while {stage}: {exc!r} (see hostd's log)")

    def _emit_state(self, job: Job, old: JobState | None, reason: str) -> None:
        level = logging.WARNING if job.state in _TROUBLE else logging.INFO
        log.log(level, "job %d %r: %s -> %s (%s)", job.id, job.name,
                "new" if old is None else old.value, job.state.value, reason)
        self.bus.publish("job.state", {"job_id": job.id, "name": job.name,
                                       "old": None if old is None else old.value,
                                       "new": job.state.value, "reason": reason})

    # -- waiters ---------------------------------------------------------------------------

    async def wait_finished(self, job_id: int) -> Job:
        """Until the job is completed, failed, cancelled or interrupted (at once if it is).

        Raises
        ------
        JobNotFound
            No such job, or it was deleted while waited for.
        """
        job = self.store.get(job_id)
        if job.state in STOPPED:
            return job
        await self.done.setdefault(job_id, asyncio.Event()).wait()
        return self.store.get(job_id)

    async def wait_paused_or_done(self, job_id: int, paused: asyncio.Event) -> None:
        done = self.done.setdefault(job_id, asyncio.Event())
        waiters = [asyncio.ensure_future(paused.wait()), asyncio.ensure_future(done.wait())]
        try:
            await asyncio.wait(waiters, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for w in waiters:
                w.cancel()

    def release_waiters(self, job_id: int) -> None:
        """Wake whoever waits for the job to stop or pause: it has stopped (or is gone)."""
        for waiting in (self.done, self.paused, self.left):
            evt = waiting.pop(job_id, None)
            if evt is not None:
                evt.set()

    # -- what runs next --------------------------------------------------------------------

    def next_ready(self) -> bool:
        """Whether a new job may start: one is ready and the queue is not held."""
        return self.hold.reason is None and self.store.first(JobState.READY) is not None

    def next_stl(self) -> Job | None:
        """The oldest queued STL job (the next to slice)."""
        for job in self.store.list([JobState.QUEUED]):
            if job.kind == "stl":
                return job
        return None

    def finish_active(self, act: Active) -> None:
        """The job leaves the printer; its last figures stay visible in ``status()``."""
        self.last = JobFigures.live(act, time.monotonic())
        self.active = None

    # -- the queue hold --------------------------------------------------------------------

    def queue_start(self) -> dict[str, Any]:
        """The operator cleared the platform: the next ready job may start."""
        self.hold.set(None)
        self.wake_print.set()
        return self.queue_status()

    def queue_hold(self, reason: str = "held by the operator") -> dict[str, Any]:
        """No new job starts until :meth:`queue_start` (the job printing goes on)."""
        if self.hold.reason is None:
            self.hold.set(reason)
        return self.queue_status()

    def queue_status(self) -> dict[str, Any]:
        return self.hold.status(self.counts[JobState.READY.value])

    def status(self) -> dict[str, Any]:
        """Jobs waiting, per state and finished since the start (from memory)."""
        return {"queue_length": sum(self.counts[s.value] for s in WAITING),
                "counts": dict(self.counts), "finished": dict(self.finished)}
