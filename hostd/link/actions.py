"""What the protocol state machine asks its shell to do."""

from __future__ import annotations

from dataclasses import dataclass

from hostd.link.errors import LinkError
from hostd.link.replies import Reply

# Write and Acked are made once or twice per line: plain slotted classes, since a frozen
# dataclass's __init__ (object.__setattr__ per field) costs twice as much. Nothing changes an
# action after the protocol made it.


@dataclass(slots=True)
class Write:
    """Put these bytes on the wire, now, after every earlier :class:`Write`."""

    data: bytes


@dataclass(slots=True)
class Acked:
    """Every numbered line up to and including ``line`` has been acknowledged."""

    line: int


@dataclass(frozen=True)
class Answer:
    """The query sent as line ``line`` was acknowledged; ``replies`` arrived while it ran."""

    line: int
    replies: tuple[Reply, ...]


@dataclass(frozen=True)
class Connected:
    """The ``M110 N0`` handshake succeeded; lines may be submitted."""


@dataclass(frozen=True)
class Failed:
    """Every line not yet acknowledged is lost to ``error``; the job must stop."""

    error: LinkError


@dataclass(frozen=True)
class Notice:
    """Something went wrong on the wire and the link is recovering: for the operator's log.
    ``kind`` is ``timeout`` (a nudge), ``starved`` (an early M105 while lines waited for
    credit) or ``resend``."""

    kind: str
    message: str


Action = Write | Acked | Answer | Connected | Failed | Notice
