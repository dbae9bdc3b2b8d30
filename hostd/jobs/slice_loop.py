"""The slice loop: queued STL jobs, oldest first, sliced in the worker process one at a time,
their G-code checked whole and stored in the spool; the job is then ready to print."""

from __future__ import annotations

import asyncio
from functools import partial
from typing import Any

from hostd.jobs.file_check import FileChecker
from hostd.jobs.queue import JobQueue
from hostd.jobs.spool import Spool, SpoolError
from hostd.jobs.states import JobState
from hostd.jobs.store import Job
from hostd.printer.errors import PrinterError
from hostd.slicing_worker import SliceError, SliceOptions, SlicingWorker, sliced_reason


class SliceLoop:
    """Slices the queued STL jobs; :meth:`run` is the loop's task."""

    def __init__(self, queue: JobQueue, spool: Spool, worker: SlicingWorker | None,
                 checker: FileChecker) -> None:
        self.queue = queue
        self.spool = spool
        self.worker = worker
        self.checker = checker
        self.slicing: int | None = None  # the job the slicing worker is busy with
        self.progress: dict[str, Any] | None = None
        """The slice under way: ``job.slicing``'s data (job_id, name, stage, percent)."""

    async def run(self) -> None:
        wake = self.queue.wake_slice
        while True:
            await wake.wait()
            wake.clear()
            while (job := self.queue.next_stl()) is not None:
                try:
                    await self._slice_one(job)
                except Exception as exc:  # a bug: this job fails, the queue goes on
                    self.queue.fail_on_bug(job.id, "slicing", exc)

    def cancel(self, job_id: int) -> None:
        """Job ``job_id`` was cancelled or deleted: stop its slice, if it is the one running
        (the next STL job need not wait for it)."""
        if self.slicing == job_id and self.worker is not None:
            self.worker.cancel()

    def _progress(self, job: Job, stage: str, percent: float) -> None:
        """The slice of ``job`` reached ``stage``: the ``job.slicing`` event."""
        self.progress = {"job_id": job.id, "name": job.name, "stage": stage,
                         "percent": percent}
        self.queue.bus.publish("job.slicing", dict(self.progress))

    async def _slice_one(self, job: Job) -> None:
        queue = self.queue
        queue.set_state(job.id, JobState.SLICING, "slicing")
        try:
            if self.worker is None:
                raise SliceError("no slicing worker")
            stl = self.spool.path(job.upload_sha, ".stl")
            self.slicing = job.id
            try:
                outcome = await self.worker.slice(stl, job.upload_sha, job.name, SliceOptions(
                    job.allow_overhang, dict(job.slice_options)), partial(self._progress, job))
            finally:
                self.slicing = None
                self.progress = None
            summary = await self.checker.summarize(outcome.gcode_path, job.name)
            data = await asyncio.to_thread(outcome.gcode_path.read_bytes)
            sha = await asyncio.to_thread(self.spool.put, data, ".gcode")
        except (SliceError, SpoolError, PrinterError) as exc:
            if queue.state_of(job.id) is JobState.SLICING:
                queue.set_state(job.id, JobState.FAILED, f"slicing failed: {exc}")
            return
        if queue.state_of(job.id) is not JobState.SLICING:
            return  # cancelled or deleted meanwhile
        info = {**job.info, **outcome.info, "slice_s": round(outcome.duration_s, 3),
                "cache_hit": outcome.cache_hit, "cache_key": outcome.gcode_path.stem,
                "subparts": summary.subparts,
                "layers": summary.layers, "transitions": summary.transitions}
        queue.store.update(job.id, gcode_sha=sha, total_lines=summary.total,
                           estimate=summary.estimate, info=info)
        queue.set_state(job.id, JobState.READY, sliced_reason(outcome.info))
        queue.wake_print.set()
