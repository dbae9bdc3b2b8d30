"""A storage error mid-print interrupts the job safely (issue 38, item 2), with an injected
one here (the job database's writes refused as SQLite refuses them on a full disk);
``tests/daemon/test_full_disk.py`` fills a real tmpfs under a running daemon.

The print loop used to die on the first refused write: the job stayed ``printing`` in the
database while status said none was, its heaters stayed on, pause and resume were refused
and only a restart recovered. Now the job pauses (its reason names the error), its heaters
go off after ``pause.idle_timeout``, status and metrics name the state, uploads are refused
in one line, and once the disk takes writes again everything pending is written and the job
resumes, without a restart."""

from __future__ import annotations

import asyncio
import sqlite3
from pathlib import Path
from typing import Any

import pytest
from test_manager_races import MARKS, AckingPort

from hostd.events import EventBus
from hostd.jobs import storage
from hostd.jobs.manager import JobManager
from hostd.jobs.spool import Spool
from hostd.jobs.states import JobState, JobStateError
from hostd.jobs.store import JobStore, StoreError
from hostd.printer.streamer import StreamSettings

FULL = "database or disk is full"


class Disk:
    """The job database's connection, whose writes fail as SQLite's do while ``full``."""

    def __init__(self, db: sqlite3.Connection) -> None:
        self.db = db
        self.full = False

    def _refuse(self, sql: str) -> None:
        if self.full and sql.lstrip().split()[0].upper() in ("INSERT", "UPDATE", "DELETE"):
            raise sqlite3.OperationalError(FULL)

    def execute(self, sql: str, *args: Any) -> sqlite3.Cursor:
        self._refuse(sql)
        return self.db.execute(sql, *args)

    def executemany(self, sql: str, rows: Any) -> sqlite3.Cursor:
        self._refuse(sql)
        return self.db.executemany(sql, rows)

    def __enter__(self) -> Disk:
        self.db.__enter__()
        return self

    def __exit__(self, *exc: Any) -> Any:
        return self.db.__exit__(*exc)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.db, name)


class SlowPort(AckingPort):
    """Acknowledges a line every 2 ms, one after the other, so that a job takes a while."""

    def __init__(self, log: list[str]) -> None:
        super().__init__(log)
        self.free_at = 0.0

    def submit(self, command: str) -> asyncio.Future[None]:
        self.log.append(command)
        self.fw.apply(command)
        loop = asyncio.get_running_loop()
        fut = loop.create_future()
        self.free_at = max(self.free_at, loop.time()) + 0.002
        loop.call_at(self.free_at, self._ack, fut, len(self.log))
        return fut


@pytest.mark.asyncio
@pytest.mark.timeout(60)
async def test_a_full_disk_pauses_the_job_turns_the_heaters_off_and_recovers(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(storage, "RETRY_MIN", 0.05)
    wire: list[str] = []
    store = JobStore(tmp_path / "jobs.db")
    disk = Disk(store._db)
    store._db = disk  # type: ignore[assignment]
    mgr = JobManager(store, Spool(tmp_path / "spool", 1 << 20), None,
                     lambda: SlowPort(wire), EventBus(), StreamSettings(idle_timeout=0.2))
    text = "M140 S60\nM104 S200\nG90\nM83\n" + "".join(
        f"G1 X{i % 50} Y{MARKS['x']} E0.1 F600\n" for i in range(400))
    job = await mgr.submit("long.gcode", text.encode(), "gcode")
    events: asyncio.Queue[tuple[str, dict[str, Any]]] = asyncio.Queue()
    mgr.bus.subscribe(lambda name, data: events.put_nowait((name, data)))
    mgr.start()
    async with asyncio.timeout(30):
        await _until(events, lambda n, d: n == "job.progress" and d["progress"] > 0.2)
        disk.full = True
        paused = await _until(events, lambda n, d: n == "job.state" and d["new"] == "paused")
        assert paused["reason"] == f"storage error: job database {store.path}: {FULL}"
        assert mgr.status()["storage"]["failing"] is True
        assert mgr.status()["current"]["state"] == "paused"  # a job on the printer, paused
        await _until(events, lambda n, d: n == "storage" and d["heaters_off"])
        assert wire[-2:] == ["M104 S0", "M140 S0"]  # after pause.idle_timeout (0.2 s)
        with pytest.raises(StoreError, match=f"a new job cannot be stored: .*{FULL}$"):
            await mgr.submit("next.gcode", b"G28\n", "gcode")
        with pytest.raises(JobStateError, match="cannot go on while the job database cannot "
                                                "be written"):
            await mgr.resume(job.id)
        disk.full = False
        await _until(events, lambda n, d: n == "storage" and not d["failing"])
        assert not disk.full and JobStore(tmp_path / "jobs.db").get(job.id).state is \
            JobState.PAUSED  # what was pending is on disk now
        await mgr.resume(job.id)
        done = await mgr.wait_finished(job.id)
    assert done.state is JobState.COMPLETED
    resumed = wire[wire.index("M140 S0") + 1:]
    assert "M190 S60" in resumed and "M109 S200" in resumed  # heated again before going on
    assert mgr.alive()
    await mgr.stop()


async def _until(events: asyncio.Queue[tuple[str, dict[str, Any]]], pred: Any
                 ) -> dict[str, Any]:
    while True:
        name, data = await events.get()
        if pred(name, data):
            return data
