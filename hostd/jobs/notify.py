"""The operator's hook (``notify.command``): run when a job completes, fails or pauses, with
the job's JSON (as ``job.get`` gives it) on its standard input.

The command runs through ``/bin/sh -c`` with ``HOSTD_JOB_ID``, ``HOSTD_JOB_STATE`` and
``HOSTD_JOB_NAME`` in its environment, as the daemon's user, and never holds the daemon up:
it is started on the event loop and waited for in a task of its own. One that runs past
``notify.timeout`` is killed; one that fails or is killed is logged as a warning with the
first line of what it wrote on stderr.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
from collections.abc import Callable
from typing import Any

from hostd.events import EventBus

log = logging.getLogger(__name__)

NOTIFY_STATES = frozenset({"completed", "failed", "paused"})
"""The job states that run the hook."""
STDERR_KEPT = 4096
"""Bytes of the hook's stderr kept for the log."""


class Notifier:
    """Runs ``command`` for each job that enters one of :data:`NOTIFY_STATES`.

    Parameters
    ----------
    command
        A shell command line; empty: no hook.
    describe
        The job's JSON by id (``job.get``'s).
    timeout
        Seconds the command may run.
    """

    def __init__(self, bus: EventBus, command: str, describe: Callable[[int], dict[str, Any]],
                 timeout: float = 30.0) -> None:
        self.command = command
        self.describe = describe
        self.timeout = timeout
        self.runs = 0
        self.failures = 0
        self._tasks: set[asyncio.Task[None]] = set()
        self._unsubscribe = (bus.subscribe(self._on_state, ("job.state",)) if command
                             else (lambda: None))

    def _on_state(self, name: str, data: dict[str, Any]) -> None:
        state = data.get("new")
        if state not in NOTIFY_STATES or data.get("old") == state:
            return
        job_id = int(data["job_id"])
        try:
            job = self.describe(job_id)
        except Exception as exc:  # a job deleted at once: nothing to tell
            log.warning("notify.command: job %d: %s", job_id, exc)
            return
        task = asyncio.get_running_loop().create_task(self.run(job, str(state)))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def run(self, job: dict[str, Any], state: str) -> None:
        """Run the command for ``job`` (now ``state``) to its end or the timeout."""
        self.runs += 1
        env = {**os.environ, "HOSTD_JOB_ID": str(job.get("id")), "HOSTD_JOB_STATE": state,
               "HOSTD_JOB_NAME": str(job.get("name"))}
        stdin = json.dumps(job, sort_keys=True).encode() + b"\n"
        try:
            proc = await asyncio.create_subprocess_shell(
                self.command, stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.DEVNULL,
                stderr=asyncio.subprocess.PIPE, env=env, start_new_session=True)
        except OSError as exc:
            self._failed(job, f"cannot start: {exc.strerror or exc}")
            return
        try:
            _, err = await asyncio.wait_for(proc.communicate(stdin), self.timeout)
        except TimeoutError:
            with contextlib.suppress(ProcessLookupError):
                proc.kill()
            await proc.wait()
            self._failed(job, f"killed after notify.timeout ({self.timeout:g} s)")
            return
        except asyncio.CancelledError:  # the daemon stops: the hook goes with it
            with contextlib.suppress(ProcessLookupError):
                proc.kill()
            raise
        if proc.returncode:
            first = err[:STDERR_KEPT].decode("utf-8", "replace").strip().splitlines()
            self._failed(job, f"exit status {proc.returncode}"
                         + (f": {first[0]}" if first else ""))

    def _failed(self, job: dict[str, Any], why: str) -> None:
        self.failures += 1
        log.warning("notify.command for job %s (%s): %s", job.get("id"), job.get("state"), why)

    async def close(self) -> None:
        """Stop listening; hooks still running are cancelled (their processes killed)."""
        self._unsubscribe()
        for task in list(self._tasks):
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)

    def status(self) -> dict[str, Any]:
        return {"command": bool(self.command), "runs": self.runs, "failures": self.failures,
                "running": len(self._tasks)}
