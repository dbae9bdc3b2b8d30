"""What a print leaves behind as it goes: the streamer's hooks.

Progress is written to the job database (at most every :data:`PERSIST_INTERVAL`, and at every
layer, pause and checkpoint) and published as ``job.progress`` (at most every
:data:`EVENT_INTERVAL`, and at every layer); the database's own checkpoint runs on a worker
thread, so its fsync never holds the event loop; transitions are counted and recorded.
"""

from __future__ import annotations

import asyncio
import time
from typing import Any

from hostd.jobs.active import Active
from hostd.jobs.figures import JobFigures
from hostd.jobs.joblog import log
from hostd.jobs.queue import JobQueue
from hostd.jobs.states import JobState
from hostd.jobs.storage import StorageGuard
from hostd.jobs.store import StorageError, StoreError
from hostd.printer.program import Transition
from hostd.printer.streamer import Hooks, Streamer

PERSIST_INTERVAL = 0.25  # s between progress writes (also at every layer change)
EVENT_INTERVAL = 0.2  # s between progress events


class ProgressRecorder:
    """The hooks of the job on the printer (:attr:`JobQueue.active`)."""

    def __init__(self, queue: JobQueue, storage: StorageGuard | None = None) -> None:
        self.queue = queue
        self.store = queue.store
        self.storage = storage if storage is not None else StorageGuard(queue, 300.0)
        self.transitions = {"total": 0, "failed": 0}
        self.checkpoints = 0  # the database's, done
        self.checkpoint_task: asyncio.Task[None] | None = None

    def hooks(self, job_id: int) -> Hooks:
        return Hooks(progress=self.on_progress, paused=self.on_paused,
                     resumed=self.on_resumed, checkpoint=self.on_checkpoint,
                     event=lambda name, data: self.on_event(job_id, name, data))

    async def settle(self) -> None:
        """Wait for a database checkpoint still running (before the store closes)."""
        if self.checkpoint_task is not None:
            await asyncio.gather(self.checkpoint_task, return_exceptions=True)

    def on_progress(self, st: Streamer) -> None:
        act = self.queue.active
        if act is None:
            return
        now = time.monotonic()
        if act.rate_mark is None and st.acked > st.start and (
                st.layer is not None or not act.program.layers):
            total = st.program.total
            act.rate_mark = (act.elapsed(now), st.acked / total if total else 1.0)
        layer = (st.subpart, st.layer)
        changed = layer != act.last_layer
        last = st.acked == st.program.total
        if changed or last or now - act.last_persist >= PERSIST_INTERVAL:
            act.last_layer = layer
            self.persist(act)
        if changed or last or now - act.last_event >= EVENT_INTERVAL:
            act.last_event = now
            self.queue.bus.publish("job.progress", JobFigures.live(act, now).progress_event())

    def persist(self, act: Active, force: bool = False) -> None:
        st = act.streamer
        st.sync_acked()  # the firmware's line, not the end of the last whole batch
        act.last_persist = time.monotonic()
        self.store.update(act.job.id, acked_lines=st.acked, subpart=st.subpart, layer=st.layer,
                          modal=st.modal.snapshot(), filament_mm=st.modal.extruded,
                          print_seconds=act.elapsed(act.last_persist))
        self.storage.check(act)  # a write the disk refused pauses the job
        if self.store.claim_checkpoint() and not self.queue.stopping and (
                self.checkpoint_task is None or self.checkpoint_task.done()):
            self.checkpoint_task = asyncio.create_task(self._run_checkpoint(),
                                                       name="checkpoint")

    async def _run_checkpoint(self) -> None:
        """The database's checkpoint on a worker thread: its fsync never holds the loop."""
        try:
            await asyncio.to_thread(self.store.checkpoint)
        except StoreError as exc:
            log.warning("%s (the next one retries)", exc)
            return
        self.checkpoints += 1

    def on_paused(self, st: Streamer, reason: str) -> None:
        act = self.queue.active
        if act is None:
            return
        act.pause_clock(time.monotonic())
        self.persist(act, force=True)
        self.store.update(act.job.id, modal=(st.paused_modal or st.modal).snapshot())
        self.queue.set_state(act.job.id, JobState.PAUSED, reason)
        self.storage.paused(act)
        evt = self.queue.paused.pop(act.job.id, None)
        if evt is not None:
            evt.set()

    def on_resumed(self, st: Streamer) -> None:
        act = self.queue.active
        if act is None:
            return
        act.resume_clock(time.monotonic())
        self.storage.resumed()
        self.queue.set_state(act.job.id, JobState.PRINTING, "resumed")

    def on_checkpoint(self, st: Streamer, tr: Transition, pose: dict[str, float]) -> None:
        act = self.queue.active
        if act is None:
            return
        self.transitions["total"] += 1
        try:
            self.store.add_checkpoint(act.job.id, tr.subpart, tr.parent, pose.get("A", 0.0),
                                      pose.get("C", 0.0), tr.end, pose)
        except StorageError as exc:  # the guard pauses the job (persist below)
            log.warning("job %d: checkpoint of sub-part %d not kept: %s", act.job.id,
                        tr.subpart, exc)
        self.persist(act, force=True)

    def on_event(self, job_id: int, name: str, data: dict[str, Any]) -> None:
        if name == "transition_failed":
            self.transitions["total"] += 1
            self.transitions["failed"] += 1
        self.queue.bus.publish(name, {"job_id": job_id, **data})
