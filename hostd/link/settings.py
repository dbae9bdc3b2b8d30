"""Settings of the serial link, built from the ``serial.*`` configuration keys."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from hostd.config import Config

BITS_PER_BYTE = 10  # start + 8 data + stop bits on the wire


@dataclass(frozen=True)
class LinkSettings:
    """Everything the link needs to know; defaults match ``config/hostd.yaml``.

    Attributes
    ----------
    port
        Device path, or ``sim://`` for the in-process emulator.
    baud
        Baud rate of a real port.
    flow_control
        ``window`` (buffer credit) or ``pingpong`` (one line in flight).
    rx_buffer_bytes
        Firmware receive buffer the window may fill, bytes.
    partial_lines
        In window mode, send the first part of the next line when the credit is short of the
        whole line (character counting, as Grbl's streaming protocol): the receive buffer holds
        bytes, not lines, so it may be filled to exactly its size.
    read_hold
        Window mode, real ports, receive buffers of 120 bytes or more: while replies come at
        the wire's pace, leave the port unread for this share of the wire time still queued,
        so one wake-up takes in several ``ok`` (:mod:`hostd.link.read_hold`); 0 reads each
        reply as it arrives.
    ok_timeout
        Seconds without progress before the M105 nudge; as long again before the link is lost.
    starve_timeout
        Seconds without progress, while lines wait for credit, before the line going out in
        parts is finished and an ``M105`` is sent past the credit (its ``ok T:`` makes up for
        a lost ``ok``); at most once until the next ``ok``, and no step towards a lost link.
        0 (or ``ok_timeout`` or more) turns it off.
    nudges
        ``M105`` nudges sent after successive timeouts before the link is declared lost.
    resend_limit
        Resend requests for one line before the job fails.
    history_size
        Acknowledged lines kept for resend requests.
    handshake_timeout
        Seconds to wait for the ``ok`` of ``M110 N0`` before retrying it.
    handshake_attempts
        ``M110 N0`` attempts before connecting fails.
    reconnect_min, reconnect_max
        First and largest delay between reconnect attempts, s (doubling).
    max_queued
        Lines :meth:`SerialLink.stream` submits ahead of the acknowledgements.
    """

    port: str = "sim://"
    baud: int = 115200
    flow_control: str = "window"
    rx_buffer_bytes: int = 127
    partial_lines: bool = True
    read_hold: float = 0.7
    ok_timeout: float = 10.0
    starve_timeout: float = 1.0
    nudges: int = 1
    resend_limit: int = 10
    history_size: int = 1024
    handshake_timeout: float = 2.0
    handshake_attempts: int = 5
    reconnect_min: float = 0.5
    reconnect_max: float = 30.0
    max_queued: int = 64


def link_settings_from_config(cfg: Config) -> LinkSettings:
    """Build :class:`LinkSettings` from the ``serial.*`` keys of a validated configuration."""
    s = cfg.section("serial")
    return LinkSettings(
        port=s["port"], baud=int(s["baud"]), flow_control=s["flow_control"],
        rx_buffer_bytes=int(s["rx_buffer_bytes"]), partial_lines=bool(s["partial_lines"]),
        read_hold=float(s["read_hold"]),
        ok_timeout=float(s["ok_timeout"]), starve_timeout=float(s["starve_timeout"]),
        nudges=int(s["nudges"]),
        resend_limit=int(s["resend_limit"]), history_size=int(s["history_size"]),
        handshake_timeout=float(s["handshake_timeout"]),
        handshake_attempts=int(s["handshake_attempts"]),
        reconnect_min=float(s["reconnect_min"]), reconnect_max=float(s["reconnect_max"]),
        max_queued=int(s["max_queued"]),
    )
