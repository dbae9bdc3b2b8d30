"""When the job database cannot be written (a full disk, a read-only or failing card).

:class:`~hostd.jobs.store.JobStore` keeps what it could not write pending and names the
error (:attr:`~hostd.jobs.store.JobStore.failure`); the guard acts on it:

- the job printing is paused (retract, lift), its reason ``storage error: ...``, so no print
  goes on that could not be resumed where it stopped;
- while the job stays paused and the writes still fail, its heaters are turned off after
  ``pause.idle_timeout`` (noted as raw G-code would be, so the resume heats them again);
- the writes are retried, with backoff, until the disk takes them: then the pending state
  is on disk, uploads are taken again and the job can be resumed, without a restart.

``status()`` names the state (``jobs.storage`` in ``hostd status --json``, the metric
``hostd_storage_failing``).
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from typing import Any

from hostd.jobs.active import Active
from hostd.jobs.joblog import log
from hostd.jobs.queue import JobQueue

REASON = "storage error"
"""How the reason of a job the guard paused starts."""
HEATERS_OFF = ("M104 S0", "M140 S0")
RETRY_MIN, RETRY_MAX = 1.0, 30.0  # s between retries of the pending writes (backoff)


class StorageGuard:
    """Pauses the job on a storage error, turns its heaters off, retries the writes."""

    def __init__(self, queue: JobQueue, idle_timeout: float) -> None:
        self.queue = queue
        self.store = queue.store
        self.idle_timeout = idle_timeout
        self.since: float | None = None  # wall time of the first refused write
        self.failed = asyncio.Event()  # wakes the retry loop
        self._heaters_off: asyncio.TimerHandle | None = None
        self.heaters_off = False  # turned off under the paused job (until it resumes)
        self._tasks: set[asyncio.Task[None]] = set()
        self.store.on_failure = self._failing

    def _failing(self) -> None:
        """The disk refused a write, the first since the last that went through."""
        if self.since is None:
            self.since = time.time()
            log.error("job database writes fail: %s; the job printing pauses, uploads are "
                      "refused until there is room again", self.store.failure)
            self.queue.bus.publish("storage", self.status())
        self.failed.set()
        self.check(self.queue.active)

    def check(self, act: Active | None) -> None:
        """While the writes fail, the job on the printer pauses (asked again if it was
        resumed meanwhile)."""
        failure = self.store.failure
        if failure is not None and act is not None and act.streamer.state == "streaming":
            act.streamer.request_pause(f"{REASON}: {failure}")

    def paused(self, act: Active) -> None:
        """The job on the printer paused: while the writes fail, its heaters go off after
        ``idle_timeout``."""
        if self.since is None or self._heaters_off is not None:
            return
        loop = asyncio.get_running_loop()
        self._heaters_off = loop.call_later(self.idle_timeout, self._turn_off, act)

    def resumed(self) -> None:
        """The job goes on: no heater is turned off under it."""
        self.heaters_off = False
        self._cancel_timer()

    def _cancel_timer(self) -> None:
        if self._heaters_off is not None:
            self._heaters_off.cancel()
            self._heaters_off = None

    def _turn_off(self, act: Active) -> None:
        self._heaters_off = None
        if act.streamer.state != "paused" or self.since is None:
            return
        task = asyncio.create_task(self._send_off(act), name="heaters-off")
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _send_off(self, act: Active) -> None:
        log.warning("job %d: paused %g s while the job database cannot be written "
                    "(pause.idle_timeout): heaters off; the resume heats them again",
                    act.job.id, self.idle_timeout)
        act.streamer.note_raw(list(HEATERS_OFF))
        for command in HEATERS_OFF:
            await act.streamer.port.query(command)
        self.heaters_off = True
        self.queue.bus.publish("storage", self.status())

    async def run(self) -> None:
        """Retry the pending writes while they fail (the task of the job manager)."""
        while True:
            await self.failed.wait()
            delay = RETRY_MIN
            while not self.store.flush():
                await asyncio.sleep(delay)  # backoff period, not synchronisation
                delay = min(delay * 2, RETRY_MAX)
            self.failed.clear()
            if self.since is not None:
                log.warning("job database writes go through again after %.0f s",
                            time.time() - self.since)
                self.since = None
                self._cancel_timer()
                self.queue.bus.publish("storage", self.status())

    def status(self) -> dict[str, Any]:
        return {"failing": self.store.failure is not None, "error": self.store.failure,
                "since": self.since, "heaters_off": self.heaters_off}

    async def close(self) -> None:
        self.resumed()
        for task in list(self._tasks):
            task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await asyncio.gather(*self._tasks, return_exceptions=True)
