"""Jobs: the life-cycle state machine, the SQLite job database and the upload spool, and the
job manager over its parts (the queue and its hold, the slice and print loops, the progress
hooks, resume points, one figures type for every view of a job)."""

from __future__ import annotations

from hostd.jobs.spool import Spool, SpoolError
from hostd.jobs.states import JobState, JobStateError
from hostd.jobs.store import Checkpoint, Job, JobNotFound, JobStore, StoreError

__all__ = ["Checkpoint", "Job", "JobNotFound", "JobState", "JobStateError", "JobStore", "Spool",
           "SpoolError", "StoreError"]
