"""The job life cycle: states, the transitions allowed between them, and its error class.

::

    queued → slicing → ready → printing ⇄ paused → completed | failed | cancelled | interrupted

G-code uploads skip ``slicing`` (``queued → ready``). ``interrupted`` is what a job that was
printing or paused becomes when it stopped through no fault of its own: hostd stopped (SIGTERM)
or died under it (found at the next start), the firmware reset mid-print (a banner on an open
port), or the serial link was lost (no ok even after the nudges, the port gone). It can be
resumed (→ ``printing``) or cancelled. A job caught in ``slicing`` by a crash goes back to
``queued`` (nothing is lost).
"""

from __future__ import annotations

from enum import StrEnum


class JobStateError(Exception):
    """A transition the state machine does not allow (e.g. pausing a completed job)."""


class JobState(StrEnum):
    QUEUED = "queued"
    SLICING = "slicing"
    READY = "ready"
    PRINTING = "printing"
    PAUSED = "paused"
    COMPLETED = "completed"
    FAILED = "failed"
    CANCELLED = "cancelled"
    INTERRUPTED = "interrupted"


S = JobState
ALLOWED: dict[JobState, frozenset[JobState]] = {
    S.QUEUED: frozenset({S.SLICING, S.READY, S.FAILED, S.CANCELLED}),
    S.SLICING: frozenset({S.READY, S.FAILED, S.CANCELLED, S.QUEUED}),
    S.READY: frozenset({S.PRINTING, S.FAILED, S.CANCELLED}),
    S.PRINTING: frozenset({S.PAUSED, S.COMPLETED, S.FAILED, S.CANCELLED, S.INTERRUPTED}),
    S.PAUSED: frozenset({S.PRINTING, S.FAILED, S.CANCELLED, S.INTERRUPTED}),
    S.INTERRUPTED: frozenset({S.PRINTING, S.FAILED, S.CANCELLED}),
    S.COMPLETED: frozenset(),
    S.FAILED: frozenset(),
    S.CANCELLED: frozenset(),
}

TERMINAL = frozenset(s for s, nxt in ALLOWED.items() if not nxt)
ACTIVE = frozenset({S.PRINTING, S.PAUSED})
"""States in which a job owns the printer."""
WAITING = frozenset({S.QUEUED, S.SLICING, S.READY})
"""States of jobs in the queue (not yet printed)."""


def parse_state(value: str) -> JobState:
    """The state named ``value``; :class:`JobStateError` for an unknown name."""
    try:
        return JobState(value)
    except ValueError:
        raise JobStateError(f"unknown job state {value!r}") from None


def check_transition(old: JobState, new: JobState) -> None:
    """Raise :class:`JobStateError` unless ``old → new`` is allowed (every state change goes
    through it: :meth:`hostd.jobs.store.JobStore.transition`)."""
    if not can_transition(old, new):
        raise JobStateError(f"cannot go from {old} to {new}")


def can_transition(old: JobState, new: JobState) -> bool:
    """Whether ``old → new`` is allowed."""
    return new in ALLOWED[old]
