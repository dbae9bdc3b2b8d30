"""The job queue keeps going: a job cancelled or deleted while its file loads is not printed,
an unexpected error fails only its own job, and ``job.wait`` returns for every stopped job."""

from __future__ import annotations

import asyncio
import logging
from pathlib import Path
from typing import Any

import pytest

from hostd.events import EventBus
from hostd.jobs.manager import JobManager
from hostd.jobs.spool import Spool
from hostd.jobs.states import JobState
from hostd.jobs.store import Job, JobNotFound, JobStore
from hostd.link.replies import HeaterReading, Position, Temperatures
from hostd.printer.modal import ModalState
from hostd.printer.program import Program
from hostd.printer.streamer import StreamSettings


class AckingPort:
    """Executes every line in order and acknowledges it on the next loop turn."""

    def __init__(self, log: list[str]) -> None:
        self.log = log
        self.fw = ModalState()
        self.acks = 0

    def submit(self, command: str) -> asyncio.Future[None]:
        self.log.append(command)
        self.fw.apply(command)
        fut = asyncio.get_running_loop().create_future()
        asyncio.get_running_loop().call_soon(self._ack, fut, len(self.log))
        return fut

    def _ack(self, fut: asyncio.Future[None], seq: int) -> None:
        self.acks = max(self.acks, seq)  # the submission number of the last line acked
        fut.set_result(None)

    def submit_many(self, commands: list[str]) -> tuple[int, asyncio.Future[None]]:
        first = len(self.log) + 1
        return first, [self.submit(c) for c in commands][-1]

    def withdraw(self, first: int, last: int) -> int:
        return 0  # every line goes out as it is submitted

    def acknowledged(self) -> int:
        return self.acks

    async def query(self, command: str) -> tuple[Any, ...]:
        self.log.append(command)
        if command == "M114":
            return (Position({k: self.fw.position[k] for k in "XYZAC"}),)
        return (Temperatures({"T": HeaterReading(self.fw.hotend, self.fw.hotend)}),)


class GatedManager(JobManager):
    """Holds the chosen jobs' file loads until :attr:`gate` opens; a load that raises
    ``boom`` for the jobs in :attr:`broken`."""

    def __init__(self, tmp_path: Path, wire: list[str]) -> None:
        super().__init__(JobStore(tmp_path / "jobs.db"), Spool(tmp_path / "spool", 1 << 20),
                         None, lambda: AckingPort(wire), EventBus(), StreamSettings())
        self.gated: set[int] = set()
        self.broken: set[int] = set()
        self.loading = asyncio.Event()
        self.gate = asyncio.Event()

    async def _load_program(self, job: Job) -> Program:
        if job.id in self.broken:
            raise RuntimeError("boom")
        if job.id in self.gated:
            self.loading.set()
            await self.gate.wait()
        return await super()._load_program(job)


MARKS = {"first": 11, "second": 22, "stopped": 33, "after": 44, "bad": 55, "good": 66, "x": 77}
"""Each job's name and the Y it alone moves to, which marks its lines on the wire."""


def add_job(mgr: JobManager, name: str, state: JobState = JobState.READY) -> Job:
    """A G-code job, straight into the store in ``state`` (ready, or interrupted)."""
    text = f"G90\nG1 X1 Y{MARKS[name]} F600\nG1 X2\n".encode()
    sha = mgr.spool.put(text, ".gcode")
    job = mgr.store.add(f"{name}.gcode", "gcode", sha, gcode_sha=sha)
    mgr.store.update(job.id, total_lines=3)
    path = [JobState.READY] if state is JobState.READY else [
        JobState.READY, JobState.PRINTING, JobState.INTERRUPTED]
    for s in path:
        mgr.store.transition(job.id, s)
    mgr.counts = mgr.store.counts()
    return mgr.store.get(job.id)


def printed(wire: list[str], name: str) -> bool:
    return any(f"Y{MARKS[name]} " in line for line in wire)


@pytest.mark.asyncio
@pytest.mark.timeout(30)
@pytest.mark.parametrize("action", ["cancel", "delete"])
async def test_a_job_cancelled_or_deleted_while_it_loads_is_not_printed(
        tmp_path: Path, action: str):
    wire: list[str] = []
    mgr = GatedManager(tmp_path, wire)
    first = add_job(mgr, "first")
    mgr.gated.add(first.id)
    mgr.start()
    async with asyncio.timeout(10):
        await mgr.loading.wait()
        if action == "cancel":
            assert (await mgr.cancel(first.id)).state is JobState.CANCELLED
        else:
            await mgr.delete(first.id)
        second = add_job(mgr, "second")
        mgr.gate.set()
        mgr._wake_print.set()
        done = await mgr.wait_finished(second.id)
    assert done.state is JobState.COMPLETED
    assert mgr.alive() and mgr.active is None
    assert not printed(wire, "first") and printed(wire, "second")
    if action == "cancel":
        assert mgr.store.get(first.id).state is JobState.CANCELLED
    else:
        with pytest.raises(JobNotFound):
            mgr.store.get(first.id)
    await mgr.stop()


@pytest.mark.asyncio
@pytest.mark.timeout(30)
async def test_an_interrupted_job_cancelled_while_its_resume_loads_stays_cancelled(
        tmp_path: Path):
    wire: list[str] = []
    mgr = GatedManager(tmp_path, wire)
    stopped = add_job(mgr, "stopped", JobState.INTERRUPTED)
    mgr.gated.add(stopped.id)
    mgr.start()
    async with asyncio.timeout(10):
        resuming = asyncio.create_task(mgr.resume(stopped.id, "layer"))
        await mgr.loading.wait()
        await mgr.cancel(stopped.id)
        assert (await resuming).state is JobState.CANCELLED  # resume answers with the outcome
        after = add_job(mgr, "after")
        mgr.gate.set()
        mgr._wake_print.set()
        assert (await mgr.wait_finished(after.id)).state is JobState.COMPLETED
    assert mgr.store.get(stopped.id).state is JobState.CANCELLED
    assert not printed(wire, "stopped") and mgr.alive()
    await mgr.stop()


@pytest.mark.asyncio
@pytest.mark.timeout(30)
async def test_an_unexpected_error_fails_its_job_and_the_queue_goes_on(
        tmp_path: Path, caplog: pytest.LogCaptureFixture):
    wire: list[str] = []
    mgr = GatedManager(tmp_path, wire)
    bad, good = add_job(mgr, "bad"), add_job(mgr, "good")
    mgr.broken.add(bad.id)
    with caplog.at_level(logging.ERROR, logger="hostd.jobs.manager"):
        mgr.start()
        async with asyncio.timeout(10):
            failed = await mgr.wait_finished(bad.id)
            completed = await mgr.wait_finished(good.id)
    assert failed.state is JobState.FAILED and "internal error" in failed.reason
    assert "RuntimeError('boom')" in failed.reason
    assert completed.state is JobState.COMPLETED and printed(wire, "good")
    assert any(r.exc_info and "boom" in str(r.exc_info[1]) for r in caplog.records)
    assert mgr.alive() and mgr.active is None
    await mgr.stop()


@pytest.mark.asyncio
@pytest.mark.timeout(30)
async def test_wait_returns_at_once_for_an_interrupted_job(tmp_path: Path):
    mgr = GatedManager(tmp_path, [])
    job = add_job(mgr, "x", JobState.INTERRUPTED)
    async with asyncio.timeout(5):
        assert (await mgr.wait_finished(job.id)).state is JobState.INTERRUPTED


@pytest.mark.asyncio
@pytest.mark.timeout(30)
async def test_wait_on_no_job_fails_and_keeps_nothing(tmp_path: Path):
    mgr = GatedManager(tmp_path, [])
    for missing in range(100, 150):
        with pytest.raises(JobNotFound):
            await mgr.wait_finished(missing)
    assert mgr._done == {}


@pytest.mark.asyncio
@pytest.mark.timeout(30)
async def test_a_waiter_learns_that_its_job_was_deleted(tmp_path: Path):
    mgr = GatedManager(tmp_path, [])  # not started: the job stays ready
    job = add_job(mgr, "x")
    waiter = asyncio.create_task(mgr.wait_finished(job.id))
    async with asyncio.timeout(5):
        while job.id not in mgr._done:  # the waiter is registered on its first step
            await asyncio.sleep(0)
        await mgr.delete(job.id)
        with pytest.raises(JobNotFound):
            await waiter
    assert mgr._done == {}


@pytest.mark.asyncio
@pytest.mark.timeout(30)
async def test_deleting_a_job_removes_its_file_once_no_other_job_uses_it(tmp_path: Path):
    mgr = GatedManager(tmp_path, [])
    first, second = add_job(mgr, "x"), add_job(mgr, "x")  # the same file twice
    other = add_job(mgr, "good")
    assert first.gcode_sha == second.gcode_sha != other.gcode_sha

    def kept(job: Job) -> bool:
        assert job.gcode_sha is not None
        return mgr.spool.path(job.gcode_sha, ".gcode", must_exist=False).exists()

    async with asyncio.timeout(5):
        await mgr.cancel(first.id)
        await mgr.delete(first.id)
        assert kept(second) and kept(other)
        await mgr.cancel(second.id)
        await mgr.delete(second.id)
    assert not kept(second) and kept(other)
    assert mgr.status()["counts"]["cancelled"] == 0


@pytest.mark.asyncio
@pytest.mark.timeout(30)
async def test_an_interrupted_job_without_markers_goes_on_from_its_acknowledged_line(
        tmp_path: Path):
    from hostd.jobs.states import JobStateError

    wire: list[str] = []
    mgr = GatedManager(tmp_path, wire)
    stopped = add_job(mgr, "stopped", JobState.INTERRUPTED)  # G90, G1 X1 Y33, G1 X2
    mgr.store.update(stopped.id, acked_lines=2)
    mgr.start()
    async with asyncio.timeout(10):
        with pytest.raises(JobStateError, match="no ;HOSTD_LAYER markers"):
            await mgr.resume(stopped.id, "subpart")
        assert mgr.store.get(stopped.id).state is JobState.INTERRUPTED and wire == []
        await mgr.resume(stopped.id, "layer")
        done = await mgr.wait_finished(stopped.id)
    assert done.state is JobState.COMPLETED
    assert not printed(wire, "stopped")  # its first move is not printed again
    assert wire[0] == "G28" and "G1 X2" in wire
    await mgr.stop()


class HeldPort(AckingPort):
    """Lines go out at once and are acknowledged only as far as the test says, one by one."""

    def __init__(self, log: list[str], sent: int) -> None:
        super().__init__(log)
        self.futs: list[tuple[int, asyncio.Future[None]]] = []
        self.enough = asyncio.Event()  # ``sent`` lines are out
        self.sent = sent

    def submit(self, command: str) -> asyncio.Future[None]:
        self.log.append(command)
        fut = asyncio.get_running_loop().create_future()
        self.futs.append((len(self.log), fut))
        if len(self.log) >= self.sent:
            self.enough.set()
        return fut

    def ack_through(self, seq: int) -> None:
        self.acks = seq
        for number, fut in self.futs:
            if number <= seq and not fut.done():
                fut.set_result(None)


@pytest.mark.asyncio
@pytest.mark.timeout(30)
async def test_an_interrupted_job_records_the_firmwares_last_acknowledged_line(
        tmp_path: Path):
    """The streamer takes note of acknowledgements a batch (32 lines) at a time; the line
    recorded when the job is interrupted is the link's, to the line."""
    wire: list[str] = []
    port = HeldPort(wire, sent=64)
    mgr = JobManager(JobStore(tmp_path / "jobs.db"), Spool(tmp_path / "spool", 1 << 20), None,
                     lambda: port, EventBus(), StreamSettings(lookahead=64))
    text = "G90\n" + "".join(f"G1 X{i % 50} Y{MARKS['x']} F600\n" for i in range(200))
    sha = mgr.spool.put(text.encode(), ".gcode")
    job = mgr.store.add("long.gcode", "gcode", sha, gcode_sha=sha)
    mgr.store.update(job.id, total_lines=201)
    mgr.store.transition(job.id, JobState.READY)
    mgr.counts = mgr.store.counts()
    mgr.start()
    async with asyncio.timeout(10):
        await port.enough.wait()  # two batches out, none acknowledged
        port.ack_through(45)  # the first batch and 13 lines of the second
        await mgr.stop()
    stopped = mgr.store.get(job.id)
    assert stopped.state is JobState.INTERRUPTED
    assert stopped.acked_lines == 45 and stopped.reason.endswith("at line 45")
