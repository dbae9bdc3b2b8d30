"""Worker processes for the stages 1 and 2 of a long sub-part's layers (see
:mod:`slicer.paths.subpart_paths` for the stages).

A sub-part of :data:`CHUNK_MIN_LAYERS` layers or more (the root of a branched part holds most
of them, its branches tens) has its shells and zones computed in forked worker processes, by
chunks of consecutive layers (a chunk also computes the shell of the layer after its last,
which stage 2 reads): threads gain nothing there, as the Python between the GEOS calls holds
the GIL. The planner starts the chunks as soon as the sub-part is marched
(:func:`start_stages`): the workers take no GIL from the marching of the sub-parts after it.
Stage 3 reads each layer once its own chunk is in, not after the last chunk.

The workers are forked (:func:`layer_processes`; a forked child has the parent's modules and
only runs shapely and numpy here), die with the slicer, and compute with the same calls as a
plain loop, so the plan is the same byte for byte. If the pool is broken from the start the
sub-part goes to the threads; a chunk lost later (its worker died) or refused by a pool that
broke is computed by the thread that reads it.
"""

from __future__ import annotations

import bisect
import contextlib
import functools
import itertools
import multiprocessing
import os
from collections.abc import Callable, Iterator
from concurrent.futures import Executor, Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any

from slicer.cores import die_with_parent
from slicer.paths.interfaces import ChildBase
from slicer.paths.layers import LayerPlane
from slicer.paths.subpart_paths import (
    MAX_WORKERS,
    LayerJob,
    Staged,
    Stages,
    Zones,
    done,
    fill_spec,
    timed,
)
from slicer.paths.toolpaths import Shell, shell
from slicer.settings import ProcessSettings

CHUNK_MIN_LAYERS = 20  # a sub-part with this many layers has stages 1-2 in processes
CHUNKS_PER_PROCESS = 3  # chunks of layers per worker process: evens out unequal chunks


@contextlib.contextmanager
def layer_processes(longest: int, min_layers: int = CHUNK_MIN_LAYERS
                    ) -> Iterator[ProcessPoolExecutor | None]:
    """Forked worker processes, one per core (at most :data:`MAX_WORKERS`), when a sub-part
    of ``longest`` layers reaches ``min_layers`` and there are two cores; else ``None``.

    The workers are forked at once, in the caller's thread (a fork copies only the thread
    that makes it: forking here, not from a builder thread at its first submission while
    other threads run, leaves no lock in the child held by a thread it does not have). When
    the caller fails, the chunks not yet started are dropped.
    """
    n = _processes()
    if n < 2 or longest < min_layers:
        yield None
        return
    procs = ProcessPoolExecutor(n, mp_context=multiprocessing.get_context("fork"),
                                initializer=die_with_parent, initargs=(os.getpid(),))
    try:
        procs.submit(os.getpid)  # with "fork", the first submission starts every worker
        yield procs
    except BaseException:
        procs.shutdown(wait=True, cancel_futures=True)
        raise
    procs.shutdown(wait=True)


def _processes() -> int:
    return min(MAX_WORKERS, os.cpu_count() or 1)


def chunk_stages(layers: list[LayerPlane], settings: ProcessSettings, grounded: bool,
                 bases: list[ChildBase], lo: int, hi: int) -> Staged:
    """Stages 1 and 2 of layers ``lo`` to ``hi - 1`` (run in a worker process): their
    timed shells and zones. The shell of layer ``hi`` is computed too, not returned."""
    spec = fill_spec(settings)
    elsewhere: Future[tuple[Shell, float]] = Future()  # the layers this chunk never reads
    elsewhere.set_exception(LookupError(f"only the shells of layers {lo} to {hi} are computed "
                                        "in this chunk"))
    shells = [elsewhere] * len(layers)
    for i in range(lo, min(hi + 1, len(layers))):
        shells[i] = done(timed(shell, layers[i].region, spec))
    job = LayerJob(layers, shells, settings, grounded, bases)
    return ([shells[i].result() for i in range(lo, hi)],
            [job.layer(i) for i in range(lo, hi)])


class _Chunks:
    """Stages 1 and 2 of a sub-part's layers, computed by chunks in worker processes and read
    layer by layer: reading a layer waits for its own chunk only, so stage 3 starts on the
    first chunk while the workers compute the others. A chunk whose worker died is computed
    by the reader, with the same calls (:func:`chunk_stages`)."""

    def __init__(self, bounds: list[int], chunks: list[Future[Staged] | None],
                 compute: Callable[[int, int], Staged]) -> None:
        self.bounds, self.chunks, self.compute = bounds, chunks, compute
        self.results: list[Staged | None] = [None] * len(chunks)

    def layer(self, i: int) -> tuple[tuple[Shell, float], tuple[Zones, float, float]]:
        """Layer i's timed shell and zones, once its chunk is in."""
        j = bisect.bisect_right(self.bounds, i) - 1
        got = self.results[j]
        if got is None:
            got = self.results[j] = self._wait(j)
        return got[0][i - self.bounds[j]], got[1][i - self.bounds[j]]

    def _wait(self, j: int) -> Staged:
        chunk = self.chunks[j]
        if chunk is not None:
            try:
                return chunk.result()
            except BrokenProcessPool:  # its worker died (out of memory?)
                pass
        return self.compute(self.bounds[j], self.bounds[j + 1])


@dataclass(frozen=True)
class _Part:
    """One layer's shell (``part`` 0) or zones (1) from :class:`_Chunks`, read as a future."""

    chunks: _Chunks
    i: int
    part: int

    def result(self) -> Any:
        return self.chunks.layer(self.i)[self.part]


def _staged_in_processes(layers: list[LayerPlane], settings: ProcessSettings, grounded: bool,
                         bases: list[ChildBase], procs: Executor) -> Stages:
    """Stages 1 and 2 of every layer submitted to ``procs`` by chunks; raises
    :class:`BrokenProcessPool` if not even the first chunk could be submitted."""
    n = len(layers)
    k = min(n, CHUNKS_PER_PROCESS * _processes())
    bounds = [n * j // k for j in range(k + 1)]
    chunks: list[Future[Staged] | None] = []
    for lo, hi in itertools.pairwise(bounds):
        try:
            chunks.append(procs.submit(chunk_stages, layers, settings, grounded, bases, lo, hi))
        except BrokenProcessPool:
            if not chunks:
                raise
            chunks.append(None)  # computed by the reader
    read = _Chunks(bounds, chunks, functools.partial(chunk_stages, layers, settings,
                                                       grounded, bases))
    return [_Part(read, i, 0) for i in range(n)], [_Part(read, i, 1) for i in range(n)]


def start_stages(layers: list[LayerPlane], settings: ProcessSettings, grounded: bool,
                 bases: list[ChildBase], procs: Executor | None,
                 min_layers: int = CHUNK_MIN_LAYERS) -> Stages | None:
    """Stages 1 and 2 of a sub-part of ``min_layers`` layers or more, started by chunks in
    ``procs`` (:func:`layer_processes`), to be read by
    :func:`~slicer.paths.subpart_paths.build_layers`; ``None`` for a
    shorter sub-part, without ``procs`` or when the pool is broken (the threads then do it).

    The planner starts them as soon as the sub-part is marched, so the workers compute while
    the sub-parts after it are marched (they hold no GIL the marching waits for).
    """
    if procs is None or len(layers) < min_layers:
        return None
    try:
        return _staged_in_processes(layers, settings, grounded, bases, procs)
    except BrokenProcessPool:
        return None
