"""The slicer's worker processes (stages 1-2 of long sub-parts) never outlive it."""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from process_checks import gone_within

ROOT = Path(__file__).resolve().parents[2]
CHILD = textwrap.dedent("""
    import os, sys
    from slicer.paths.layer_workers import layer_processes

    with layer_processes(10_000) as procs:
        assert procs is not None
        pids = {procs.submit(os.getpid).result() for _ in range(8)}
        print(" ".join(map(str, sorted(pids))), flush=True)
        sys.stdin.read()  # until killed
""")


@pytest.mark.skipif(not hasattr(os, "pidfd_open") or (os.cpu_count() or 1) < 2,
                    reason="Linux pidfds and two cores")
def test_workers_die_with_a_killed_slicer() -> None:
    proc = subprocess.Popen([sys.executable, "-c", CHILD], cwd=ROOT, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        assert select.select([proc.stdout], [], [], 60.0)[0], "the workers never answered"
        workers = [int(p) for p in proc.stdout.readline().split()]
        assert workers and proc.pid not in workers
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    assert all(gone_within(pid, 20.0) for pid in workers)


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="worker processes need two cores")
def test_a_failing_slicer_drops_the_chunks_not_started() -> None:
    """An error while the workers have work queued (a sub-part whose stage 3 fails) leaves
    at once: the queued chunks are cancelled, not computed first."""
    from slicer.paths.layer_workers import layer_processes

    queued = []
    with pytest.raises(RuntimeError, match="no plane"), layer_processes(1, min_layers=1) as procs:
        assert procs is not None
        queued = [procs.submit(time.sleep, 0.2) for _ in range(40)]
        raise RuntimeError("no plane")
    assert all(f.done() for f in queued)
    assert sum(f.cancelled() for f in queued) >= 30


@pytest.mark.timeout(30)
def test_a_layer_is_read_once_its_own_chunk_is_in() -> None:
    """Stage 3 reads a layer as soon as its chunk is in, not after the last chunk; a chunk
    whose worker died is computed by the reader, once."""
    from concurrent.futures import Future
    from concurrent.futures.process import BrokenProcessPool

    from slicer.paths.layer_workers import _Chunks

    def chunk(lo: int, hi: int, tag: str):  # type: ignore[no-untyped-def]
        return ([(f"{tag} shell {i}", 0.0) for i in range(lo, hi)],
                [(f"{tag} zones {i}", 0.0, 0.0) for i in range(lo, hi)])

    first, second = Future(), Future()
    computed: list[tuple[int, int]] = []

    def compute(lo: int, hi: int):  # type: ignore[no-untyped-def]
        computed.append((lo, hi))
        return chunk(lo, hi, "here")

    read = _Chunks([0, 2, 5], [first, second], compute)
    first.set_result(chunk(0, 2, "worker"))
    assert read.layer(1) == (("worker shell 1", 0.0), ("worker zones 1", 0.0, 0.0))
    assert not second.done()  # it did not wait for the other chunk
    second.set_exception(BrokenProcessPool("a worker died"))
    assert read.layer(4)[0] == ("here shell 4", 0.0)
    assert read.layer(2)[1] == ("here zones 2", 0.0, 0.0)
    assert computed == [(2, 5)]
