"""A Marlin-like firmware front end on a simulated clock: receive buffer, line checking,
command queue, ``ok``/``Resend`` replies, busy keepalive, autoreport and fault injection.

Pure apart from the seeded random faults: bytes go in with :meth:`Firmware.receive`, time
moves with :meth:`Firmware.advance` / :meth:`Firmware.settle`, replies come out of
:meth:`Firmware.take_output`. Every executed command is appended to :attr:`Firmware.log`.

The input path is Marlin's: the serial interrupt puts bytes into the receive ring
(``RX_BUFFER_SIZE``; when it is full, arriving bytes are silently lost); the main loop
(``get_serial_commands``, also called from ``idle()`` while a command blocks) moves them into
its line buffer and each complete line into the command queue (``BUFSIZE`` slots) as long as
the queue has a free slot, and stops reading while it is full. A command's ``ok`` is sent once
it has been processed, while it still holds its slot: with ADVANCED_OK it reads
``ok N<its line> P<free planner blocks> B<BUFSIZE - queued commands>``. A rejected line is
answered by ``Error:…``, ``Resend: <last+1>`` and a bare ``ok``. A line is read as Marlin 2
reads it: its ``;`` comment dropped by the queue, a numbered line's checksum after its last
``*``, the command and its parameters as ``GCodeParser::parse`` finds them
(:class:`~hostd.sim.machine.Command`).
"""

from __future__ import annotations

import re
from collections import deque

from hostd.sim.faults import Faults
from hostd.sim.machine import FIRMWARE_NAME, Command, Machine
from hostd.sim.settings import SimSettings
from slicer.gcode.markers import queued_line

_M112 = re.compile(rb"(?:^|[\s\d])M112(?:[\s*]|$)")
HALT_MESSAGE = "Error:Printer halted. kill() called!"
HEAT_WAITS = ("M109", "M190")
HEAT_REPORT_INTERVAL = 1.0  # s: Marlin prints the heaters once a second while M109/M190 wait


def xor_checksum(data: bytes) -> int:
    """Marlin's checksum: the XOR of the bytes before ``*``."""
    cs = 0
    for b in data:
        cs ^= b
    return cs


class Firmware:
    """The emulated board. See the module docstring for the driving protocol.

    Attributes
    ----------
    log
        ``(line number or None, command)`` of every executed command, in order.
    dropped_bytes
        Bytes lost because the receive buffer was full.
    rx_high_water
        Most bytes ever held in the receive buffer.
    """

    def __init__(self, settings: SimSettings) -> None:
        self.settings = settings
        self.faults = Faults(settings)
        self.now = 0.0
        self.log: list[tuple[int | None, str]] = []
        self.dropped_bytes = 0
        self.rx_high_water = 0
        self.boots = 0
        self._reset_done = False
        self._silence_done = False
        self._out: list[str] = []
        self.boot()

    # -- lifecycle ----------------------------------------------------------------------

    def boot(self) -> None:
        """(Re)start: forget buffers, queue, planner and line number; print the banner."""
        self.boots += 1
        self.machine = Machine(self.settings)
        self.rx = bytearray()
        self._line = bytearray()
        self._isr_line = bytearray()
        self.queue: deque[Command] = deque()
        self.last_n = 0
        self.executed = 0
        self.halted = False
        self.silence_left = 0
        self.busy_until = 0.0
        self.read_at = 0.0  # the main loop reads the receive buffer again from then on
        self._busy_report_at: float | None = None
        self._heat_report_at: float | None = None
        self._autoreport_at: float | None = None
        self._out += ["start", f"echo:{FIRMWARE_NAME}", "echo: Free Memory: 4096"]

    def take_output(self) -> bytes:
        """Reply bytes produced since the last call."""
        if not self._out:
            return b""
        data = "".join(f"{line}\n" for line in self._out).encode("ascii", "replace")
        self._out = []
        return data

    # -- input --------------------------------------------------------------------------

    def receive(self, data: bytes) -> None:
        """Bytes arriving now, in order (see the module docstring for where they go)."""
        if self.halted:
            return
        start = 0
        while start < len(data):
            end = data.find(b"\n", start)
            end = len(data) if end < 0 else end + 1
            self._arrive(data[start:end])
            start = end
            self.service()

    def _arrive(self, chunk: bytes) -> None:
        self._emergency_parser(chunk)
        if self.halted:
            return
        if not self.rx and self._reading():
            # The main loop is reading: the bytes go on into its line buffer as they come.
            self._read_line_bytes(chunk)
            return
        room = max(self.settings.rx_buffer_bytes - len(self.rx), 0)
        if len(chunk) > room:
            self.dropped_bytes += len(chunk) - room
            chunk = chunk[:room]
        self.rx += chunk
        self.rx_high_water = max(self.rx_high_water, len(self.rx))

    def _read_serial(self) -> None:
        """The main loop drains the receive ring while the command queue has a free slot."""
        while self.rx and self._reading() and not self.halted:
            end = self.rx.find(b"\n")
            end = len(self.rx) if end < 0 else end + 1
            chunk = bytes(self.rx[:end])
            del self.rx[:end]
            self._read_line_bytes(chunk)

    def _reading(self) -> bool:
        """Whether the main loop takes bytes out of the receive buffer now."""
        return len(self.queue) < self.settings.queue_slots and self.now >= self.read_at

    def _read_line_bytes(self, chunk: bytes) -> None:
        self._line += chunk
        if self._line.endswith(b"\n"):
            line, self._line = bytes(self._line[:-1]), bytearray()
            self._accept(line)

    def _emergency_parser(self, chunk: bytes) -> None:
        self._isr_line += chunk
        if not self._isr_line.endswith(b"\n"):
            return
        line, self._isr_line = bytes(self._isr_line), bytearray()
        if _M112.search(line.strip()):
            self._halt()

    def _halt(self) -> None:
        self.halted = True
        self.queue.clear()
        self.rx.clear()
        self._line.clear()
        self.log.append((None, "M112"))
        self._out.append(HALT_MESSAGE)

    # -- time ---------------------------------------------------------------------------

    def advance(self, until: float) -> None:
        """Let simulated time run to ``until``, handling every event on the way."""
        while True:
            event = self.next_event()
            if event is None or event > until:
                break
            self.now = max(self.now, event)
            self._timers()
            self.service()
        self.now = max(self.now, until)
        self._timers()
        self.service()

    def settle(self, limit: int = 100_000) -> None:
        """Fast mode: jump simulated time until the command queue and the receive buffer are
        empty (or stuck)."""
        for _ in range(limit):
            if (not self.queue and not self.rx) or self.halted:
                return
            event = self.next_event()
            if event is None:
                return
            self.advance(event)

    def next_event(self) -> float | None:
        """Simulated time of the next internal event, if any."""
        times = [t for t in (self._busy_report_at, self._heat_report_at, self._autoreport_at)
                 if t is not None]
        head = self._head_ready()
        if head is not None:
            times.append(head)
        if self.rx and self.now < self.read_at and not self.halted:
            times.append(self.read_at)
        return min(times) if times else None

    def _head_ready(self) -> float | None:
        if self.halted or not self.queue:
            return None
        if self.now < self.busy_until:
            return self.busy_until
        head = self.queue[0]
        return self.machine.ready_at(head, self.now) if head.started else self.now

    def _timers(self) -> None:
        if self._busy_report_at is not None and self.now >= self._busy_report_at:
            self._out.append("echo:busy: processing")
            self._busy_report_at += self.settings.busy_interval
        if self._heat_report_at is not None and self.now >= self._heat_report_at:
            # the wait loop's line: the heaters, then the residency countdown (not begun)
            self._out.append(" " + self.machine.temperature_report(self.now) + " W:?")
            self._heat_report_at += HEAT_REPORT_INTERVAL
        interval = self.machine.autoreport
        if interval <= 0:
            self._autoreport_at = None
        elif self._autoreport_at is None:
            self._autoreport_at = self.now + interval
        elif self.now >= self._autoreport_at:
            self._out.append(" " + self.machine.temperature_report(self.now))
            self._autoreport_at = self.now + interval

    # -- the main loop ------------------------------------------------------------------

    def service(self) -> None:
        """Read complete lines into the queue and run commands, at the current time."""
        while not self.halted:
            self._read_serial()
            if not self._run_head():
                return

    def _accept(self, raw: bytes) -> None:
        if self.silence_left > 0:
            self.silence_left -= 1
            return
        line = self.faults.corrupt(raw.rstrip(b"\r"))
        if b";" in line or b"\\" in line:  # the queue drops a comment, keeps escaped text
            line = queued_line(line.decode("latin-1")).encode("latin-1")
        line = line.strip()
        if not line:
            return
        if line[:1] != b"N":
            if b"*" in line:  # Marlin 1.1's answer (Marlin 2 would run it, '*' cut): a line
                self._reject("No Line Number with checksum")  # whose N a bit flip hit
            else:
                self._enqueue(None, line)
            return
        self._numbered(line)

    def _numbered(self, line: bytes) -> None:
        head, _, rest = line.partition(b" ")
        try:
            number = int(head[1:])
        except ValueError:
            self._reject("Line Number is not Last Line Number+1")
            return
        body = rest.partition(b"*")[0]  # what the parser reads: up to the first '*'
        summed, star, cs = line.rpartition(b"*")  # the checksum: after the last (strrchr)
        is_m110 = body.strip().upper().startswith(b"M110")
        if number != self.last_n + 1 and not is_m110:
            self._reject("Line Number is not Last Line Number+1")
            return
        if not star:
            self._reject("No Checksum with line number")
            return
        if not cs.strip().isdigit() or int(cs) != xor_checksum(summed):
            self._reject("checksum mismatch")
            return
        self.last_n = number
        if is_m110:
            words = Command(number, body.decode("latin-1").strip()).words
            self.last_n = int(words.get("N", number))
        self._enqueue(number, body)

    def _enqueue(self, number: int | None, body: bytes) -> None:
        text = body.decode("latin-1").strip()
        if text:
            self.queue.append(Command(number, text))

    def _reject(self, message: str) -> None:
        self._out.append(f"Error:{message}, Last Line: {self.last_n}")
        self._out.append(f"Resend: {self.last_n + 1}")
        self._ok("ok")

    def _ok(self, text: str | None) -> None:
        if self.faults.lose_ok():
            return
        self._out.append(text or "ok")

    def _advanced_ok(self, number: int | None) -> str:
        """The ADVANCED_OK line of the command being processed (it still holds its slot)."""
        planner = self.machine.planner.free(self.now) - 1
        slots = self.settings.queue_slots - len(self.queue)
        n = f" N{number}" if number is not None else ""
        return f"ok{n} P{max(planner, 0)} B{slots}"

    def _run_head(self) -> bool:
        if not self.queue or self.now < self.busy_until:
            self._arm_busy_report()
            return False
        cmd = self.queue[0]
        if not cmd.started:
            cmd.started = True
            self.machine.start(cmd, self.now)
            if cmd.code == "M112":
                self._halt()
                return False
        if self.machine.ready_at(cmd, self.now) > self.now:
            self._arm_busy_report()
            if cmd.code in HEAT_WAITS and self._heat_report_at is None:
                self._heat_report_at = self.now + HEAT_REPORT_INTERVAL
            return False
        self._complete(cmd)
        return True

    def _arm_busy_report(self) -> None:
        blocked = bool(self.queue) and self.settings.busy_interval > 0
        if not blocked:
            self._busy_report_at = None
        elif self._busy_report_at is None:
            self._busy_report_at = self.now + self.settings.busy_interval

    def _complete(self, cmd: Command) -> None:
        lines, ok_text = self.machine.finish(cmd, self.now)
        self._busy_report_at = self._heat_report_at = None
        self.log.append((cmd.number, cmd.text))
        self._out.extend(lines)
        if self.settings.advanced_ok and ok_text is None:
            ok_text = self._advanced_ok(cmd.number)
        self.queue.popleft()
        self._ok(ok_text)
        self.read_at = self.now + self.settings.read_delay
        self.busy_until = self.now + self.faults.busy_for()
        if cmd.number is not None and cmd.number > 0:
            self.executed += 1
            self._scheduled_faults()

    def _scheduled_faults(self) -> None:
        s = self.settings
        if s.reset_at_line and not self._reset_done and self.executed >= s.reset_at_line:
            self._reset_done = True
            self.boot()
        elif (s.silence_at_line and not self._silence_done
              and self.executed >= s.silence_at_line):
            self._silence_done = True
            self.silence_left = s.silence_lines
