"""Job database writes as the daemon makes them while a job streams: how long one can hold the
event loop.

Run: ``.venv/bin/python bench/store.py [--writes 3000]``. It writes progress rows (the
columns and modal state ``ProgressRecorder.persist`` writes) to a fresh database in a temporary
directory, first as hostd does (no commit checkpoints the write-ahead log:
``JobStore.checkpoint`` runs on a worker thread every ``CHECKPOINT_CHANGES`` rows, here
between two writes as the daemon's quarter-second spacing allows), then with SQLite's
automatic checkpoint (every 1000 pages, inside the commit that fills them), and prints for
each the median, 99th percentile and longest write on the calling thread, in milliseconds,
and the longest checkpoint. The temporary directory is on the machine's own disk: an SD
card syncs far more slowly.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hostd.jobs.store import CHECKPOINT_CHANGES, JobStore
from hostd.printer.modal import ModalState


def write_all(store: JobStore, writes: int, threaded: bool) -> tuple[list[float], float]:
    """``writes`` progress rows; the seconds each took on this thread, and the longest
    checkpoint run on a worker thread (0 if none)."""
    job = store.add("bench.gcode", "gcode", "0" * 64)
    modal = ModalState().snapshot()
    took, longest = [], 0.0
    for n in range(writes):
        start = time.perf_counter()
        store.update(job.id, acked_lines=n, subpart=n // 1000, layer=n // 10, modal=modal,
                     filament_mm=n * 0.03, print_seconds=n * 0.25)
        took.append(time.perf_counter() - start)
        if threaded and store.claim_checkpoint():
            longest = max(longest, checkpoint_on_a_thread(store))
    return took, longest


def checkpoint_on_a_thread(store: JobStore) -> float:
    """Seconds one ``JobStore.checkpoint`` took on a worker thread."""
    spent: list[float] = []

    def run() -> None:
        start = time.perf_counter()
        store.checkpoint()
        spent.append(time.perf_counter() - start)

    worker = threading.Thread(target=run)
    worker.start()
    worker.join()
    return spent[0]


def report(name: str, took: list[float], checkpoint: float) -> None:
    ordered = sorted(took)
    p99 = ordered[int(0.99 * (len(ordered) - 1))]
    print(f"{name:28} median {1e3 * statistics.median(ordered):6.3f} ms  p99 {1e3 * p99:6.3f} ms"
          f"  longest {1e3 * ordered[-1]:7.3f} ms  longest checkpoint on a thread "
          f"{1e3 * checkpoint:7.3f} ms")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--writes", type=int, default=3000, help="progress rows (default 3000)")
    args = ap.parse_args()
    print(f"job database bench: {args.writes} progress writes, a checkpoint every "
          f"{CHECKPOINT_CHANGES} rows on a worker thread (hostd) or every 1000 pages inside "
          "a commit (SQLite's automatic checkpoint)")
    with tempfile.TemporaryDirectory(prefix="hostd-store-") as name:
        store = JobStore(Path(name) / "hostd.db")
        report("hostd", *write_all(store, args.writes, threaded=True))
        store.close()
        store = JobStore(Path(name) / "auto.db")
        store._db.execute("PRAGMA wal_autocheckpoint=1000")  # SQLite's default, for contrast
        report("automatic checkpoint", *write_all(store, args.writes, threaded=False))
        store.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
