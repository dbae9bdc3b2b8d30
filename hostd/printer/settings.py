"""Settings of the streamer, built from the configuration (``process.*``, ``pause.*``,
``transition.*`` and the machine's travel and rotary speed)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from hostd.config.placeholders import process_values

if TYPE_CHECKING:
    from hostd.config import Config

SECONDS_PER_MINUTE = 60.0


def per_minute(speed: float) -> float:
    """A G-code feed (F, mm or degrees a minute) from a config speed (a second)."""
    return float(speed) * SECONDS_PER_MINUTE


@dataclass(frozen=True)
class StreamSettings:
    """What the streamer needs besides the file: its look-ahead, the moves it makes itself
    (a pause's retract and lift, a resume's way back, a cancel's end script) and the
    tolerances of a transition's readback. Feeds (``*_f``) are G-code F values, per minute.
    The defaults are small test values; the daemon's come from the configuration
    (:func:`stream_settings_from_config`)."""

    lookahead: int = 16
    retract: float = 1.0
    retract_f: float = 2100.0
    lift: float = 10.0
    lift_f: float = 600.0
    travel_f: float = 7200.0
    rotary_f: float = 3000.0
    safe_height: float = 60.0
    z_max: float = 700.0
    position_tolerance: float = 0.05
    angle_tolerance: float = 0.05
    temperature_tolerance: float = 5.0
    end_gcode: str = "M104 S0\nM140 S0\nM107\nG0 Z{safe_z} F3000\nG0 A0 C0 F3000\nM84\n"
    end_values: dict[str, Any] = field(default_factory=dict)
    """The end script's placeholders besides ``{safe_z}`` (the process settings)."""
    idle_timeout: float = 300.0
    """Seconds a job paused by a storage error keeps its heaters on (``pause.idle_timeout``)."""


def stream_settings_from_config(cfg: Config) -> StreamSettings:
    """Build :class:`StreamSettings` from a validated configuration: the retract, travel and
    safe height the slicer uses too, the pause's lift (``pause.lift``, ``pause.lift_speed``)
    and the transition tolerances."""
    p = cfg.section("process")
    t = cfg.section("transition")
    pause = cfg.section("pause")
    return StreamSettings(
        lookahead=int(cfg.get("serial.max_queued", 64)),
        retract=float(p["retract_length"]), retract_f=per_minute(p["retract_speed"]),
        lift=float(pause["lift"]), lift_f=per_minute(pause["lift_speed"]),
        idle_timeout=float(pause["idle_timeout"]), travel_f=per_minute(p["travel_speed"]),
        rotary_f=per_minute(cfg["machine.max_rotary_velocity"]),
        safe_height=float(p["safe_height"]), z_max=float(cfg["machine.z_range"][1]),
        position_tolerance=float(t["position_tolerance"]),
        angle_tolerance=float(t["angle_tolerance"]),
        temperature_tolerance=float(t["temperature_tolerance"]),
        end_gcode=str(p["end_gcode"]), end_values=process_values(cfg))
