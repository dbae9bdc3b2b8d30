"""A cancel that comes while the slicing worker still looks in its cache stops the slice; a
worker ended after it wrote its files leaves none of them in the cache."""

from __future__ import annotations

import asyncio
import threading
from pathlib import Path

import pytest

from hostd.config.loader import load
from hostd.config.paths import DEFAULT_CONFIG
from hostd.slicing_worker import CANCELLED, SliceError, SlicingWorker, picture_path
from hostd.worker_process import WorkerDied


@pytest.mark.asyncio
@pytest.mark.parametrize("look_up", ["lookup", "refusal"])
async def test_a_cancel_during_the_cache_look_up_stops_the_slice_before_it_starts(
        tmp_path: Path, look_up: str) -> None:
    """The job shows ``slicing`` before the worker has looked in its cache (for a file, then
    for a kept refusal); a cancel (or a delete) then found no slice running, and the slice
    ran to its end for nobody (the e2e test of it failed about one run in six; during the
    refusal's look-up, on a busy machine, the slice of a deleted job failed on its STL and
    counted as a failure)."""
    worker = SlicingWorker(tmp_path / "cache", load(DEFAULT_CONFIG).data)
    entered, release = threading.Event(), threading.Event()
    miss = getattr(worker.cache, look_up)

    def slow_look_up(key: str) -> object:
        entered.set()
        release.wait(10)
        return miss(key)

    setattr(worker.cache, look_up, slow_look_up)
    stl = tmp_path / "part.stl"
    stl.write_bytes(b"solid x\nendsolid x\n")
    async with asyncio.timeout(20):
        task = asyncio.create_task(worker.slice(stl, "0" * 64, "part.stl"))
        await asyncio.to_thread(entered.wait, 10)
        assert worker.cancel() is True
        release.set()
        with pytest.raises(SliceError) as info:
            await task
    assert str(info.value) == CANCELLED
    assert not worker.process.started  # no worker was spawned for it
    assert (worker.cancelled, worker.failures, worker.active) == (1, 0, 0)
    worker.close()


@pytest.mark.asyncio
@pytest.mark.parametrize("how", ["cancelled", "died", "returned after a cancel"])
async def test_a_worker_ended_after_writing_its_files_leaves_nothing_in_the_cache(
        tmp_path: Path, how: str) -> None:
    """The worker renames its G-code into place and draws the pictures beside it before it
    returns; a cancel (or a death) in between ended it with those files written and no info
    kept, and they stayed in the cache (the e2e cancel test found a cancelled slice's
    G-code and pictures there on a busy machine). Here the worker's call writes them, then
    raises :class:`WorkerDied` when it is ended, as the process pool's call does, or
    returns all the same (the cancel came as it finished)."""
    worker = SlicingWorker(tmp_path / "cache", load(DEFAULT_CONFIG).data)
    wrote, ended = asyncio.Event(), asyncio.Event()

    async def run(stl_path: Path, out: Path, *args: object) -> dict[str, object]:
        out.write_text("G1 X1\n")
        Path(f"{out}.123.tmp").write_text("G1")
        for which in ("decomposition", "toolpaths"):
            picture_path(out, which).write_bytes(b"png")
        wrote.set()
        await ended.wait()
        if how == "returned after a cancel":
            return {"lines": 1}
        raise WorkerDied("the worker process died")

    worker._run = run  # type: ignore[method-assign,assignment]
    stl = tmp_path / "part.stl"
    stl.write_bytes(b"solid x\nendsolid x\n")
    cache = tmp_path / "cache"
    async with asyncio.timeout(20):
        task = asyncio.create_task(worker.slice(stl, "0" * 64, "part.stl"))
        await wrote.wait()
        assert sorted(p.name.split(".", 1)[1] for p in cache.iterdir()) == [
            "decomposition.png", "gcode", "gcode.123.tmp", "toolpaths.png"]
        if how != "died":
            assert worker.cancel() is True
        ended.set()
        with pytest.raises(SliceError) as info:
            await task
    assert (str(info.value) == CANCELLED) is (how != "died")
    assert sorted(cache.iterdir()) == []
    assert (worker.cancelled, worker.failures) == ((0, 1) if how == "died" else (1, 0))
    assert worker.cache_hits == 0 and worker.active == 0
    worker.close()


@pytest.mark.asyncio
async def test_an_error_of_a_slice_being_cancelled_is_the_cancel_not_a_failure(
        tmp_path: Path) -> None:
    """Deleting a slicing job removes its STL as the worker is ended; a worker that got to
    read the file first failed on it, and its error counted as a slicer failure (the e2e
    delete test, on a busy machine: ``failures`` 1)."""
    worker = SlicingWorker(tmp_path / "cache", load(DEFAULT_CONFIG).data)
    started, ended = asyncio.Event(), asyncio.Event()

    async def run(stl_path: Path, *args: object) -> dict[str, object]:
        started.set()
        await ended.wait()
        raise SliceError(f"part.stl: cannot read {stl_path}: No such file or directory")

    worker._run = run  # type: ignore[method-assign,assignment]
    stl = tmp_path / "part.stl"
    stl.write_bytes(b"solid x\nendsolid x\n")
    async with asyncio.timeout(20):
        task = asyncio.create_task(worker.slice(stl, "0" * 64, "part.stl"))
        await started.wait()
        assert worker.cancel() is True
        ended.set()
        with pytest.raises(SliceError) as info:
            await task
    assert str(info.value) == CANCELLED
    assert (worker.cancelled, worker.failures, worker.active) == (1, 0, 0)
    worker.close()
