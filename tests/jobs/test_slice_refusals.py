"""The slicer's refusals are kept with the slice cache: the same file sent again is refused
at once, under its new name, while a bad file or a cancelled slice is tried again."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import pytest

import slicer.pipeline
from hostd.config.loader import load
from hostd.config.paths import DEFAULT_CONFIG
from hostd.slicing_worker import (
    SliceError,
    SliceOptions,
    SliceRefused,
    SlicingWorker,
    slice_in_worker,
)
from slicer.decompose import DecompositionError
from slicer.mesh import MeshError

WALLS = ("replay found 3 unsupported wall layers over air (...); refusing to write the file: "
         "worst sub-part 1 layer 6")


class Recorded(SlicingWorker):
    """A worker whose slices raise what the test says, in order, counting them."""

    def __init__(self, root: Path, outcomes: list[Exception]) -> None:
        super().__init__(root / "cache", load(DEFAULT_CONFIG).data)
        self.outcomes, self.runs = outcomes, 0

    async def _run(self, stl_path: Path, out: Path, name: str | None, options: SliceOptions,
                   on_progress: Any) -> dict[str, Any]:
        self.runs += 1
        raise self.outcomes.pop(0)


async def _refusal(worker: SlicingWorker, stl: Path, name: str,
                   options: SliceOptions | None = None) -> SliceError:
    with pytest.raises(SliceError) as info:
        await worker.slice(stl, "a" * 64, name, options)
    return info.value


@pytest.mark.asyncio
async def test_a_refusal_is_kept_and_served_again_under_the_new_uploads_name(tmp_path: Path
                                                                              ) -> None:
    stl = tmp_path / "part.stl"
    stl.write_bytes(b"solid x\nendsolid x\n")
    worker = Recorded(tmp_path, [SliceRefused(f"t: {WALLS}"), SliceRefused("other")])
    async with asyncio.timeout(20):
        first = await _refusal(worker, stl, "t")  # a short name: only the line's own is new
        again = await _refusal(worker, stl, "tee (2).stl")
        # the job that allows walls over air has another key: sliced, not refused from it
        allowed = await _refusal(worker, stl, "t", SliceOptions(allow_overhang=True))
    assert isinstance(first, SliceRefused) and str(first) == f"t: {WALLS}"
    assert isinstance(again, SliceRefused) and str(again) == f"tee (2).stl: {WALLS}"
    assert str(allowed) == "other"
    assert (worker.runs, worker.cache_hits, worker.failures) == (2, 1, 3)
    worker.close()


@pytest.mark.asyncio
async def test_an_error_that_is_no_refusal_is_not_kept(tmp_path: Path) -> None:
    """A file the slicer cannot read (or a worker that died) is sliced again next time: the
    operator may have mended the file's spool copy or the machine's memory."""
    stl = tmp_path / "part.stl"
    stl.write_bytes(b"solid x\nendsolid x\n")
    worker = Recorded(tmp_path, [SliceError("part.stl: truncated"), SliceError("again")])
    async with asyncio.timeout(20):
        assert str(await _refusal(worker, stl, "part.stl")) == "part.stl: truncated"
        assert str(await _refusal(worker, stl, "part.stl")) == "again"
    assert (worker.runs, worker.cache_hits) == (2, 0)
    assert list((tmp_path / "cache").iterdir()) == []
    worker.close()


@pytest.mark.parametrize(("error", "kind"), [
    (DecompositionError("no decomposition: sub-part 0 overhangs 287 mm² more than 45°"),
     SliceRefused),
    (MeshError("<mesh>: not watertight"), SliceError),
])
def test_the_worker_tells_a_refusal_from_a_bad_file(tmp_path: Path, monkeypatch: Any,
                                                    error: Exception, kind: type) -> None:
    def refuse(*args: Any, **kwargs: Any) -> None:
        raise error

    monkeypatch.setattr(slicer.pipeline, "slice_model", refuse)
    spool = tmp_path / "0042.stl"
    with pytest.raises(SliceError) as info:
        slice_in_worker(str(spool), dict(load(DEFAULT_CONFIG).data), str(tmp_path / "o.gcode"),
                        name="tee.stl")
    assert type(info.value) is kind
    assert str(info.value).startswith("tee.stl: ")
