"""The job manager: submit, slice ahead, print FIFO, pause/resume/cancel, recover after a crash.

The face of the job domain to the daemon and its control endpoints, over its parts:

- :class:`~hostd.jobs.queue.JobQueue`: every job's state, counts and waiters, the queue hold,
  the job on the printer;
- :class:`~hostd.jobs.slice_loop.SliceLoop` and :class:`~hostd.jobs.print_loop.PrintLoop`: the
  two loops, STL jobs to the slicing worker and ready jobs (one at a time) to a
  :class:`~hostd.printer.streamer.Streamer` on the printer port;
- :class:`~hostd.jobs.progress.ProgressRecorder`: the streamer's hooks (progress persisted,
  throttled, plus at every layer, pause and checkpoint; events on the bus);
- :mod:`hostd.jobs.resume`: where an interrupted job resumes;
- :class:`~hostd.jobs.figures.JobFigures`: every view of a job's figures.
"""

from __future__ import annotations

import asyncio
import re
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hostd.errors import PrinterBusy, ShuttingDown
from hostd.events import EventBus
from hostd.jobs.active import Active
from hostd.jobs.figures import JobFigures
from hostd.jobs.file_check import FileChecker, GcodeSummary, MeshSummary
from hostd.jobs.joblog import log
from hostd.jobs.print_loop import PrintLoop, Readiness, load_program
from hostd.jobs.progress import ProgressRecorder
from hostd.jobs.queue import JobQueue
from hostd.jobs.resume import resume_point, resume_scope
from hostd.jobs.slice_loop import SliceLoop
from hostd.jobs.spool import MESH_KINDS, SUFFIX, Spool, SpoolError, Staged, check_name, upload_kind
from hostd.jobs.states import TERMINAL, JobState, JobStateError
from hostd.jobs.storage import StorageGuard
from hostd.jobs.store import Job, JobStore
from hostd.printer.envelope import Envelope
from hostd.printer.modal import ModalState
from hostd.printer.program import Program
from hostd.printer.settings import StreamSettings
from hostd.printer.streamer import Port, Streamer
from hostd.slicing_worker import PICTURES, SliceOptions, SlicingWorker, picture_path

CACHE_KEY = re.compile(r"[0-9a-f]{64}-[0-9a-f]{32}")
"""A slice cache entry's name (:func:`hostd.slicing_worker.cache_key`)."""


class JobManager:
    """Jobs from upload to outcome. Create, then :meth:`start`; :meth:`stop` at shutdown."""

    def __init__(self, store: JobStore, spool: Spool, worker: SlicingWorker | None,
                 port_factory: Callable[[], Port], bus: EventBus,
                 settings: StreamSettings, envelope: Envelope | None = None,
                 printer: Readiness | None = None, hold_after_print: bool = False,
                 resends: Callable[[], int] | None = None) -> None:
        self.store = store
        self.spool = spool
        self.worker = worker
        self.bus = bus
        self.settings = settings
        self.printer = printer
        self.checker = FileChecker(envelope)  # whole-file checks, off the loop's GIL
        self.queue = JobQueue(store, bus, hold_after_print)
        self.storage = StorageGuard(self.queue, settings.idle_timeout)
        self.recorder = ProgressRecorder(self.queue, self.storage)
        self.slicer = SliceLoop(self.queue, spool, worker, self.checker)
        self.printing = PrintLoop(self.queue, self.recorder, port_factory, settings,
                                  self._load_program, printer, resends)
        self.recovered: list[int] = []
        self._recovered = False
        self._tasks: list[asyncio.Task[None]] = []
        # the queue's wake-up and waiters, under the names the tests use
        self._wake_print = self.queue.wake_print
        self._done = self.queue.done

    @property
    def active(self) -> Active | None:
        """The job on the printer, or ``None``."""
        return self.queue.active

    @active.setter
    def active(self, act: Active | None) -> None:
        self.queue.active = act

    @property
    def counts(self) -> dict[str, int]:
        """Jobs per state, from memory."""
        return self.queue.counts

    @counts.setter
    def counts(self, counts: dict[str, int]) -> None:
        self.queue.counts = counts

    @property
    def envelope(self) -> Envelope | None:
        """The machine's travel every file and raw command is checked against."""
        return self.checker.envelope

    @property
    def checkpoints(self) -> int:
        """The job database's checkpoints done since the start."""
        return self.recorder.checkpoints

    # -- life cycle ------------------------------------------------------------------------

    def recover(self) -> None:
        """After a restart, the jobs a crash left printing or slicing, interrupted or queued
        again (once): before any client can see them, so none sees a dead job printing."""
        if not self._recovered:
            self._recovered = True
            self.recovered += self.queue.recover()

    def start(self) -> None:
        self.recover()
        self._tasks = [asyncio.create_task(self.printing.run(), name="print-loop"),
                       asyncio.create_task(self.slicer.run(), name="slice-loop"),
                       asyncio.create_task(self.storage.run(), name="storage")]
        for task in self._tasks:
            task.add_done_callback(_log_death)
        self.queue.wake_print.set()
        self.queue.wake_slice.set()

    def alive(self) -> bool:
        """Whether the print and slice loops are running (for the watchdog)."""
        return bool(self._tasks) and not any(t.done() for t in self._tasks)

    def tasks(self) -> list[asyncio.Task[None]]:
        """The print and slice loops (read-only use: the watchdog's report)."""
        return list(self._tasks)

    async def stop(self, reason: str = "daemon stopped") -> None:
        """Stop at a safe point: the active job stops feeding after its acked lines and is
        recorded ``interrupted`` with its progress and modal state."""
        self.queue.stopping = True
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        await self.recorder.settle()  # its thread must be done before the store closes
        await self.storage.close()
        act = self.queue.active
        if act is not None:
            self.recorder.persist(act, force=True)
            job = self.store.get(act.job.id)
            if job.state in (JobState.PRINTING, JobState.PAUSED):
                self.queue.set_state(job.id, JobState.INTERRUPTED,
                                     f"{reason} at line {act.streamer.acked}")
                if act.streamer.modal.extruded > 0:
                    self.queue.hold.after(job.id, "was interrupted when hostd stopped")
            self.queue.finish_active(act)
        self.checker.close()

    # -- requests (from the control endpoints) -------------------------------------------

    async def submit(self, name: str, data: bytes, kind: str | None = None,
                     options: SliceOptions | None = None) -> Job:
        """Queue ``data``, an upload named ``name`` (see :meth:`submit_staged`)."""
        staged = self.spool.stage()
        try:
            await asyncio.to_thread(staged.write, data)
        except BaseException:
            staged.discard()
            raise
        return await self.submit_staged(name, staged, kind, options)

    def stage(self) -> Staged:
        """A new staging file in the spool, for an upload to be written to."""
        return self.spool.stage()

    async def submit_staged(self, name: str, staged: Staged, kind: str | None = None,
                            options: SliceOptions | None = None) -> Job:
        """Queue an upload written to the spool's staging: checked whole in the worker
        process, then stored under its digest (a part sent as 3MF or OBJ as the binary STL
        the check made of it), with the slice ``options`` of a part (refused for a G-code: it
        is not sliced). Afterwards the staged file is gone: stored, or on any error
        discarded."""
        options = options or SliceOptions()
        converted: Path | None = None
        try:
            if self.queue.stopping:
                raise ShuttingDown("the daemon is shutting down")
            check_name(name)
            kind = upload_kind(name, kind)
            if kind == "gcode" and options != SliceOptions():
                raise SpoolError(f"{name}: a G-code file is not sliced here: the slice options "
                                 "(allow_overhang, seed, parts) are for STL uploads")
            self.spool.check_size(staged.size, name)
            await asyncio.to_thread(staged.finish)  # on disk before the worker reads it
            summary = await self.checker.check(staged.path, kind, name)
            if isinstance(summary, MeshSummary) and summary.converted is not None:
                converted = Path(summary.converted)
                sha = await asyncio.to_thread(self.spool.adopt, converted, SUFFIX["stl"])
            else:
                sha = await asyncio.to_thread(self.spool.commit, staged,
                                              SUFFIX["stl" if kind in MESH_KINDS else kind])
        finally:
            staged.discard()
            if converted is not None:
                converted.unlink(missing_ok=True)
        return self._queued(name, sha, summary, options)

    def _queued(self, name: str, sha: str, summary: GcodeSummary | MeshSummary,
                options: SliceOptions) -> Job:
        """A checked upload stored as ``sha``, now a queued job (a G-code one ready)."""
        gcode = summary if isinstance(summary, GcodeSummary) else None
        job = self.store.add(Path(name).name[:200] or "upload", "stl" if gcode is None
                             else "gcode", sha, gcode_sha=None if gcode is None else sha,
                             estimate={} if gcode is None else gcode.estimate,
                             allow_overhang=options.allow_overhang,
                             slice_options=dict(options.decompose))
        self.queue.added(job)
        if isinstance(summary, GcodeSummary):
            self.store.update(job.id, total_lines=summary.total)
            self.queue.set_state(job.id, JobState.READY, "g-code upload")
            self.queue.wake_print.set()
        else:
            self.store.update(job.id, info={"format": summary.format})
            self.queue.wake_slice.set()
        return self.store.get(job.id)

    async def pause(self, job_id: int, wait: bool = True) -> Job:
        act = self._require_active(job_id, JobState.PRINTING)
        evt = self.queue.paused.setdefault(job_id, asyncio.Event())
        act.streamer.request_pause("paused by operator")
        if wait:
            await self.queue.wait_paused_or_done(job_id, evt)
        return self.store.get(job_id)

    async def resume(self, job_id: int, scope: str | None = None) -> Job:
        """Resume a paused job, or restart an interrupted one from ``scope`` (default
        :data:`~hostd.jobs.resume.DEFAULT_SCOPE`); returns the job once it has left that
        state (printing, or failed when it could not be resumed)."""
        job = self.store.get(job_id)
        act = self.queue.active
        paused = act if (job.state is JobState.PAUSED and act is not None
                         and act.job.id == job_id) else None  # this job, paused on the printer
        if paused is not None and scope is not None:
            raise JobStateError(f"job {job_id} is paused: it goes on from its next line "
                                "(from is for interrupted jobs)")
        if paused is None and job.state is not JobState.INTERRUPTED:
            raise JobStateError(f"job {job_id} is {job.state}; only paused or interrupted jobs "
                                "resume")
        scope = resume_scope(scope)
        if paused is None and (act is not None or self.printing.resume_request is not None):
            raise PrinterBusy("another job is on the printer")
        if self.printer is not None and not self.printer.connected:
            raise PrinterBusy("the printer is not ready (serial link down or halted): wait for "
                              "it to reconnect, or hostctl firmware-restart after a halt")
        if not self.store.flush():
            raise JobStateError(f"job {job_id} cannot go on while the job database cannot be "
                                f"written ({self.store.failure}): make room, then resume")
        left = self.queue.left.setdefault(job_id, asyncio.Event())
        if paused is not None:
            paused.streamer.request_resume()
        else:
            self.printing.request_resume(job_id, scope)
        await left.wait()
        if (refused := self.printing.refused.pop(job_id, None)) is not None:
            raise JobStateError(refused)
        return self.store.get(job_id)

    async def cancel(self, job_id: int, wait: bool = True) -> Job:
        job = self.store.get(job_id)
        act = self.queue.active
        if act is not None and act.job.id == job_id:
            done = self.queue.done.setdefault(job_id, asyncio.Event())
            act.streamer.request_cancel()
            if wait:
                await done.wait()
            return self.store.get(job_id)
        if job.state in TERMINAL:
            raise JobStateError(f"job {job_id} is already {job.state}")
        self.queue.set_state(job_id, JobState.CANCELLED, "cancelled by operator")
        self.slicer.cancel(job_id)
        return self.store.get(job_id)

    async def delete(self, job_id: int) -> Job:
        job = self.store.delete(job_id)
        self.slicer.cancel(job_id)  # its STL is about to go: no slice of it is wanted
        self.queue.forget(job)
        for sha, kind in ((job.upload_sha, job.kind), (job.gcode_sha, "gcode")):
            if sha and self.store.references(sha) == 0:
                await asyncio.to_thread(self.spool.remove, sha, SUFFIX[kind])
        return job

    async def wait_finished(self, job_id: int) -> Job:
        """Until the job is completed, failed, cancelled or interrupted (at once if it is)."""
        return await self.queue.wait_finished(job_id)

    def queue_start(self) -> dict[str, Any]:
        """The operator cleared the platform: the next ready job may start."""
        return self.queue.queue_start()

    def queue_hold(self, reason: str = "held by the operator") -> dict[str, Any]:
        """No new job starts until :meth:`queue_start` (the job printing goes on); an
        earlier hold's reason stays."""
        return self.queue.queue_hold(reason)

    def queue_status(self) -> dict[str, Any]:
        return self.queue.queue_status()

    def _require_active(self, job_id: int, state: JobState) -> Active:
        job = self.store.get(job_id)
        act = self.queue.active
        if act is None or act.job.id != job_id or job.state is not state:
            raise JobStateError(f"job {job_id} is {job.state}, not {state}")
        return act

    # -- which job a request means -----------------------------------------------------------

    def current_id(self, job_id: int | None) -> int:
        """``job_id``, or else the job on the printer's."""
        if job_id is not None:
            return job_id
        if self.queue.active is None:
            raise JobStateError("no job is printing; give an id")
        return self.queue.active.job.id

    def resumable_id(self) -> int:
        """The job a resume without an id means: the one on the printer, else the newest
        paused or interrupted one."""
        if self.queue.active is not None:
            return self.queue.active.job.id
        jobs = self.store.list([JobState.INTERRUPTED, JobState.PAUSED])
        if not jobs:
            raise JobStateError("no paused or interrupted job; give an id")
        return jobs[-1].id

    def streamer(self) -> Streamer | None:
        """The streamer of the job on the printer (printing or paused), or ``None``."""
        act = self.queue.active
        return None if act is None else act.streamer

    # -- views -----------------------------------------------------------------------------

    def job_dict(self, job: Job) -> dict[str, Any]:
        """``job`` as plain JSON, with its live figures while it is on the printer."""
        d = job.to_dict()
        act = self.queue.active
        if act is not None and act.job.id == job.id:
            d.update(JobFigures.live(act, time.monotonic()).job_fields())
        return d

    def list_jobs(self, states: list[JobState] | None, limit: int
                  ) -> tuple[list[dict[str, Any]], int]:
        """The newest ``limit`` jobs in ``states`` (0: all; ``None``: any state), oldest
        first, and how many there are in all."""
        jobs = [self.job_dict(j) for j in self.store.list(states, limit, newest=True)]
        return jobs, self.store.count(states)

    def job_detail(self, job_id: int) -> dict[str, Any]:
        """One job with its state history and checkpoints."""
        job = self.store.get(job_id)
        out = self.job_dict(job)
        out["history"] = self.store.history(job.id)
        out["checkpoints"] = [c.to_dict() for c in self.store.checkpoints(job.id)]
        return out

    def picture(self, job_id: int, which: str) -> Path | None:
        """The file of a sliced job's picture ``which`` (:data:`PICTURES`), or ``None``
        when it has none (a G-code upload, a slice older than the pictures)."""
        info = self.store.get(job_id).info
        key = info.get("cache_key")
        if (self.worker is None or which not in PICTURES or which not in
                (info.get("pictures") or ()) or not isinstance(key, str)
                or not CACHE_KEY.fullmatch(key)):
            return None
        path = picture_path(self.worker.cache.gcode_path(key), which)
        return path if path.is_file() else None

    def status(self) -> dict[str, Any]:
        """A read-only snapshot from memory (no database access).

        ``current`` is the job on the printer (or None); ``latest`` is the same, or else the
        last job that printed since the start, with its final figures and state.
        """
        act = self.queue.active
        current = None if act is None else JobFigures.live(act, time.monotonic())
        latest = current if current is not None else self.queue.last
        return {**self.queue.status(),
                "transitions": dict(self.recorder.transitions),
                "current": None if current is None else current.status(),
                "latest": None if latest is None else latest.status(),
                "recovered": list(self.recovered), "db_checkpoints": self.recorder.checkpoints,
                "waiting_for_printer": self.printing.waiting_for_printer,
                "storage": self.storage.status(),
                "slicing": self.slicer.progress,
                "queue": self.queue.queue_status(),
                "file_checks": self.checker.status()}

    # -- the parts' work, under the names the tests use -------------------------------------

    async def _load_program(self, job: Job) -> Program:
        """The job's G-code (the print loop's loader: a test holds or breaks it here)."""
        return await load_program(self.spool, job)

    async def _resume_point(self, job: Job, program: Program, scope: str
                            ) -> tuple[int, ModalState, list[str]]:
        return await resume_point(self.store, job, program, scope, self.settings)

    def _persist(self, act: Active, force: bool = False) -> None:
        self.recorder.persist(act, force)

    @property
    def _checkpoint(self) -> asyncio.Task[None] | None:
        return self.recorder.checkpoint_task

    def _on_progress(self, st: Streamer) -> None:
        self.recorder.on_progress(st)

    def _progress(self, act: Active, now: float) -> dict[str, Any]:
        return JobFigures.live(act, now).progress_event()


def _log_death(task: asyncio.Task[None]) -> None:
    """A job loop ended other than by cancellation: say why, with the traceback."""
    if not task.cancelled() and task.exception() is not None:
        log.error("the %s stopped: no more jobs run until hostd restarts", task.get_name(),
                  exc_info=task.exception())

