"""Errors of the job streamer (each subsystem has its own error class)."""

from __future__ import annotations


class PrinterError(Exception):
    """A print cannot go on, or a printer request cannot be served."""


class TransitionFailed(PrinterError):
    """A rotate/return block did not reach its target (lost step, wrong temperature)."""

    def __init__(self, reason: str, expected: dict[str, float] | None = None,
                 measured: dict[str, float] | None = None) -> None:
        super().__init__(reason)
        self.expected = expected or {}
        self.measured = measured or {}


class ProgramError(PrinterError):
    """A G-code file whose HOSTD markers are malformed."""


class ScriptRefused(PrinterError):
    """Raw G-code refused before any of it is sent: malformed, over a heater's limit or the
    machine's travel, empty, or too long (``str()`` names the script and the problem)."""
