"""The daemon as the control endpoints see it: all of it that is theirs to use.

:class:`~hostd.daemon.Daemon` is one (the endpoints never import it); a test may pass another.
"""

from __future__ import annotations

from typing import Any, Protocol

from hostd.control.rpc import Encoded
from hostd.events import EventBus
from hostd.jobs.manager import JobManager
from hostd.printer.raw_gcode import RawReplies


class Host(Protocol):
    """The daemon's facade for :mod:`hostd.control.endpoints`."""

    @property
    def is_sim(self) -> bool:
        """Whether the printer is the built-in emulator (``serial.port: sim://``)."""
        ...

    @property
    def machine_name(self) -> str: ...

    @property
    def max_upload_bytes(self) -> int: ...

    @property
    def bus(self) -> EventBus: ...

    @property
    def jobs(self) -> JobManager: ...

    def snapshot(self) -> dict[str, Any]:
        """Every component's ``status()`` (plain JSON)."""
        ...

    def snapshot_json(self) -> Encoded:
        """:meth:`snapshot` encoded, as ``printer.status`` answers it (a few milliseconds
        old at most, and never older than the last event)."""
        ...

    async def raw_gcode(self, script: str) -> RawReplies:
        """Run an operator's raw G-code (:mod:`hostd.printer.raw_gcode`)."""
        ...

    async def firmware_restart(self) -> dict[str, Any]: ...

    async def emergency_stop(self) -> None: ...

    def emulator_log(self) -> list[tuple[int | None, str]]: ...
