"""Errors of the serial link. Every failure the job streamer must act on is a :class:`LinkError`."""

from __future__ import annotations


class LinkError(Exception):
    """Base of every serial-link failure; ``str()`` is the human-readable reason.

    Attributes
    ----------
    last_acked
        The last submission number (see :meth:`SerialLink.submit`) acknowledged on the
        connection before the failure (0 if none).
    job_line
        Set on errors raised by :meth:`SerialLink.stream`: the index, in the streamed input, of
        the last acknowledged line (``None`` if none was).
    """

    def __init__(self, reason: str, last_acked: int = 0, job_line: int | None = None) -> None:
        super().__init__(reason)
        self.reason = reason
        self.last_acked = last_acked
        self.job_line = job_line


class FirmwareReset(LinkError):
    """The firmware rebooted (start banner while connected): the job is interrupted."""


class FirmwareHalted(LinkError):
    """The firmware halted (``Error:Printer halted``, ``!!``, or our own M112)."""


class EmergencyStop(FirmwareHalted):
    """The host sent M112."""


class LinkLost(LinkError):
    """No answer after the timeout and the M105 nudge, or the port went away."""


class ResendLoop(LinkError):
    """The firmware asked for the same line more often than the configured limit."""


class HistoryExhausted(LinkError):
    """The firmware asked for a line no longer kept in the resend history."""


class NotConnected(LinkError):
    """A request was made while the link is not connected."""
