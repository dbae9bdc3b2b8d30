"""What the host has learnt about the firmware from its replies (for the status snapshot)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from hostd.link.replies import (
    Capability,
    FirmwareInfo,
    Ok,
    Position,
    Reply,
    Temperatures,
)


@dataclass
class Observed:
    """Latest firmware name, capabilities, temperatures, position and ADVANCED_OK fields."""

    firmware_name: str | None = None
    firmware_fields: dict[str, str] = field(default_factory=dict)
    capabilities: dict[str, bool] = field(default_factory=dict)
    temperatures: Temperatures | None = None
    position: Position | None = None
    planner_free: int | None = None
    buffer_free: int | None = None
    advanced_ok: bool = False

    def update(self, reply: Reply) -> None:
        """Take note of one reply; replies that carry no state are ignored."""
        if isinstance(reply, Ok):
            self._ok(reply)
        elif isinstance(reply, Temperatures):
            self.temperatures = reply
        elif isinstance(reply, Position):
            self.position = reply
        elif isinstance(reply, FirmwareInfo):
            self.firmware_name = reply.name
            self.firmware_fields = dict(reply.fields)
        elif isinstance(reply, Capability):
            self.capabilities[reply.name] = reply.enabled

    def forget_machine(self) -> None:
        """Drop what a reset makes stale (temperatures, position, queue fields); the
        firmware's name and capabilities stay until it reports them again."""
        self.temperatures = None
        self.position = None
        self.planner_free = None
        self.buffer_free = None

    def _ok(self, ok: Ok) -> None:
        if ok.temperatures is not None:
            self.temperatures = ok.temperatures
        if ok.position is not None:
            self.position = ok.position
        if ok.planner_free is not None or ok.buffer_free is not None:
            self.advanced_ok = True
            self.planner_free = ok.planner_free
            self.buffer_free = ok.buffer_free

    def as_dict(self) -> dict[str, Any]:
        """Plain, JSON-able data."""
        temps = {}
        if self.temperatures is not None:
            temps = {k: {"actual": h.actual, "target": h.target, "power": h.power}
                     for k, h in self.temperatures.heaters.items()}
        return {
            "firmware_name": self.firmware_name,
            "capabilities": dict(self.capabilities),
            "temperatures": temps,
            "position": dict(self.position.axes) if self.position else {},
            "planner_free": self.planner_free,
            "buffer_free": self.buffer_free,
            "advanced_ok": self.advanced_ok,
        }
