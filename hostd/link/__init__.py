"""The serial link to the printer's board: exactly once, in order, as fast as the wire allows.

Layers
------
:mod:`~hostd.link.framing`
    Pure: ``checksum``, ``frame(n, cmd) -> "N<n> <cmd>*<cs>"``, ``framed(n, cmd) -> bytes``
    (the same, encoded, with its newline), ``strip_gcode(line)``.
:mod:`~hostd.link.replies`
    Pure: ``parse_reply(line) -> Reply`` (``Ok``, ``Resend``, ``Busy``, ``Wait``, ``Echo``,
    ``ErrorReply``, ``Halted``, ``Temperatures``, ``Position``, ``FirmwareInfo``,
    ``Capability``, ``Banner``, ``Other``).
:mod:`~hostd.link.protocol`
    Pure state machine ``Protocol``: numbering, checksums, send window (ping-pong or
    buffer credit, halved after each resend; with ``partial_lines`` the credit is filled to
    the byte, the next line going out in parts), resends from a history ring with duplicate
    suppression and a loop guard, ``busy`` keep-alives, timeout → ``M105`` nudge → link lost,
    reset and halt detection. Time is passed in; it returns actions.
:mod:`~hostd.link.link`
    ``SerialLink``: the asyncio shell (replies handled in the port's callback, one timer,
    one writer).
:mod:`~hostd.link.transport`
    ``open_port``: ``sim://`` (in-process emulator on a socket pair) or a real port / pty,
    as an asyncio transport with a line-splitting protocol; ``open_socket`` for any socket.
:mod:`~hostd.link.read_hold`
    Pure: ``ReadHold``, when a real port is read next. While ``ok`` come at the wire's pace
    the port is left unread for ``serial.read_hold`` of the wire time still queued, so one
    wake-up of the loop takes in several.

Using the link
--------------
::

    link = SerialLink(link_settings_from_config(cfg), sim_settings_from_config(cfg))
    await link.connect()                       # M110 N0, then M115; raises LinkLost
    try:
        async for index in link.stream(gcode_lines):   # strips comments itself
            job.last_acked_line = index        # input index, acknowledged by the firmware
    except FirmwareReset as err:               # board rebooted mid-print
        job.interrupted(at=err.job_line)
    except LinkError as err:                   # FirmwareHalted, ResendLoop, LinkLost, ...
        job.failed(reason=str(err), at=err.job_line)
    pos = await link.query("M114")             # Position(axes={"X":..,"A":..,"C":..})
    temps = await link.query("M105")           # Temperatures(heaters={"T": ..., "B": ...})
    link.emergency_stop()                      # M112 at once; never awaits
    link.status()                              # JSON-able dict, see below
    await link.close()

``SerialLink(settings, emulator_settings=None, *, opener=open_port)``:

- ``async connect()``, ``async close()``, ``async wait_connected()``, ``connected``.
- ``submit(cmd) -> Future[int]`` (never blocks; resolves with the submission number when the
  firmware acknowledges the line, fails with a ``LinkError``), ``enqueue(cmds)``,
  ``async send(cmd) -> int``; ``submit_many(cmds) -> (first, Future[int])`` queues several
  with one future for the last (the job streamer's way: a future per batch, not per line);
  ``withdraw(first, last) -> int`` takes back the lines of such a batch that have not gone out
  (a pause or cancel acts after the firmware's few lines, not after the whole queue).
- ``async stream(lines, strip=True)`` yields the input index of each line as it is
  acknowledged, in order, with at most ``settings.max_queued`` lines ahead.
- ``async query(cmd) -> Reply``; ``emergency_stop()``; ``status() -> dict``.

Acknowledgements are cumulative and conservative: an index is yielded only after the firmware
executed that line (a lost ``ok`` delays it, never advances it). Errors:
``LinkError`` ⊃ ``FirmwareReset`` (job interrupted), ``FirmwareHalted`` ⊃ ``EmergencyStop``,
``LinkLost`` (timeout after the nudge, or port gone: the link reconnects with backoff),
``ResendLoop``, ``HistoryExhausted``, ``NotConnected``. After a reset the link handshakes again
by itself; after a halt, call ``connect()`` again. What the link recovers from by itself (an
``ok`` timeout and its nudge, a resend) is logged as a warning naming the port and the line
(resends at most once a minute: :mod:`hostd.link.notices`); so are losing the port and
getting it back.

``status()`` keys: ``state``, ``connected``, ``port``, ``firmware_name``, ``capabilities``,
``temperatures`` (heater → actual/target/power), ``position`` (X, Y, Z, A, C, E),
``lines_sent``, ``lines_acked``, ``lines_resent``, ``lines_split`` (lines sent in parts),
``lines_withdrawn`` (taken back unsent by a pause or cancel),
``resend_requests``, ``duplicate_resends``, ``checksum_errors``, ``line_errors``, ``timeouts``,
``starve_nudges`` (M105 sent after ``serial.starve_timeout`` while lines waited for credit),
``resyncs`` (``M110`` s sent after a resend request out of step with the lines taken),
``resets``, ``window_bytes``,
``flow_control``, ``inflight_lines``, ``inflight_bytes``, ``queued_lines``, ``planner_free``,
``buffer_free``, ``advanced_ok``, ``ok_rtt`` (count, last/mean/max ms), ``reconnects``,
``last_error``.
"""

from __future__ import annotations

from hostd.link.errors import (
    EmergencyStop,
    FirmwareHalted,
    FirmwareReset,
    HistoryExhausted,
    LinkError,
    LinkLost,
    NotConnected,
    ResendLoop,
)
from hostd.link.framing import checksum, frame, strip_gcode
from hostd.link.link import SerialLink
from hostd.link.replies import parse_reply
from hostd.link.settings import LinkSettings, link_settings_from_config

__all__ = [
    "EmergencyStop", "FirmwareHalted", "FirmwareReset", "HistoryExhausted", "LinkError",
    "LinkLost", "LinkSettings", "NotConnected", "ResendLoop", "SerialLink", "checksum", "frame",
    "link_settings_from_config", "parse_reply", "strip_gcode",
]
