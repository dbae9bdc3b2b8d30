"""Deterministic test bench: the pure Protocol and the emulated Firmware on a virtual clock.

No asyncio and no wall clock: a discrete-event loop carries bytes both ways with a fixed
latency, runs the firmware's planner and heaters in simulated time and fires the protocol's
timeouts, so a 10 000-line job with faults runs in about a second and always the same way.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass, field

from hostd.link.actions import Acked, Action, Answer, Connected, Failed, Write
from hostd.link.errors import LinkError
from hostd.link.framing import checksum
from hostd.link.protocol import Protocol
from hostd.link.settings import LinkSettings
from hostd.sim.firmware import Firmware
from hostd.sim.settings import SimSettings

NUDGE = "M105"


@dataclass
class Outcome:
    """What happened on the virtual wire."""

    acked: list[int] = field(default_factory=list)
    failures: list[LinkError] = field(default_factory=list)
    answers: list[Answer] = field(default_factory=list)
    connects: int = 0
    ack_ahead_of_execution: list[tuple[int, int]] = field(default_factory=list)
    sent: list[bytes] = field(default_factory=list)
    events: list[Action] = field(default_factory=list)  # every action but Write, in order
    end_time: float = 0.0
    max_inflight_bytes: int = 0  # most unanswered bytes the host had out at once


class VirtualBench:
    """Protocol ⇄ latency ⇄ Firmware, on one virtual clock."""

    def __init__(self, link: LinkSettings, sim: SimSettings, latency: float = 0.0005,
                 read_every: float | None = None) -> None:
        self.protocol = Protocol(link)
        self.firmware = Firmware(sim)
        self.latency = latency
        # None: each reply is handed over alone; else the replies arriving within this many
        # seconds of the first (and before anything else happens) are read together
        self.read_every = read_every
        self.now = 0.0
        self.outcome = Outcome()
        self._queue: list[tuple[float, int, str, bytes | str]] = []
        self._seq = 0
        self._fw_clear = 0.0
        self._host_clear = 0.0
        self._log_seen = 0
        self._jobs_done = 0
        self._base = 0

    # -- wiring -------------------------------------------------------------------------

    def _push(self, when: float, kind: str, payload: bytes | str) -> None:
        self._seq += 1
        heapq.heappush(self._queue, (when, self._seq, kind, payload))

    def _apply(self, actions: list[Action]) -> None:
        for action in actions:
            if isinstance(action, Write):
                self.outcome.sent.append(action.data)
                self.outcome.max_inflight_bytes = max(self.outcome.max_inflight_bytes,
                                                      self.protocol.inflight_bytes)
                self._fw_clear = max(self._fw_clear, self.now) + 1e-9
                self._push(self._fw_clear + self.latency, "fw", action.data)
                continue
            self.outcome.events.append(action)
            if isinstance(action, Acked):
                self._check_ack(action.line)
                self.outcome.acked.append(action.line)
            elif isinstance(action, Failed):
                self.outcome.failures.append(action.error)
            elif isinstance(action, Connected):
                self.outcome.connects += 1
            elif isinstance(action, Answer):
                self.outcome.answers.append(action)

    def _check_ack(self, seq: int) -> None:
        log = self.firmware.log
        for number, text in log[self._log_seen:]:
            self._jobs_done += (number is not None and number > 0 and text != NUDGE
                                and not text.startswith("M110"))
        self._log_seen = len(log)
        executed = self._jobs_done
        if seq > executed - self._base:
            self.outcome.ack_ahead_of_execution.append((seq, executed))

    def _firmware_output(self) -> None:
        for line in self.firmware.take_output().decode("ascii").splitlines():
            self._host_clear = max(self._host_clear, self.now) + 1e-9
            self._push(self._host_clear + self.latency, "host", line)

    # -- running ------------------------------------------------------------------------

    def connect(self, max_time: float = 60.0) -> bool:
        """Handshake; True when connected."""
        self._firmware_output()
        self._apply(self.protocol.start(self.now))
        self._run_until(lambda: self.protocol.state != "handshake", max_time)
        return self.protocol.state == "ready"

    def stream(self, commands: list[str], ahead: int = 64, max_time: float = 1e7,
               emergency_at: int | None = None, queries: tuple[str, ...] = ()) -> Outcome:
        """Submit ``commands`` keeping ``ahead`` unacknowledged; run until done or failed.

        Commands starting with one of ``queries`` go as queries (answered in
        ``outcome.answers``)."""
        self._base = len(job_log(self.firmware)) - self.protocol.last_acked
        self._log_seen = len(self.firmware.log)
        self._jobs_done = len(job_log(self.firmware))
        next_index = 0

        def refill() -> None:
            nonlocal next_index
            while (next_index < len(commands) and self.protocol.state == "ready"
                   and next_index - self.protocol.last_acked < ahead):
                command = commands[next_index]
                kind = "query" if queries and command.startswith(queries) else "line"
                _, actions = self.protocol.submit(command, self.now, kind=kind)
                next_index += 1
                self._apply(actions)
                if emergency_at is not None and next_index == emergency_at:
                    self._apply(self.protocol.emergency_stop(self.now))

        def done() -> bool:
            refill()
            return bool(self.outcome.failures) or self.protocol.last_acked >= len(commands)

        self._run_until(done, max_time)
        self.outcome.end_time = self.now
        return self.outcome

    def _run_until(self, done: object, max_time: float) -> None:
        check = done if callable(done) else (lambda: True)
        while not check() and self.now < max_time:
            if not self._step():
                break

    def _step(self) -> bool:
        candidates = []
        if self._queue:
            candidates.append((self._queue[0][0], "queue"))
        deadline = self.protocol.deadline()
        if deadline is not None:
            candidates.append((deadline, "timer"))
        event = self.firmware.next_event()
        if event is not None:
            candidates.append((event, "firmware"))
        if not candidates:
            return False
        when, kind = min(candidates)
        self.now = max(self.now, when)
        if kind == "timer":
            self._apply(self.protocol.tick(self.now))
        elif kind == "firmware":
            self.firmware.advance(self.now)
            self._firmware_output()
        else:
            self._deliver()
        return True

    def _deliver(self) -> None:
        _, _, kind, payload = heapq.heappop(self._queue)
        if kind == "fw":
            assert isinstance(payload, bytes)
            self.firmware.advance(self.now)
            self.firmware.receive(payload)
            self._firmware_output()
        else:
            assert isinstance(payload, str)
            lines = [payload]
            while (self.read_every is not None and self._queue
                   and self._queue[0][2] == "host"
                   and self._queue[0][0] <= self.now + self.read_every):
                lines.append(str(heapq.heappop(self._queue)[3]))
            self._apply(self.protocol.receive_lines(lines, self.now))


def wire_lines(sent: list[bytes]) -> list[bytes]:
    """The lines the host put on the wire (writes joined: a line may go out in parts)."""
    *lines, rest = b"".join(sent).split(b"\n")
    assert rest == b"", f"a line was left unfinished: {rest!r}"
    return lines


def assert_whole_valid_lines(sent: list[bytes]) -> None:
    """Every line on the wire is a whole, valid framed line (or M112): the parts of a line
    that went out in parts were never interleaved with anything else."""
    for line in wire_lines(sent):
        if line == b"M112":
            continue
        body, star, cs = line.partition(b"*")
        assert line[:1] == b"N" and star and int(cs) == checksum(body.decode()), line


def job_log(firmware: Firmware) -> list[str]:
    """Numbered commands the firmware executed, without the handshake, the M105 nudges and
    the ``M110`` s that resynchronise the numbering after a resend request."""
    return [text for number, text in firmware.log
            if number is not None and number > 0 and text != NUDGE
            and not text.startswith("M110")]
