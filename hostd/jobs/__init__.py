"""Jobs: the life-cycle state machine, the SQLite job database and the upload spool."""

from __future__ import annotations

from hostd.jobs.spool import Spool, SpoolError
from hostd.jobs.states import JobState, JobStateError
from hostd.jobs.store import Checkpoint, Job, JobNotFound, JobStore, StoreError

__all__ = ["Checkpoint", "Job", "JobNotFound", "JobState", "JobStateError", "JobStore", "Spool",
           "SpoolError", "StoreError"]
