"""Where an interrupted job resumes: the command to start from, the modal state before it and
the restart prelude (home, heat, the way back by the safe Z)."""

from __future__ import annotations

import asyncio

from hostd.jobs.states import JobStateError
from hostd.jobs.store import Job, JobStore
from hostd.printer.modal import ModalState
from hostd.printer.program import Program
from hostd.printer.settings import StreamSettings
from hostd.printer.streamer import safe_z

RESUME_SCOPES = ("layer", "subpart", "checkpoint")
DEFAULT_SCOPE = "layer"
"""Where an interrupted job resumes by default: the start of the layer it stopped in (at most
that layer is printed twice over). A sub-part or checkpoint restart prints again every layer
of the sub-part done so far, on top of themselves: the operator's choice, never a default."""


def resume_scope(scope: str | None) -> str:
    """``scope``, or the default; :class:`JobStateError` for one that is not a scope."""
    scope = scope or DEFAULT_SCOPE
    if scope not in RESUME_SCOPES:
        raise JobStateError(f"resume from {scope!r}: use one of {', '.join(RESUME_SCOPES)}")
    return scope


async def resume_point(store: JobStore, job: Job, program: Program, scope: str,
                       settings: StreamSettings) -> tuple[int, ModalState, list[str]]:
    """The command to resume from, the modal state before it and the restart prelude.

    The modal state is rebuilt by reading the file up to that command, on a thread: the
    event loop (status calls, other clients) does not wait for a long file to be read."""
    if scope == "checkpoint":
        cp = store.last_checkpoint(job.id)
        start = cp.line if cp is not None else program.resume_index(job.acked_lines,
                                                                      "subpart")
    else:
        start = program.resume_index(min(job.acked_lines, max(program.total - 1, 0)), scope)
    modal = await asyncio.to_thread(program.modal_before, start)
    s = settings
    prelude = [] if start == 0 else modal.restart_commands(
        safe_z(modal.position["Z"], program, s), s.travel_f, s.rotary_f, s.lift_f)
    return start, modal, prelude
