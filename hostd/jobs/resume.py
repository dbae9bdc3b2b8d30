"""Where an interrupted job resumes: the command to start from, the modal state before it and
the restart prelude (home, heat, the way back by the safe Z).

A file with ``;HOSTD_LAYER`` markers resumes at the start of a layer or sub-part. A file
without them (an upload from another slicer) has no such place: it resumes from its last
acknowledged line, the modal state rebuilt from the file up to it (heaters, E mode, the
position approached from the safe Z); asked for a sub-part or checkpoint, the resume is
refused with the reason. It never restarts from the first line, which would print the
first moves again on top of the part."""

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


class ResumeRefused(JobStateError):
    """The resume asked for has no place to start in this file; the job stays interrupted."""


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
    start = resume_index(store, job, program, scope)
    modal = await asyncio.to_thread(program.modal_before, start)
    s = settings
    prelude = [] if start == 0 else modal.restart_commands(
        safe_z(modal.position["Z"], program, s), s.travel_f, s.rotary_f, s.lift_f)
    return start, modal, prelude


def resume_index(store: JobStore, job: Job, program: Program, scope: str) -> int:
    """The command the job resumes from (see the module docstring); :class:`ResumeRefused`
    for a sub-part or checkpoint of a file without layer markers."""
    acked = min(job.acked_lines, program.total)
    if not program.layers:
        if scope != DEFAULT_SCOPE and acked > 0:
            raise ResumeRefused(
                f"job {job.id} cannot resume from its {scope}: its file has no ;HOSTD_LAYER "
                f"markers; it resumes from its last acknowledged line {acked} (hostctl resume "
                f"{job.id}, from {DEFAULT_SCOPE})")
        return acked
    if scope == "checkpoint":
        cp = store.last_checkpoint(job.id)
        return cp.line if cp is not None else program.resume_index(acked, "subpart")
    return program.resume_index(min(acked, max(program.total - 1, 0)), scope)
