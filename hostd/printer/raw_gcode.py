"""Raw G-code from the operator (``hostctl send``, ``printer.gcode``): what is let through.

A script is checked as a file is (no control characters, finite numbers, the heaters' limits,
the travel of absolute moves: a relative one, from a place unknown, is not known), and holds
at most :data:`RAW_MAX_LINES` commands. While a job prints only :data:`SAFE_WHILE_PRINTING`
goes; while it is paused anything does, and the streamer notes it so that the resume puts
back what it may have changed. The firmware's answers are returned with the commands it
refused (:func:`refused`).
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass

from hostd.errors import PrinterBusy
from hostd.link.replies import Echo, ErrorReply, Reply
from hostd.printer.envelope import Envelope
from hostd.printer.errors import ProgramError, ScriptRefused
from hostd.printer.program import parse_program
from hostd.printer.streamer import Streamer

SAFE_WHILE_PRINTING = frozenset({"M105", "M114", "M115", "M117", "M118", "M119", "M220",
                                 "M221", "M106", "M107", "M104", "M140", "M155"})
"""Raw commands accepted while a job prints: queries, messages, fan, overrides, set points."""
RAW_MAX_LINES = 100
REFUSALS = ("unknown command",)
"""How an ``echo:`` reply of Marlin's starts when it did not run the command."""
Query = Callable[[str], Awaitable[Reply]]


@dataclass(frozen=True)
class RawReplies:
    """The commands a script ran and the firmware's reply to each."""

    commands: list[str]
    replies: list[Reply]

    def refused(self) -> list[tuple[str, Reply]]:
        """The commands the firmware answered with an error, and that answer."""
        return [(c, r) for c, r in zip(self.commands, self.replies, strict=True) if refused(r)]


def check_script(script: str, envelope: Envelope | None) -> list[str]:
    """The commands of ``script``, checked as a file is; :class:`ScriptRefused` if not."""
    try:
        program = parse_program(script)
        if envelope is not None:
            envelope.check(program)
    except ProgramError as exc:
        raise ScriptRefused(f"script: {exc}") from None
    commands = program.commands
    if not commands:
        raise ScriptRefused("script: no G-code commands")
    if len(commands) > RAW_MAX_LINES:
        raise ScriptRefused(f"script: more than {RAW_MAX_LINES} commands")
    return commands


def admit(commands: Sequence[str], job: Streamer | None) -> None:
    """Let ``commands`` through beside the job on the printer (``job``: its streamer):
    :class:`PrinterBusy` for one outside the safe set while it prints; while it is paused the
    streamer notes them (the resume puts back what they change)."""
    if job is None:
        return
    if job.state == "paused":
        job.note_raw(commands)
        return
    unsafe = [c for c in commands if c.split()[0] not in SAFE_WHILE_PRINTING]
    if unsafe:
        raise PrinterBusy(f"refused while printing: {unsafe[0]} (allowed: "
                          f"{' '.join(sorted(SAFE_WHILE_PRINTING))})")


async def run_script(script: str, envelope: Envelope | None, job: Streamer | None,
                     query: Query) -> RawReplies:
    """Check ``script``, admit it beside ``job`` and send its commands one by one."""
    commands = check_script(script, envelope)
    admit(commands, job)
    return RawReplies(commands, [await query(c) for c in commands])


def refused(reply: Reply) -> bool:
    """Whether the firmware answered a raw command with an error: an ``Error:`` line, or an
    ``echo:Unknown command``."""
    if isinstance(reply, ErrorReply):
        return True
    return isinstance(reply, Echo) and reply.text.lower().startswith(REFUSALS)
