"""The job database's checkpoints run on a worker thread while progress is written."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import pytest

from hostd.events import EventBus
from hostd.jobs.active import Active
from hostd.jobs.manager import JobManager
from hostd.jobs.spool import Spool
from hostd.jobs.store import JobStore
from hostd.printer.program import parse_program
from hostd.printer.streamer import Streamer, StreamSettings


def _manager(tmp_path: Path, changes: int) -> tuple[JobManager, Active]:
    store = JobStore(tmp_path / "jobs.db", checkpoint_changes=changes)
    manager = JobManager(store, Spool(tmp_path / "spool", 1 << 20), None, lambda: None,
                         EventBus(), StreamSettings())
    program = parse_program("G90\nG1 X1 Y1 Z0.2\nG1 X2 Y2\n")
    job = store.add("part.gcode", "gcode", "0" * 64)
    streamer = Streamer(None, program, StreamSettings())  # type: ignore[arg-type]
    return manager, Active(job, program, streamer, time.monotonic())


@pytest.mark.asyncio
@pytest.mark.timeout(30)
async def test_progress_writes_leave_the_checkpoint_to_a_worker_thread(tmp_path: Path):
    manager, act = _manager(tmp_path, changes=20)
    threads: list[int] = []
    checkpoint = manager.store.checkpoint

    def noted() -> tuple[int, int]:
        threads.append(threading.get_ident())
        return checkpoint()

    manager.store.checkpoint = noted  # type: ignore[method-assign]
    for n in range(100):
        act.streamer.acked = n % 3
        manager._persist(act)
        task = manager._checkpoint
        if task is not None and not task.done():
            # progress is written a quarter second apart, far longer than a checkpoint takes
            await task
    await manager.stop()
    assert manager.checkpoints == len(threads) == 5  # one per 20 rows written
    assert threading.get_ident() not in threads
    assert manager.status()["db_checkpoints"] == manager.checkpoints
    frames, copied = manager.store.checkpoint()
    assert frames <= 20 and copied == frames  # each checkpoint let the log start afresh


@pytest.mark.asyncio
@pytest.mark.timeout(30)
async def test_a_failed_checkpoint_is_logged_and_the_next_one_retries(
        tmp_path: Path, caplog: Any):
    manager, act = _manager(tmp_path, changes=5)
    path = manager.store.path
    manager.store.path = str(tmp_path / "missing" / "jobs.db")
    for _ in range(6):
        manager._persist(act)
    assert manager._checkpoint is not None
    await manager._checkpoint
    assert manager.checkpoints == 0 and "checkpoint failed" in caplog.text
    manager.store.path = path
    for _ in range(6):
        manager._persist(act)
    await manager.stop()  # waits for the checkpoint's thread
    assert manager.checkpoints == 1
