"""The job manager: submit, slice ahead, print FIFO, pause/resume/cancel, recover after a crash.

It owns the job store and the spool, hands STL jobs to the slicing worker, runs at most one
:class:`~hostd.printer.streamer.Streamer` at a time on the printer port, persists progress
(throttled, plus at every layer, pause and checkpoint) and publishes events on the bus.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable, Coroutine
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from hostd.errors import PrinterBusy, ShuttingDown
from hostd.events import EventBus
from hostd.jobs.file_check import FileChecker, parse_upload
from hostd.jobs.spool import SUFFIX, Spool, SpoolError, Staged, upload_kind
from hostd.jobs.states import TERMINAL, WAITING, JobState, JobStateError
from hostd.jobs.store import Job, JobNotFound, JobStore, StoreError
from hostd.link.errors import FirmwareReset, LinkError, LinkLost
from hostd.printer.envelope import Envelope
from hostd.printer.errors import PrinterError
from hostd.printer.modal import ModalState
from hostd.printer.program import Program, Transition
from hostd.printer.settings import StreamSettings
from hostd.printer.streamer import Hooks, Port, Streamer, safe_z
from hostd.slicing_worker import SliceError, SlicingWorker, sliced_reason

log = logging.getLogger(__name__)
_TROUBLE = (JobState.FAILED, JobState.INTERRUPTED)  # logged as warnings: the operator acts

PERSIST_INTERVAL = 0.25  # s between progress writes (also at every layer change)
EVENT_INTERVAL = 0.2  # s between progress events
RESUME_SCOPES = ("layer", "subpart", "checkpoint")
DEFAULT_SCOPE = "layer"
"""Where an interrupted job resumes by default: the start of the layer it stopped in (at most
that layer is printed twice over). A sub-part or checkpoint restart prints again every layer
of the sub-part done so far, on top of themselves: the operator's choice, never a default."""
STOPPED = TERMINAL | {JobState.INTERRUPTED}  # states a job.wait returns at
HOLD_KEY = "queue_hold"  # store setting: why the queue is held (absent: it runs)


class Readiness(Protocol):
    """Whether the printer takes lines (the serial link): a job starts only when it does."""

    @property
    def connected(self) -> bool: ...

    async def wait_connected(self) -> None: ...


@dataclass
class Active:
    """The job on the printer and its live figures."""

    job: Job
    program: Program
    streamer: Streamer
    started: float
    paused_at: float | None = None
    paused_total: float = 0.0
    last_persist: float = 0.0
    last_event: float = 0.0
    last_layer: tuple[int | None, int | None] = (None, None)
    filament_base: float = 0.0
    rate_mark: tuple[float, float] | None = None
    """(elapsed s, progress) where the measured rate starts: the first acknowledged line of a
    layer, so the start script's heat-up (or a resume's reheat) does not count as slow
    printing; None before it."""

    def elapsed(self, now: float) -> float:
        paused = self.paused_total + (now - self.paused_at if self.paused_at else 0.0)
        return max(0.0, now - self.started - paused)


class JobManager:
    """Jobs from upload to outcome. Create, then :meth:`start`; :meth:`stop` at shutdown."""

    def __init__(self, store: JobStore, spool: Spool, worker: SlicingWorker | None,
                 port_factory: Callable[[], Port], bus: EventBus,
                 settings: StreamSettings, envelope: Envelope | None = None,
                 printer: Readiness | None = None, hold_after_print: bool = False) -> None:
        self.store = store
        self.printer = printer
        self.hold_after_print = hold_after_print
        self.hold_reason: str | None = store.setting(HOLD_KEY)
        """Why no new job starts (a printed part on the platform), or ``None``: persisted,
        lifted by :meth:`queue_start` (``hostctl queue start``)."""
        self.spool = spool
        self.worker = worker
        self.checker = FileChecker(envelope)  # whole-file checks, off the loop's GIL
        self.port_factory = port_factory
        self.bus = bus
        self.settings = settings
        self.active: Active | None = None
        self._wake_print = asyncio.Event()
        self._wake_slice = asyncio.Event()
        self._tasks: list[asyncio.Task[None]] = []
        self._stopping = False
        self._resume_request: tuple[int, str] | None = None
        self._done: dict[int, asyncio.Event] = {}
        self._paused_evt: dict[int, asyncio.Event] = {}
        self._left: dict[int, asyncio.Event] = {}  # resume() waits for the job's next state
        self._slicing: int | None = None  # the job the slicing worker is busy with
        self.counts = store.counts()  # jobs per state, kept in memory (status() is a read)
        self.finished = {s: self.counts[s] for s in ("completed", "failed", "cancelled",
                                                       "interrupted")}
        self.transitions = {"total": 0, "failed": 0}
        self.recovered: list[int] = []
        self._last: dict[str, Any] | None = None  # figures of the last job that printed
        self._checkpoint: asyncio.Task[None] | None = None  # the database's, on a thread
        self.checkpoints = 0
        self.waiting_for_printer = False  # a job is ready but the link is down or halted

    # -- life cycle ------------------------------------------------------------------------

    def start(self) -> None:
        for job in self.store.recover():
            self.recovered.append(job.id)
            if job.state is JobState.INTERRUPTED and job.filament_mm > 0:
                self._hold_for(job.id, "was interrupted when hostd stopped")
            if job.state is JobState.INTERRUPTED:
                self.finished["interrupted"] += 1
            log.warning("job %d %s: %s", job.id, job.state, job.reason)
        self.counts = self.store.counts()
        self._last = self._last_printed()
        self._tasks = [asyncio.create_task(self._print_loop(), name="print-loop"),
                       asyncio.create_task(self._slice_loop(), name="slice-loop")]
        for task in self._tasks:
            task.add_done_callback(_log_death)
        self._wake_print.set()
        self._wake_slice.set()

    def _last_printed(self) -> dict[str, Any] | None:
        """After a restart, the figures of the job that printed last (from the database):
        ``status()`` names it (an interrupted job to resume) as it would have before."""
        ended = [j for j in self.store.list(STOPPED, limit=20, newest=True)
                 if j.started_at is not None]
        if not ended:
            return None
        job = max(ended, key=lambda j: j.updated_at)
        total = job.total_lines
        return {"info": {"id": str(job.id), "name": job.name}, "id": job.id,
                "state": job.state.value, "progress": job.acked_lines / total if total else 0.0,
                "acked": job.acked_lines, "total": total, "subpart": job.subpart,
                "subparts_total": None, "layer": job.layer, "layers_total": None,
                "elapsed_s": job.print_seconds, "remaining_s": None,
                "filament_mm": job.filament_mm, "a": None, "c": None, "axes": {},
                "pause_reason": None}

    def alive(self) -> bool:
        """Whether the print and slice loops are running (for the watchdog)."""
        return bool(self._tasks) and not any(t.done() for t in self._tasks)

    def tasks(self) -> list[asyncio.Task[None]]:
        """The print and slice loops (read-only use: the watchdog's report)."""
        return list(self._tasks)

    async def stop(self, reason: str = "daemon stopped") -> None:
        """Stop at a safe point: the active job stops feeding after its acked lines and is
        recorded ``interrupted`` with its progress and modal state."""
        self._stopping = True
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        if self._checkpoint is not None:  # its thread must be done before the store closes
            await asyncio.gather(self._checkpoint, return_exceptions=True)
        act = self.active
        if act is not None:
            self._persist(act, force=True)
            job = self.store.get(act.job.id)
            if job.state in (JobState.PRINTING, JobState.PAUSED):
                self._set_state(job.id, JobState.INTERRUPTED,
                                f"{reason} at line {act.streamer.acked}")
                if act.streamer.modal.extruded > 0:
                    self._hold_for(job.id, "was interrupted when hostd stopped")
            self._finish_active(act)
        self.checker.close()

    # -- requests (from the control endpoints) -------------------------------------------

    async def submit(self, name: str, data: bytes, kind: str | None = None) -> Job:
        """Queue ``data``, an upload named ``name`` (see :meth:`submit_staged`)."""
        staged = self.spool.stage()
        try:
            await asyncio.to_thread(staged.write, data)
        except BaseException:
            staged.discard()
            raise
        return await self.submit_staged(name, staged, kind)

    async def submit_staged(self, name: str, staged: Staged, kind: str | None = None) -> Job:
        """Queue an upload written to the spool's staging: checked whole in the worker
        process, then stored under its digest. Afterwards the staged file is gone: stored, or
        on any error discarded."""
        try:
            if self._stopping:
                raise ShuttingDown("the daemon is shutting down")
            kind = upload_kind(name, kind)
            self.spool.check_size(staged.size, name)
            await asyncio.to_thread(staged.finish)  # on disk before the worker reads it
            summary = await self.checker.check(staged.path, kind, name)
            sha = await asyncio.to_thread(self.spool.commit, staged, SUFFIX[kind])
        finally:
            staged.discard()
        estimate, total = (summary.estimate, summary.total) if summary else ({}, 0)
        job = self.store.add(Path(name).name[:200] or "upload", kind, sha,
                             gcode_sha=sha if kind == "gcode" else None, estimate=estimate)
        self.counts[job.state.value] += 1
        self._emit_state(job, None, "submitted")
        if kind == "gcode":
            self.store.update(job.id, total_lines=total)
            self._set_state(job.id, JobState.READY, "g-code upload")
            self._wake_print.set()
        else:
            self._wake_slice.set()
        return self.store.get(job.id)

    async def pause(self, job_id: int, wait: bool = True) -> Job:
        act = self._require_active(job_id, JobState.PRINTING)
        evt = self._paused_evt.setdefault(job_id, asyncio.Event())
        act.streamer.request_pause("paused by operator")
        if wait:
            await self._wait_paused_or_done(job_id, evt)
        return self.store.get(job_id)

    async def resume(self, job_id: int, scope: str | None = None) -> Job:
        """Resume a paused job, or restart an interrupted one from ``scope`` (default
        :data:`DEFAULT_SCOPE`); returns the job once it has left that state (printing, or
        failed when it could not be resumed)."""
        job = self.store.get(job_id)
        act = self.active
        paused = act if (job.state is JobState.PAUSED and act is not None
                         and act.job.id == job_id) else None  # this job, paused on the printer
        if paused is not None and scope is not None:
            raise JobStateError(f"job {job_id} is paused: it goes on from its next line "
                                "(from is for interrupted jobs)")
        if paused is None and job.state is not JobState.INTERRUPTED:
            raise JobStateError(f"job {job_id} is {job.state}; only paused or interrupted jobs "
                                "resume")
        scope = scope or DEFAULT_SCOPE
        if scope not in RESUME_SCOPES:
            raise JobStateError(f"resume from {scope!r}: use one of {', '.join(RESUME_SCOPES)}")
        if paused is None and (self.active is not None or self._resume_request is not None):
            raise PrinterBusy("another job is on the printer")
        if self.printer is not None and not self.printer.connected:
            raise PrinterBusy("the printer is not ready (serial link down or halted): wait for "
                              "it to reconnect, or hostctl firmware-restart after a halt")
        left = self._left.setdefault(job_id, asyncio.Event())
        if paused is not None:
            paused.streamer.request_resume()
        else:
            self._resume_request = (job_id, scope)
            self._wake_print.set()
        await left.wait()
        return self.store.get(job_id)

    async def cancel(self, job_id: int, wait: bool = True) -> Job:
        job = self.store.get(job_id)
        act = self.active
        if act is not None and act.job.id == job_id:
            done = self._done.setdefault(job_id, asyncio.Event())
            act.streamer.request_cancel()
            if wait:
                await done.wait()
            return self.store.get(job_id)
        if job.state in TERMINAL:
            raise JobStateError(f"job {job_id} is already {job.state}")
        self._set_state(job_id, JobState.CANCELLED, "cancelled by operator")
        if self._slicing == job_id and self.worker is not None:
            self.worker.cancel()  # the next STL job need not wait for this slice
        return self.store.get(job_id)

    async def delete(self, job_id: int) -> Job:
        job = self.store.delete(job_id)
        if self._slicing == job_id and self.worker is not None:
            self.worker.cancel()  # its STL is about to go: no slice of it is wanted
        self.counts[job.state.value] -= 1
        if self.hold_reason is not None and self.hold_reason.startswith(f"job {job_id} "):
            self._set_hold(f"job {job_id} was deleted (its part may still be on the platform):"
                           " clear the platform, then hostctl queue start")
        self._release_waiters(job_id)
        for sha, kind in ((job.upload_sha, job.kind), (job.gcode_sha, "gcode")):
            if sha and self.store.references(sha) == 0:
                await asyncio.to_thread(self.spool.remove, sha, SUFFIX[kind])
        return job

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
        await self._done.setdefault(job_id, asyncio.Event()).wait()
        return self.store.get(job_id)

    def _require_active(self, job_id: int, state: JobState) -> Active:
        job = self.store.get(job_id)
        act = self.active
        if act is None or act.job.id != job_id or job.state is not state:
            raise JobStateError(f"job {job_id} is {job.state}, not {state}")
        return act

    async def _wait_paused_or_done(self, job_id: int, evt: asyncio.Event) -> None:
        done = self._done.setdefault(job_id, asyncio.Event())
        waiters = [asyncio.ensure_future(evt.wait()), asyncio.ensure_future(done.wait())]
        try:
            await asyncio.wait(waiters, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for w in waiters:
                w.cancel()

    # -- slicing ---------------------------------------------------------------------------

    async def _slice_loop(self) -> None:
        while True:
            await self._wake_slice.wait()
            self._wake_slice.clear()
            while (job := self._next_stl()) is not None:
                try:
                    await self._slice_one(job)
                except Exception as exc:  # a bug: this job fails, the queue goes on
                    self._fail_on_bug(job.id, "slicing", exc)

    def _state_of(self, job_id: int) -> JobState | None:
        """The job's state now, ``None`` once it is deleted."""
        try:
            return self.store.get(job_id).state
        except JobNotFound:
            return None

    def _next_stl(self) -> Job | None:
        for job in self.store.list([JobState.QUEUED]):
            if job.kind == "stl":
                return job
        return None

    async def _slice_one(self, job: Job) -> None:
        self._set_state(job.id, JobState.SLICING, "slicing")
        try:
            if self.worker is None:
                raise SliceError("no slicing worker")
            stl = self.spool.path(job.upload_sha, ".stl")
            self._slicing = job.id
            try:
                outcome = await self.worker.slice(stl, job.upload_sha, job.name)
            finally:
                self._slicing = None
            summary = await self.checker.summarize(outcome.gcode_path, job.name)
            data = await asyncio.to_thread(outcome.gcode_path.read_bytes)
            sha = await asyncio.to_thread(self.spool.put, data, ".gcode")
        except (SliceError, SpoolError, PrinterError) as exc:
            if self._state_of(job.id) is JobState.SLICING:
                self._set_state(job.id, JobState.FAILED, f"slicing failed: {exc}")
            return
        if self._state_of(job.id) is not JobState.SLICING:
            return  # cancelled or deleted meanwhile
        info = {**outcome.info, "slice_s": round(outcome.duration_s, 3),
                "cache_hit": outcome.cache_hit, "subparts": summary.subparts,
                "layers": summary.layers, "transitions": summary.transitions}
        self.store.update(job.id, gcode_sha=sha, total_lines=summary.total,
                          estimate=summary.estimate, info=info)
        self._set_state(job.id, JobState.READY, sliced_reason(outcome.info))
        self._wake_print.set()

    # -- printing --------------------------------------------------------------------------

    async def _print_loop(self) -> None:
        while True:
            await self._wake_print.wait()
            self._wake_print.clear()
            while True:
                if self._resume_request is None and not self._next_ready():
                    break
                if not await self._printer_ready():
                    continue  # the queue may have changed while the printer was away
                if self._resume_request is not None:
                    job_id, scope = self._resume_request
                    await self._contained(job_id, self._run_resumed(job_id, scope))
                    continue
                job = self.store.first(JobState.READY) if self._next_ready() else None
                if job is not None:
                    await self._contained(job.id, self._run(job, 0, None, []))

    def _next_ready(self) -> bool:
        """Whether a new job may start: one is ready and the queue is not held."""
        return self.hold_reason is None and self.store.first(JobState.READY) is not None

    # -- the queue hold --------------------------------------------------------------------

    def queue_start(self) -> dict[str, Any]:
        """The operator cleared the platform: the next ready job may start."""
        self._set_hold(None)
        self._wake_print.set()
        return self.queue_status()

    def queue_hold(self) -> dict[str, Any]:
        """No new job starts until :meth:`queue_start` (the job printing goes on)."""
        if self.hold_reason is None:
            self._set_hold("held by the operator")
        return self.queue_status()

    def queue_status(self) -> dict[str, Any]:
        return {"held": self.hold_reason is not None, "reason": self.hold_reason,
                "ready": self.counts[JobState.READY.value],
                "next_job": "after_clear" if self.hold_after_print else "at_once"}

    def _hold_for(self, job_id: int, how: str) -> None:
        """After job ``job_id`` left a part on the platform (``daemon.next_job:
        after_clear``), hold the queue until the operator clears it."""
        if not self.hold_after_print:
            return
        todo = ("resume it, or clear the platform and run hostctl queue start"
                if "interrupted" in how else "clear the platform, then hostctl queue start")
        self._set_hold(f"job {job_id} {how}: {todo}")

    def _set_hold(self, reason: str | None) -> None:
        if reason == self.hold_reason:
            return
        self.store.set_setting(HOLD_KEY, reason)
        self.hold_reason = reason
        log.info("queue %s", f"held: {reason}" if reason else "runs")
        self.bus.publish("queue.state", {"held": reason is not None, "reason": reason})

    async def _printer_ready(self) -> bool:
        """Whether the printer takes lines now; if not, wait until it does and say no.

        A job is not started on a link that is down (reconnecting) or halted (M112, a
        firmware kill): it would fail at once, and the whole queue after it. The jobs wait,
        ``ready``, until the link is back (``hostctl firmware-restart`` after a halt)."""
        if self.printer is None or self.printer.connected:
            return True
        log.warning("printer not ready: queued jobs wait for the serial link")
        self.waiting_for_printer = True
        self.bus.publish("printer.state", {"state": "waiting", "reason": "jobs wait for the "
                                           "serial link (down or halted)"})
        try:
            await self.printer.wait_connected()
        finally:
            self.waiting_for_printer = False
        log.info("printer ready: the queue goes on")
        return False

    async def _contained(self, job_id: int, run: Coroutine[Any, Any, None]) -> None:
        """Run one job; an unexpected error (a bug) fails that job, not the queue."""
        try:
            await run
        except Exception as exc:
            act = self.active
            if act is not None and act.job.id == job_id:
                self._finish_active(act)
            self._fail_on_bug(job_id, "printing", exc)

    def _fail_on_bug(self, job_id: int, stage: str, exc: Exception) -> None:
        """Log an unexpected error with its traceback and fail the job it stopped."""
        log.error("job %d: internal error while %s", job_id, stage, exc_info=exc)
        with contextlib.suppress(StoreError, JobStateError):
            if self.store.get(job_id).state not in STOPPED:
                self._set_state(job_id, JobState.FAILED,
                                f"internal error while {stage}: {exc!r} (see hostd's log)")

    async def _run_resumed(self, job_id: int, scope: str) -> None:
        try:
            job = self.store.get(job_id)
            program = await self._load_program(job)
            start, modal, prelude = await self._resume_point(job, program, scope)
        except (SpoolError, PrinterError) as exc:
            self._set_state(job_id, JobState.FAILED, f"cannot resume: {exc}")
            return
        finally:
            self._resume_request = None
        log.info("job %d resumes from %s at command %d", job_id, scope, start)
        if self.hold_reason is not None and self.hold_reason.startswith(f"job {job_id} "):
            # "...was interrupted: resume it" is done; the part stays on the platform
            self._set_hold(f"job {job_id} was resumed: when it ends, clear the platform, "
                           "then hostctl queue start")
        await self._run(job, start, modal, prelude, program=program,
                        note=f"resumed from {scope} at line {start}")

    async def _resume_point(self, job: Job, program: Program, scope: str
                            ) -> tuple[int, ModalState, list[str]]:
        """The command to resume from, the modal state before it and the restart prelude.

        The modal state is rebuilt by reading the file up to that command, on a thread: the
        event loop (status calls, other clients) does not wait for a long file to be read."""
        if scope == "checkpoint":
            cp = self.store.last_checkpoint(job.id)
            start = cp.line if cp is not None else program.resume_index(job.acked_lines,
                                                                          "subpart")
        else:
            start = program.resume_index(min(job.acked_lines, max(program.total - 1, 0)), scope)
        modal = await asyncio.to_thread(program.modal_before, start)
        s = self.settings
        prelude = [] if start == 0 else modal.restart_commands(
            safe_z(modal.position["Z"], program, s), s.travel_f, s.rotary_f, s.lift_f)
        return start, modal, prelude

    async def _load_program(self, job: Job) -> Program:
        if job.gcode_sha is None:
            raise PrinterError(f"job {job.id} has no G-code")
        data = await asyncio.to_thread(self.spool.read, job.gcode_sha, ".gcode")
        return await asyncio.to_thread(parse_upload, data, job.name)

    async def _run(self, job: Job, start: int, modal: ModalState | None, prelude: list[str],
                   program: Program | None = None, note: str = "") -> None:
        try:
            if program is None:
                program = await self._load_program(job)
        except (SpoolError, PrinterError) as exc:
            self._set_state(job.id, JobState.FAILED, str(exc))
            return
        if not self._still(job):
            return
        port = self.port_factory()
        streamer = Streamer(port, program, self.settings, self._hooks(job.id), start=start,
                            modal=modal, prelude=prelude)
        act = Active(self.store.get(job.id), program, streamer, time.monotonic(),
                     filament_base=0.0)
        self.active = act
        self._set_state(job.id, JobState.PRINTING, note or "printing")
        outcome, reason = "failed", ""
        try:
            outcome = await streamer.run()
        except FirmwareReset as exc:
            outcome, reason = "interrupted", f"firmware reset: {exc}"
        except (LinkLost, LinkError) as exc:
            outcome = "interrupted" if isinstance(exc, LinkLost) else "failed"
            reason = f"serial link: {exc}"
        except PrinterError as exc:
            reason = str(exc)
        if self._stopping:
            return  # stop() records the state
        self._persist(act, force=True)
        self._finish_active(act)
        state = {"completed": JobState.COMPLETED, "cancelled": JobState.CANCELLED,
                 "interrupted": JobState.INTERRUPTED}.get(outcome, JobState.FAILED)
        with contextlib.suppress(JobStateError):
            self._set_state(job.id, state, reason or outcome)
        if streamer.modal.extruded > 0:  # a part (or a part of one) is on the platform
            self._hold_for(job.id, {"completed": "completed", "cancelled": "was cancelled",
                                    "interrupted": "was interrupted"}.get(outcome, "failed"))

    def _still(self, job: Job) -> bool:
        """Whether ``job`` is still in the state it had when the print loop took it up: it
        may have been cancelled or deleted while its file loaded."""
        try:
            now = self.store.get(job.id).state
        except JobNotFound:
            log.info("job %d was deleted while it loaded; not printed", job.id)
            return False
        if now is not job.state:
            log.info("job %d became %s while it loaded; not printed", job.id, now)
        return now is job.state

    def _finish_active(self, act: Active) -> None:
        """The job leaves the printer; its last figures stay visible in ``status()``."""
        self._last = self._figures(act, time.monotonic())
        self.active = None

    # -- streamer hooks --------------------------------------------------------------------

    def _hooks(self, job_id: int) -> Hooks:
        return Hooks(progress=self._on_progress, paused=self._on_paused,
                     resumed=self._on_resumed, checkpoint=self._on_checkpoint,
                     event=lambda name, data: self._on_event(job_id, name, data))

    def _on_progress(self, st: Streamer) -> None:
        act = self.active
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
            self._persist(act)
        if changed or last or now - act.last_event >= EVENT_INTERVAL:
            act.last_event = now
            self.bus.publish("job.progress", self._progress(act, now))

    def _persist(self, act: Active, force: bool = False) -> None:
        st = act.streamer
        act.last_persist = time.monotonic()
        self.store.update(act.job.id, acked_lines=st.acked, subpart=st.subpart, layer=st.layer,
                          modal=st.modal.snapshot(), filament_mm=st.modal.extruded,
                          print_seconds=act.elapsed(act.last_persist))
        if self.store.claim_checkpoint() and not self._stopping and (
                self._checkpoint is None or self._checkpoint.done()):
            self._checkpoint = asyncio.create_task(self._run_checkpoint(), name="checkpoint")

    async def _run_checkpoint(self) -> None:
        """The database's checkpoint on a worker thread: its fsync never holds the loop."""
        try:
            await asyncio.to_thread(self.store.checkpoint)
        except StoreError as exc:
            log.warning("%s (the next one retries)", exc)
            return
        self.checkpoints += 1

    def _on_paused(self, st: Streamer, reason: str) -> None:
        act = self.active
        if act is None:
            return
        act.paused_at = time.monotonic()
        self._persist(act, force=True)
        self.store.update(act.job.id, modal=(st.paused_modal or st.modal).snapshot())
        self._set_state(act.job.id, JobState.PAUSED, reason)
        evt = self._paused_evt.pop(act.job.id, None)
        if evt is not None:
            evt.set()

    def _on_resumed(self, st: Streamer) -> None:
        act = self.active
        if act is None:
            return
        if act.paused_at is not None:
            act.paused_total += time.monotonic() - act.paused_at
            act.paused_at = None
        self._set_state(act.job.id, JobState.PRINTING, "resumed")

    def _on_checkpoint(self, st: Streamer, tr: Transition, pose: dict[str, float]) -> None:
        act = self.active
        if act is None:
            return
        self.transitions["total"] += 1
        self.store.add_checkpoint(act.job.id, tr.subpart, tr.parent, pose.get("A", 0.0),
                                  pose.get("C", 0.0), tr.end, pose)
        self._persist(act, force=True)

    def _on_event(self, job_id: int, name: str, data: dict[str, Any]) -> None:
        if name == "transition_failed":
            self.transitions["total"] += 1
            self.transitions["failed"] += 1
        self.bus.publish(name, {"job_id": job_id, **data})

    # -- state changes and snapshots -------------------------------------------------------

    def _set_state(self, job_id: int, new: JobState, reason: str) -> Job:
        old = self.store.get(job_id).state
        job = self.store.transition(job_id, new, reason)
        self.counts[old.value] -= 1
        self.counts[new.value] += 1
        if new.value in self.finished and new is not old:
            self.finished[new.value] += 1
        act = self.active
        if act is not None and act.job.id == job_id:
            act.job = job
        elif self._last is not None and self._last["id"] == job_id:
            self._last["state"] = new.value
        self._emit_state(job, old, reason)
        if new is not old and (left := self._left.pop(job_id, None)) is not None:
            left.set()
        if new in STOPPED:
            self._release_waiters(job_id)
        return job

    def _release_waiters(self, job_id: int) -> None:
        """Wake whoever waits for the job to stop or pause: it has stopped (or is gone)."""
        for waiting in (self._done, self._paused_evt, self._left):
            evt = waiting.pop(job_id, None)
            if evt is not None:
                evt.set()

    def _emit_state(self, job: Job, old: JobState | None, reason: str) -> None:
        level = logging.WARNING if job.state in _TROUBLE else logging.INFO
        log.log(level, "job %d %r: %s -> %s (%s)", job.id, job.name,
                "new" if old is None else old.value, job.state.value, reason)
        self.bus.publish("job.state", {"job_id": job.id, "name": job.name,
                                       "old": None if old is None else old.value,
                                       "new": job.state.value, "reason": reason})

    def _progress(self, act: Active, now: float) -> dict[str, Any]:
        st = act.streamer
        total = st.program.total
        ratio = st.acked / total if total else 1.0
        elapsed = act.elapsed(now)
        since, mark = act.rate_mark or (elapsed, ratio)
        return {"job_id": act.job.id, "acked": st.acked, "total": total,
                "progress": ratio, "subpart": st.subpart, "layer": st.layer,
                "elapsed_s": elapsed, "eta_s": eta(act.program.estimate.get("time_s"),
                                                   ratio, elapsed - since, mark),
                "filament_mm": st.modal.extruded, "state": act.job.state.value,
                "stream": st.state,
                "a": st.modal.position["A"], "c": st.modal.position["C"]}

    def job_dict(self, job: Job) -> dict[str, Any]:
        d = job.to_dict()
        act = self.active
        if act is not None and act.job.id == job.id:
            live = self._progress(act, time.monotonic())
            d.update(acked_lines=live["acked"], progress=live["progress"],
                     subpart=live["subpart"], layer=live["layer"], eta_s=live["eta_s"],
                     elapsed_s=live["elapsed_s"], filament_mm=live["filament_mm"])
        return d

    def _figures(self, act: Active, now: float) -> dict[str, Any]:
        p = self._progress(act, now)
        job = act.job
        return {"info": {"id": str(job.id), "name": job.name}, "id": job.id,
                "state": job.state.value, "progress": p["progress"],
                "acked": p["acked"], "total": p["total"],
                "subpart": p["subpart"], "subparts_total": len(act.program.subparts),
                "layer": p["layer"], "layers_total": len(act.program.layers),
                "elapsed_s": p["elapsed_s"], "remaining_s": p["eta_s"],
                "filament_mm": p["filament_mm"], "a": p["a"], "c": p["c"],
                "axes": {"A": p["a"], "C": p["c"]},
                "pause_reason": act.streamer.pause_reason}

    def status(self) -> dict[str, Any]:
        """A read-only snapshot from memory (no database access).

        ``current`` is the job on the printer (or None); ``latest`` is the same, or else the
        last job that printed since the start, with its final figures and state.
        """
        act = self.active
        current = None if act is None else self._figures(act, time.monotonic())
        latest = current if current is not None else self._last
        return {"queue_length": sum(self.counts[s.value] for s in WAITING),
                "counts": dict(self.counts), "finished": dict(self.finished),
                "transitions": dict(self.transitions), "current": current,
                "latest": None if latest is None else dict(latest),
                "recovered": list(self.recovered), "db_checkpoints": self.checkpoints,
                "waiting_for_printer": self.waiting_for_printer,
                "queue": self.queue_status(),
                "file_checks": self.checker.status()}


def _log_death(task: asyncio.Task[None]) -> None:
    """A job loop ended other than by cancellation: say why, with the traceback."""
    if not task.cancelled() and task.exception() is not None:
        log.error("the %s stopped: no more jobs run until hostd restarts", task.get_name(),
                  exc_info=task.exception())


def eta(estimate_s: float | None, ratio: float, elapsed: float, start_ratio: float
        ) -> float | None:
    """Remaining seconds: the slicer's estimate scaled by the measured/estimated rate.

    ``elapsed`` is the printing time since progress was ``start_ratio``; until 1 % more is
    done the estimate stands (None without one)."""
    done = ratio - start_ratio
    if ratio >= 1.0:
        return 0.0
    if estimate_s is None or estimate_s <= 0:
        return elapsed * (1 - ratio) / done if done > 0.01 else None
    remaining = estimate_s * (1 - ratio)
    if done <= 0.01 or elapsed <= 0:
        return remaining
    factor = elapsed / (estimate_s * done)
    return remaining * factor

