"""The print loop: one job at a time on the printer, ready jobs first in first out, and the
resumes of interrupted jobs the operator asks for.

A job starts only while the printer takes lines (the serial link is up) and the queue is not
held. Its file is loaded, a :class:`~hostd.printer.streamer.Streamer` feeds it, and its
outcome (completed, cancelled, interrupted, failed) is recorded; a part left on the platform
holds the queue. An unexpected error (a bug) fails that job only.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Awaitable, Callable, Coroutine
from typing import Any, Protocol

from hostd.jobs.active import Active
from hostd.jobs.file_check import parse_upload
from hostd.jobs.joblog import log
from hostd.jobs.progress import ProgressRecorder
from hostd.jobs.queue import JobQueue
from hostd.jobs.resume import ResumeRefused, resume_point
from hostd.jobs.spool import Spool, SpoolError
from hostd.jobs.states import JobState, JobStateError
from hostd.jobs.store import Job, JobNotFound
from hostd.link.errors import FirmwareReset, LinkError, LinkLost
from hostd.printer.errors import PrinterError
from hostd.printer.modal import ModalState
from hostd.printer.program import Program
from hostd.printer.settings import StreamSettings
from hostd.printer.streamer import Port, Streamer

OUTCOME_STATES = {"completed": JobState.COMPLETED, "cancelled": JobState.CANCELLED,
                  "interrupted": JobState.INTERRUPTED}
"""The job's state after the streamer's outcome (any other: failed)."""
LEFT_ON_PLATFORM = {"completed": "completed", "cancelled": "was cancelled",
                    "interrupted": "was interrupted"}
"""How the queue hold names a job that left a part on the platform (any other: failed)."""
Loader = Callable[[Job], Awaitable[Program]]


class Readiness(Protocol):
    """Whether the printer takes lines (the serial link): a job starts only when it does."""

    @property
    def connected(self) -> bool: ...

    async def wait_connected(self) -> None: ...


async def load_program(spool: Spool, job: Job) -> Program:
    """The job's G-code, read from the spool and parsed on a thread."""
    if job.gcode_sha is None:
        raise PrinterError(f"job {job.id} has no G-code")
    data = await asyncio.to_thread(spool.read, job.gcode_sha, ".gcode")
    return await asyncio.to_thread(parse_upload, data, job.name)


class PrintLoop:
    """Prints the ready jobs and the resumes asked for; :meth:`run` is the loop's task."""

    def __init__(self, queue: JobQueue, recorder: ProgressRecorder,
                 port_factory: Callable[[], Port], settings: StreamSettings, load: Loader,
                 printer: Readiness | None = None,
                 resends: Callable[[], int] | None = None) -> None:
        self.queue = queue
        self.recorder = recorder
        self.port_factory = port_factory
        self.settings = settings
        self.load = load
        self.printer = printer
        self.resends = resends or (lambda: 0)
        """Lines the serial link has sent again since it started (a job's own: the change)."""
        self.resume_request: tuple[int, str] | None = None
        self.refused: dict[int, str] = {}  # job → why its resume was refused (it waits)
        self.waiting_for_printer = False  # a job is ready but the link is down or halted

    async def run(self) -> None:
        queue = self.queue
        while True:
            await queue.wake_print.wait()
            queue.wake_print.clear()
            while True:
                if self.resume_request is None and not queue.next_ready():
                    break
                if not await self._printer_ready():
                    continue  # the queue may have changed while the printer was away
                if self.resume_request is not None:
                    job_id, scope = self.resume_request
                    await self._contained(job_id, self._run_resumed(job_id, scope))
                    continue
                job = queue.store.first(JobState.READY) if queue.next_ready() else None
                if job is not None:
                    await self._contained(job.id, self.print_job(job, 0, None, []))

    def request_resume(self, job_id: int, scope: str) -> None:
        """Resume the interrupted job ``job_id`` from ``scope`` next."""
        self.resume_request = (job_id, scope)
        self.queue.wake_print.set()

    async def _printer_ready(self) -> bool:
        """Whether the printer takes lines now; if not, wait until it does and say no.

        A job is not started on a link that is down (reconnecting) or halted (M112, a
        firmware kill): it would fail at once, and the whole queue after it. The jobs wait,
        ``ready``, until the link is back (``hostctl firmware-restart`` after a halt)."""
        if self.printer is None or self.printer.connected:
            return True
        log.warning("printer not ready: queued jobs wait for the serial link")
        self.waiting_for_printer = True
        self.queue.bus.publish("printer.state", {"state": "waiting", "reason": "jobs wait for "
                                                 "the serial link (down or halted)"})
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
            act = self.queue.active
            if act is not None and act.job.id == job_id:
                self.queue.finish_active(act)
            self.queue.fail_on_bug(job_id, "printing", exc)

    async def _run_resumed(self, job_id: int, scope: str) -> None:
        queue = self.queue
        try:
            job = queue.store.get(job_id)
            program = await self.load(job)
            start, modal, prelude = await resume_point(queue.store, job, program, scope,
                                                       self.settings)
        except ResumeRefused as exc:  # the job stays interrupted; resume() says why
            self.refused[job_id] = str(exc)
            queue.release_waiters(job_id)
            return
        except (SpoolError, PrinterError) as exc:
            queue.set_state(job_id, JobState.FAILED, f"cannot resume: {exc}")
            return
        finally:
            self.resume_request = None
        log.info("job %d resumes from %s at command %d", job_id, scope, start)
        if queue.hold.names(job_id):
            # "...was interrupted: resume it" is done; the part stays on the platform
            queue.hold.set(f"job {job_id} was resumed: when it ends, clear the platform, "
                           "then hostctl queue start")
        await self.print_job(job, start, modal, prelude, program=program,
                             note=f"resumed from {scope} at line {start}")

    async def print_job(self, job: Job, start: int, modal: ModalState | None,
                        prelude: list[str], program: Program | None = None,
                        note: str = "") -> None:
        """Print ``job`` from command ``start`` (after ``prelude``) to its outcome."""
        queue = self.queue
        try:
            if program is None:
                program = await self.load(job)
        except (SpoolError, PrinterError) as exc:
            queue.set_state(job.id, JobState.FAILED, str(exc))
            return
        if not self._still(job):
            return
        streamer = Streamer(self.port_factory(), program, self.settings,
                            self.recorder.hooks(job.id), start=start, modal=modal,
                            prelude=prelude)
        act = Active(queue.store.get(job.id), program, streamer, time.monotonic(),
                     filament_base=0.0)
        queue.active = act
        queue.set_state(job.id, JobState.PRINTING, note or "printing")
        resent = self.resends()
        outcome, reason = await _stream(streamer)
        if queue.stopping:
            return  # the manager's stop() records the state
        self.recorder.persist(act, force=True)
        self._record_summary(act, max(0, self.resends() - resent))
        queue.finish_active(act)
        with contextlib.suppress(JobStateError):
            queue.set_state(job.id, OUTCOME_STATES.get(outcome, JobState.FAILED),
                            reason or outcome)
        if streamer.modal.extruded > 0:  # a part (or a part of one) is on the platform
            queue.hold.after(job.id, LEFT_ON_PLATFORM.get(outcome, "failed"))

    def _record_summary(self, act: Active, resends: int) -> None:
        """The end-of-job summary (:func:`job_summary`), kept in the job's ``info``."""
        store = self.queue.store
        job = store.get(act.job.id)
        summary = job_summary(act, time.monotonic(), len(store.checkpoints(job.id)), resends)
        store.update(job.id, info={**job.info, "summary": summary})

    def _still(self, job: Job) -> bool:
        """Whether ``job`` is still in the state it had when the print loop took it up: it
        may have been cancelled or deleted while its file loaded."""
        try:
            now = self.queue.store.get(job.id).state
        except JobNotFound:
            log.info("job %d was deleted while it loaded; not printed", job.id)
            return False
        if now is not job.state:
            log.info("job %d became %s while it loaded; not printed", job.id, now)
        return now is job.state


def job_summary(act: Active, now: float, transitions: int, resends: int) -> dict[str, Any]:
    """What a job took, as it ended: filament fed (mm) and its mass (g, scaled from the
    slicer's estimate; ``None`` without one), print time (s, pauses left out), the
    sub-parts of its file, the transitions it passed and the lines the link sent again."""
    est = act.program.estimate
    filament = float(act.streamer.modal.extruded)
    per_mm = (float(est["mass_g"]) / float(est["filament_mm"])
              if est.get("mass_g") and est.get("filament_mm") else None)
    return {"filament_mm": round(filament, 1),
            "mass_g": None if per_mm is None else round(filament * per_mm, 2),
            "time_s": round(act.elapsed(now), 1), "subparts": len(act.program.subparts),
            "transitions": transitions, "transitions_planned": len(act.program.transitions),
            "resends": resends}


async def _stream(streamer: Streamer) -> tuple[str, str]:
    """Run the streamer to its end: the outcome and, for a failure, why."""
    try:
        return await streamer.run(), ""
    except FirmwareReset as exc:
        return "interrupted", f"firmware reset: {exc}"
    except (LinkLost, LinkError) as exc:
        return ("interrupted" if isinstance(exc, LinkLost) else "failed"), f"serial link: {exc}"
    except PrinterError as exc:
        return "failed", str(exc)
