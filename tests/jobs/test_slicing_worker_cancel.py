"""A cancel that comes while the slicing worker still looks in its cache stops the slice."""

from __future__ import annotations

import asyncio
import threading
from pathlib import Path

import pytest

from hostd.config.loader import load
from hostd.config.paths import DEFAULT_CONFIG
from hostd.slicing_worker import CANCELLED, SliceError, SlicingWorker


@pytest.mark.asyncio
async def test_a_cancel_during_the_cache_look_up_stops_the_slice_before_it_starts(
        tmp_path: Path) -> None:
    """The job shows ``slicing`` before the worker has looked in its cache; a cancel (or a
    delete) then found no slice running, and the slice ran to its end for nobody (the e2e
    test of it failed about one run in six)."""
    worker = SlicingWorker(tmp_path / "cache", load(DEFAULT_CONFIG).data)
    entered, release = threading.Event(), threading.Event()
    miss = worker.cache.lookup

    def slow_lookup(key: str) -> dict[str, object] | None:
        entered.set()
        release.wait(10)
        return miss(key)

    worker.cache.lookup = slow_lookup  # type: ignore[method-assign]
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
