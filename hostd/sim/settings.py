"""Settings of the firmware emulator, built from the ``sim.*`` configuration keys."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from hostd.config import Config


@dataclass(frozen=True)
class SimSettings:
    """Behaviour and fault knobs of the emulated Marlin board.

    Attributes
    ----------
    baud
        Wire rate; bytes/s = baud / 10 when ``throttle`` is on.
    rx_buffer_bytes
        Receive buffer; bytes arriving when it is full are silently lost.
    queue_slots, planner_blocks
        Marlin's BUFSIZE (command queue) and BLOCK_BUFFER_SIZE (planner).
    realtime, time_scale
        Run moves and heaters on the wall clock (scaled), else as fast as possible.
    throttle
        Limit both wire directions to baud/10 bytes per second of wall time.
    advanced_ok
        Answer ``ok N<n> P<p> B<b>`` instead of a bare ``ok``.
    read_delay
        Simulated seconds the main loop spends elsewhere (display, heaters) after each
        command before it reads the receive buffer again; bytes arriving meanwhile wait there.
    busy_interval
        Simulated seconds between ``echo:busy: processing`` while a command waits; 0 for
        none (Marlin without ``HOST_KEEPALIVE_FEATURE``). ``M109``/``M190`` print the
        heaters with ``W:`` once a second while they wait, either way.
    bit_flip_prob
        Probability that a received line has one bit flipped.
    lost_ok_prob
        Probability that an ``ok`` is never sent.
    busy_prob, busy_seconds
        Probability of a busy period (simulated seconds) after a command.
    reset_at_line
        Reboot (print the start banner, forget everything) after executing this many
        numbered lines; 0 = never.
    silence_at_line, silence_lines
        After executing ``silence_at_line`` numbered lines, swallow the next ``silence_lines``
        received lines without any answer; 0 = never.
    lost_step_axis, lost_step_degrees, lost_step_at_move
        Lose steps on ``A`` or ``C``: from the ``lost_step_at_move``-th move that changes that
        axis on, M114 reports it off the commanded position by ``lost_step_degrees``.
    seed
        Seed of the fault injection.
    """

    baud: int = 115200
    rx_buffer_bytes: int = 127
    queue_slots: int = 4
    planner_blocks: int = 16
    realtime: bool = False
    time_scale: float = 1.0
    throttle: bool = False
    advanced_ok: bool = False
    read_delay: float = 0.0
    busy_interval: float = 2.0
    bit_flip_prob: float = 0.0
    lost_ok_prob: float = 0.0
    busy_prob: float = 0.0
    busy_seconds: float = 3.0
    reset_at_line: int = 0
    silence_at_line: int = 0
    silence_lines: int = 0
    lost_step_axis: str = "A"
    lost_step_degrees: float = 0.0
    lost_step_at_move: int = 0
    seed: int = 0

    @property
    def wire_bytes_per_second(self) -> float:
        """Bytes per second the wire carries (baud / 10), infinite when not throttled."""
        return self.baud / 10 if self.throttle else math.inf


def sim_settings_from_config(cfg: Config) -> SimSettings:
    """Build :class:`SimSettings` from the ``sim.*`` keys (and ``serial.baud``)."""
    s = cfg.section("sim")
    return SimSettings(
        baud=int(cfg["serial.baud"]), rx_buffer_bytes=int(s["rx_buffer_bytes"]),
        queue_slots=int(s["queue_slots"]), planner_blocks=int(s["planner_blocks"]),
        realtime=bool(s["realtime"]), time_scale=float(s["time_scale"]),
        throttle=bool(s["throttle"]), advanced_ok=bool(s["advanced_ok"]),
        bit_flip_prob=float(s["bit_flip_prob"]), lost_ok_prob=float(s["lost_ok_prob"]),
        busy_prob=float(s["busy_prob"]), busy_seconds=float(s["busy_seconds"]),
        reset_at_line=int(s["reset_at_line"]), silence_at_line=int(s["silence_at_line"]),
        silence_lines=int(s["silence_lines"]), lost_step_axis=str(s["lost_step_axis"]),
        lost_step_degrees=float(s["lost_step_degrees"]),
        lost_step_at_move=int(s["lost_step_at_move"]), seed=int(s["seed"]),
    )
