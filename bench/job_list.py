"""``job.list`` on a long history: how long it holds the event loop.

Run: ``.venv/bin/python bench/job_list.py [--jobs 1000] [--repeat 5]``. It fills a fresh job
database in a temporary directory with ``--jobs`` finished jobs, each with the columns a
sliced job has (modal state, estimate, slicing figures), and times, for a few limits, what
the ``job.list`` endpoint does on the event loop: the query, a job's dict for each row and the
JSON encoding of the answer. It prints the best of ``--repeat`` runs in milliseconds.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hostd.jobs.states import JobState
from hostd.jobs.store import JobStore
from hostd.printer.modal import ModalState

ESTIMATE = {"filament_mm": 5123.4, "time_s": 7421.5, "mass_g": 15.27, "subparts": 3}
INFO = {"subparts": 3, "layers": 412, "transitions": 2, "lines": 80321, "filament_mm": 5123.4,
        "time_s": 7421.5, "replay": {"moves": 70211, "collisions": 0, "max_a": 61.2,
                                     "min_a": 0.0, "max_deviation_mm": 0.008},
        "slice_s": 41.2, "cache_hit": False, "gcode_bytes": 2481234}


def fill(store: JobStore, jobs: int) -> None:
    modal = ModalState().snapshot()
    for n in range(jobs):
        job = store.add(f"part-{n}.stl", "stl", f"{n:064x}", gcode_sha=f"{n + 1:064x}",
                        estimate=ESTIMATE)
        store.update(job.id, total_lines=80321, acked_lines=80321, subpart=2, layer=140,
                     modal=modal, filament_mm=5123.4, print_seconds=7301.2, info=INFO)
        for state in (JobState.SLICING, JobState.READY, JobState.PRINTING, JobState.COMPLETED):
            store.transition(job.id, state, "bench")


def list_once(store: JobStore, limit: int) -> float:
    """Seconds for what the endpoint does with ``limit``."""
    start = time.perf_counter()
    rows = [job.to_dict() for job in store.list(None, limit)]
    json.dumps({"jsonrpc": "2.0", "id": 1, "result": {"jobs": rows}})
    return time.perf_counter() - start


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=1000, help="jobs in the history (default 1000)")
    ap.add_argument("--repeat", type=int, default=5, help="runs per limit, best kept")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="hostd-list-") as name:
        store = JobStore(Path(name) / "jobs.db")
        fill(store, args.jobs)
        print(f"job.list on {args.jobs} finished jobs (best of {args.repeat})")
        for limit in (20, 50, 100, 1000):
            best = min(list_once(store, limit) for _ in range(args.repeat))
            print(f"limit {limit:5d}  {1e3 * best:8.2f} ms")
        store.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
