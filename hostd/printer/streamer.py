"""Feed one job's G-code to the printer: progress, pause/resume, cancel, transitions.

The streamer is the only writer of job lines. It keeps at most ``lookahead`` lines submitted
and not yet acknowledged, applies the acknowledged commands to its :class:`ModalState` (once
per batch of acknowledgements, and whenever the state is read, so what a reader sees is
always the state of the acknowledged prefix), and between two lines it may stop: for a
pause (retract, lift along Z, wait, restore), a cancel (the end script) or a rotate/return
transition run as a transaction (M400, temperature check, block, M400, M114 readback,
checkpoint). Wherever it waits for every line to be acknowledged, an ``M105`` goes after them
as a barrier (:meth:`Streamer._drain`), so a plain ``ok`` lost on the wire costs no timeout.
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

from hostd.link.errors import LinkError
from hostd.link.replies import Ok, Position, Reply, Temperatures
from hostd.printer.errors import PrinterError, TransitionFailed
from hostd.printer.intervention import Need, need_of_all
from hostd.printer.modal import ModalState
from hostd.printer.program import Program, Transition
from hostd.printer.settings import StreamSettings

log = logging.getLogger(__name__)
FALLBACK_END = "M104 S0\nM140 S0\nM107\nM84\n"
"""What a cancel sends when the end script cannot be filled: heaters, fan and motors off."""
BARRIER = "M105"  # answered "ok T:...": the ok that says which line it acknowledges


class Port(Protocol):
    """What the streamer needs from the serial link."""

    def submit(self, command: str) -> asyncio.Future[Any]:
        """Queue one line (never blocks); the future completes when it is acknowledged."""
        ...

    def submit_many(self, commands: Sequence[str]) -> tuple[int, asyncio.Future[Any]]:
        """Queue lines in order (never blocks): the submission number of the first, and a
        future that completes when the last is acknowledged. If the link fails first, the
        future raises the link's :class:`~hostd.link.errors.LinkError`, whose
        ``last_acked`` is the last submission number acknowledged."""
        ...

    def withdraw(self, first: int, last: int) -> int:
        """Take back the lines submitted as ``first`` .. ``last`` that have not gone out;
        returns how many (the last ones). The future of a batch cut short now completes when
        its last line kept is acknowledged; one of a batch taken back whole is cancelled."""
        ...

    async def query(self, command: str) -> tuple[Reply, ...]:
        """Send ``command``, wait for its ok, return the replies that arrived for it."""
        ...

    def acknowledged(self) -> int:
        """The highest submission number acknowledged so far (the futures of a batch
        complete only with its last line)."""
        ...


@dataclass
class Hooks:
    """Callbacks into the job manager (all synchronous and quick)."""

    progress: Callable[[Streamer], None] = lambda s: None
    paused: Callable[[Streamer, str], None] = lambda s, reason: None
    resumed: Callable[[Streamer], None] = lambda s: None
    checkpoint: Callable[[Streamer, Transition, dict[str, float]], None] = (
        lambda s, t, pose: None)
    event: Callable[[str, dict[str, Any]], None] = lambda name, data: None


@dataclass(slots=True)
class Batch:
    """Program commands ``start`` .. ``stop - 1``, submitted together: the first's submission
    number and the future of the last's acknowledgement."""

    start: int
    stop: int
    first: int
    acked: asyncio.Future[Any]


@dataclass
class StreamStats:
    transitions: int = 0
    transition_failures: int = 0
    extra_commands: list[str] = field(default_factory=list)


class Streamer:
    """Run ``program`` from command ``start`` on ``port``.

    :meth:`run` returns ``"completed"`` or ``"cancelled"`` and raises
    :class:`~hostd.link.errors.LinkError` or :class:`PrinterError` when the print cannot go on.
    """

    def __init__(self, port: Port, program: Program, settings: StreamSettings,
                 hooks: Hooks | None = None, start: int = 0,
                 modal: ModalState | None = None, prelude: list[str] | None = None) -> None:
        self.port = port
        self.program = program
        self.settings = settings
        self.hooks = hooks or Hooks()
        self.start = start
        self.acked = start  # commands 0 .. acked-1 are acknowledged
        self._modal = modal if modal is not None else program.modal_before(start)
        self._modal_upto = start  # _modal is the state after commands 0 .. _modal_upto-1
        self.prelude = list(prelude or [])
        mark = program.layer_at(start)
        self.subpart: int | None = mark.subpart if mark else None
        self.layer: int | None = mark.layer if mark else None
        self._next_layer = program.next_layer_start(start)
        self.stats = StreamStats()
        self.paused_modal: ModalState | None = None
        self.pause_reason = ""
        self._inflight: deque[Batch] = deque()
        self._pause_req = asyncio.Event()
        self._resume = asyncio.Event()
        self._cancel = asyncio.Event()
        self._stop_asked = False  # a pause or cancel is asked for: stop between two lines
        self._stoppable = False  # lines being fed may be taken back (not a transition's)
        self._rewind: int | None = None  # the first command taken back: the next to submit
        self._needs_restart = False
        self._intervention = Need.NONE  # what raw G-code during a pause asks of the resume
        self.state = "idle"

    @property
    def modal(self) -> ModalState:
        """The modal state the acknowledged commands leave."""
        self._catch_up()
        return self._modal

    def _catch_up(self) -> None:
        """Apply the commands acknowledged since the last call to the modal state (the
        streamer does so once per batch of acknowledgements, a reader whenever it reads)."""
        if self.acked > self._modal_upto:
            self._modal.apply_many(self.program.commands[self._modal_upto:self.acked])
        self._modal_upto = self.acked

    # -- control (from the job manager) --------------------------------------------------

    def request_pause(self, reason: str = "paused by operator") -> None:
        if self.state == "streaming":
            self.pause_reason = reason
            self._pause_req.set()
            self._stop()

    def request_resume(self) -> None:
        self._resume.set()

    def request_cancel(self) -> None:
        self._cancel.set()
        self._resume.set()
        self._stop()

    def _stop(self) -> None:
        """Stop between two lines: at once, as far as the link has not sent them yet."""
        self._stop_asked = True
        if self._stoppable:
            self._withdraw()

    def _withdraw(self) -> None:
        """Take back from the link the lines of the newest batches not gone out yet; the run
        goes on (after the pause) from the first one taken back. So a pause or cancel acts
        after the few lines the firmware holds, not after the whole lookahead."""
        inflight = self._inflight
        while inflight:
            batch = inflight[-1]
            count = batch.stop - batch.start
            taken = self.port.withdraw(batch.first, batch.first + count - 1)
            if not taken:
                return
            self._rewind = batch.stop - taken
            if taken < count:
                batch.stop -= taken
                return
            inflight.pop()  # its future is cancelled

    # -- the run ---------------------------------------------------------------------------

    async def run(self) -> str:
        """Stream the program; ``completed`` or ``cancelled``, or the link's error."""
        try:
            return await self._run()
        finally:  # stopped by a link error or cancelled: the batches still out are let go
            for batch in self._inflight:
                batch.acked.add_done_callback(_let_go)

    async def _run(self) -> str:
        self.state = "streaming"
        for cmd in self.prelude:
            await self._extra(cmd)
        index = self.start
        while index < self.program.total:
            if self._cancel.is_set():
                return await self._finish_cancel()
            if self._pause_req.is_set():
                await self._pause()
                if self._cancel.is_set():
                    return await self._finish_cancel()
                continue
            tr = self.program.transition_at(index)
            if tr is not None:
                ok = await self._transition(tr)
                index = tr.end  # on a mismatch the resume re-homes and reaches the target
                if not ok:
                    await self._pause(move=False)
                    if self._cancel.is_set():
                        return await self._finish_cancel()
                continue
            index = await self._feed(index, self.program.next_transition_start(index))
            if self._rewind is not None:
                index, self._rewind = self._rewind, None
        # M400: the job is done when its moves are, not when its last line is taken into
        # the planner (seconds of moves may still be queued while "completed" tells the
        # operator to clear the platform)
        await self._extra("M400")
        self.state = "done"
        return "completed"

    async def _feed(self, index: int, end: int, stoppable: bool = True) -> int:
        """Submit commands ``index`` .. ``end - 1`` in order; returns the next one to submit,
        ``end`` unless ``stoppable`` and a pause or cancel was asked for.

        Commands go out in batches of half the ``lookahead``, each with one future for its
        last line: with ``lookahead`` lines out, it sleeps until the oldest batch is
        acknowledged (one wake-up per batch, not per ``ok``), takes note of every
        acknowledged batch, and submits the next. The link's queue stays at least half full,
        far more than the firmware's buffer takes.
        """
        self._stoppable = stoppable
        try:
            return await self._feed_batches(index, end, stoppable)
        finally:
            self._stoppable = False

    async def _feed_batches(self, index: int, end: int, stoppable: bool) -> int:
        inflight, commands = self._inflight, self.program.commands
        submit_many = self.port.submit_many
        size = max(1, self.settings.lookahead // 2)
        batches = max(1, self.settings.lookahead // size)
        while index < end and not (stoppable and self._stop_asked):
            if len(inflight) >= batches:
                # a batch taken back whole (a pause) is cancelled, which wakes this too
                await _settled(inflight[0].acked)
            if inflight and inflight[0].acked.done():
                while inflight and inflight[0].acked.done():
                    self._ack_head()
                self._catch_up()  # here, not in a status call that would hold the loop
            if stoppable and self._stop_asked:
                break
            stop = min(end, index + size)
            first, fut = submit_many(commands[index:stop])
            inflight.append(Batch(index, stop, first, fut))
            index = stop
        return index

    def _ack_head(self) -> None:
        """Take note of the (done) oldest batch; raises the link's error if it failed, after
        taking note of the lines of the batch acknowledged before the failure."""
        batch = self._inflight[0]
        try:
            batch.acked.result()
        except LinkError as err:
            done = min(max(0, err.last_acked - batch.first + 1), batch.stop - batch.start)
            self._acked_to(batch.start + done)
            raise
        self._inflight.popleft()
        self._acked_to(batch.stop)
        self.hooks.progress(self)

    def sync_acked(self) -> int:
        """The commands acknowledged now, to the line: the batches' futures complete a batch
        (half the lookahead) at a time, while the link counts every ``ok``. Taken note of as
        :meth:`_ack_head` does (layer, modal state), so what is recorded of an interrupted
        job (its line, its progress) is the firmware's last acknowledged line, not the end
        of the last whole batch, up to a lookahead behind."""
        if not self._inflight:
            return self.acked
        last = self.port.acknowledged()
        for batch in self._inflight:
            done = min(max(0, last - batch.first + 1), batch.stop - batch.start)
            if batch.start + done > self.acked:
                self._acked_to(batch.start + done)
            if done < batch.stop - batch.start:
                break
        return self.acked

    def _acked_to(self, stop: int) -> None:
        """Commands up to ``stop - 1`` are acknowledged: follow the layer to the last."""
        self.acked = stop
        if stop > self._next_layer:
            self._track_layer(stop - 1)

    def _track_layer(self, index: int) -> None:
        self._next_layer = self.program.next_layer_start(index)
        mark = self.program.layer_at(index)
        if mark is None:
            return
        if mark.subpart != self.subpart:
            self.subpart, self.layer = mark.subpart, mark.layer
            self.hooks.event("job.subpart", {"subpart": mark.subpart, "layer": mark.layer})
        else:
            self.layer = mark.layer

    async def _drain(self) -> None:
        """Until every line submitted is acknowledged (before a transition, a pause, the end).

        An ``M105`` follows them as a barrier: its ``ok T:`` is the one answer that names its
        line, so it acknowledges every line before it even when the plain ``ok`` of one of
        them was lost on the wire, which the link would otherwise only notice at its
        ``serial.ok_timeout`` (10 s of the nozzle standing on the part)."""
        if not self._inflight:
            return
        self.stats.extra_commands.append(BARRIER)
        barrier = asyncio.ensure_future(self.port.query(BARRIER))
        try:
            while self._inflight:
                await _settled(self._inflight[0].acked)
                self._ack_head()
            await barrier
        finally:  # cancelled, or a batch failed: the link fails the barrier too
            if not barrier.done():
                barrier.cancel()
            elif not barrier.cancelled():
                barrier.exception()  # retrieved: the batch's error is the one raised

    async def _extra(self, command: str) -> None:
        """A command of the host's own (pause, restore, transaction), acknowledged at once."""
        await self._drain()
        self.stats.extra_commands.append(command)
        await self.port.submit(command)

    # -- pause / resume --------------------------------------------------------------------

    async def _pause(self, move: bool = True) -> None:
        # Cleared first, so that a resume or cancel asked while the pause's own lines are
        # out is kept: cleared after them, a cancel was lost and the job stayed paused.
        if not self._cancel.is_set():
            self._resume.clear()
        await self._drain()
        self.paused_modal = self.modal.copy()
        self.state = "paused"
        s = self.settings
        if move:
            for cmd in self.modal.pause_commands(s.retract, s.lift, s.z_max, s.retract_f,
                                                 s.lift_f):
                await self._extra(cmd)
        self.hooks.paused(self, self.pause_reason)
        await self._resume.wait()
        self._pause_req.clear()
        self._stop_asked = self._cancel.is_set()
        if self._cancel.is_set():
            return
        for cmd in self._resume_commands(move):
            await self._extra(cmd)
        self._needs_restart = False
        self._intervention = Need.NONE
        self.state = "streaming"
        self.pause_reason = ""
        self.hooks.resumed(self)

    def note_raw(self, commands: Sequence[str]) -> None:
        """Raw G-code an operator sends while the job is paused: the resume puts back what
        it may change (:mod:`hostd.printer.intervention`)."""
        if self.state == "paused":
            self._intervention = max(self._intervention, need_of_all(commands))

    def _resume_commands(self, move: bool) -> list[str]:
        """What brings the machine back to the paused state: after a failed transition or a
        hand that homed it, re-home and the whole way back; after a move by hand, the way
        back from a safe height; after a heater changed, the targets; else the way down
        from the pause's lift (``move``: the pause retracted and lifted)."""
        s, m, need = self.settings, self.modal, self._intervention
        if self._needs_restart:
            need = Need.RESTART
        out = m.heaters_off_commands() if self._intervention >= Need.HEAT else []
        if need >= Need.RETURN:
            out += m.restart_commands(self._safe_z(), s.travel_f, s.rotary_f, s.lift_f,
                                      home=need is Need.RESTART)
            if move:  # the pause's retract, undone where the nozzle is back on the part
                out += ["M83", f"G1 E{s.retract:.4f} F{s.retract_f:.0f}", *m.mode_commands()]
            return out
        if need is Need.HEAT:
            out += m.heat_commands()
        if move:
            out += m.resume_commands(s.retract, s.retract_f, s.travel_f, s.lift_f)
        return out

    def _safe_z(self) -> float:
        return safe_z(self.modal.position["Z"], self.program, self.settings)

    async def _finish_cancel(self) -> str:
        await self._drain()
        self.state = "cancelling"
        for raw in self._end_script().splitlines():
            cmd = raw.split(";", 1)[0].strip()
            if cmd:
                await self._extra(cmd)
        self.state = "done"
        return "cancelled"

    def _end_script(self) -> str:
        """The end script filled as the slicer fills it; if it cannot be (the config check
        makes that a bug), the heaters go off all the same."""
        values = {**self.settings.end_values, "safe_z": round(self._safe_z(), 3)}
        try:
            return self.settings.end_gcode.format_map(values)
        except (KeyError, IndexError, ValueError, TypeError) as exc:
            log.error("end script cannot be filled (%s): heaters off, motors off instead", exc)
            return FALLBACK_END

    # -- transitions -------------------------------------------------------------------------

    async def _transition(self, tr: Transition) -> bool:
        """Run the block ``tr`` as a transaction; False (job to pause) on a mismatch."""
        await self._extra("M400")
        await self._check_temperature()
        await self._feed(tr.start, tr.end, stoppable=False)  # a transaction: never cut short
        await self._drain()
        await self._extra("M400")
        self.stats.extra_commands.append("M114")
        measured = _position(await self.port.query("M114"))
        try:
            self._compare(tr, measured)
        except TransitionFailed as exc:
            self.stats.transition_failures += 1
            self.pause_reason = f"transition to sub-part {tr.subpart} failed: {exc}"
            self.hooks.event("transition_failed", {
                "subpart": tr.subpart, "parent": tr.parent, "reason": str(exc),
                "expected": exc.expected, "measured": exc.measured, "line": tr.end})
            # the machine is not where the file believes: resume re-homes and goes to the
            # block's target from a safe height before the sub-part's first layer
            self._needs_restart = True
            return False
        self.stats.transitions += 1
        self.hooks.checkpoint(self, tr, measured)
        self.hooks.event("subpart_started", {
            "subpart": tr.subpart, "parent": tr.parent, "a": measured.get("A"),
            "c": measured.get("C"), "line": tr.end, "pose": measured})
        return True

    async def _check_temperature(self) -> None:
        target = self.modal.hotend
        if target <= 0:
            return
        self.stats.extra_commands.append("M105")
        temps = _temperatures(await self.port.query("M105"))
        actual = temps.get("T")
        if actual is None or abs(actual - target) > self.settings.temperature_tolerance:
            log.info("hotend at %s, target %s: waiting before the transition", actual, target)
            await self._extra(f"M109 S{target:g}")

    def _compare(self, tr: Transition, measured: dict[str, float]) -> None:
        bad = []
        for axis, want in tr.target.items():
            got = measured.get(axis)
            tol = (self.settings.angle_tolerance if axis in "AC"
                   else self.settings.position_tolerance)
            if got is None or not math.isfinite(got) or abs(got - want) > tol:
                bad.append(f"{axis} {got} (expected {want:g})")
        if bad:
            raise TransitionFailed("position read back " + ", ".join(bad), tr.target, measured)

    def _inflight_lines(self) -> int:
        return self._inflight[-1].stop - self.acked if self._inflight else 0

    def status(self) -> dict[str, Any]:
        return {"state": self.state, "acked": self.acked, "total": self.program.total,
                "subpart": self.subpart, "layer": self.layer, "inflight": self._inflight_lines(),
                "a": self.modal.position["A"], "c": self.modal.position["C"],
                "transitions": self.stats.transitions,
                "transition_failures": self.stats.transition_failures,
                "pause_reason": self.pause_reason}


def _let_go(fut: asyncio.Future[Any]) -> None:
    """Take the outcome of a batch no one waits for any more: the link's error that ended the
    run (or a later close) is reported once, not again as a never-retrieved exception."""
    if not fut.cancelled():
        fut.exception()


async def _settled(fut: asyncio.Future[Any]) -> None:
    """Wait until ``fut`` is done, whether it succeeded or failed (its owner reads it)."""
    if not fut.done():
        await asyncio.wait((fut,))


def _position(replies: tuple[Reply, ...]) -> dict[str, float]:
    for r in reversed(replies):
        if isinstance(r, Position):
            return dict(r.axes)
    raise PrinterError("M114 gave no position")


def _temperatures(replies: tuple[Reply, ...]) -> dict[str, float]:
    for r in reversed(replies):
        temps = r.temperatures if isinstance(r, Ok) else r
        if isinstance(temps, Temperatures):
            out = {k: h.actual for k, h in temps.heaters.items()}
            if "T" not in out and "T0" in out:
                out["T"] = out["T0"]
            return out
    return {}


def safe_z(z: float, program: Program, settings: StreamSettings) -> float:
    """The machine Z to turn the platform at (a restart) or to end at (a cancel), from Z
    ``z``: ``settings.safe_height`` above it, and no lower than the file's own transitions
    lift (:attr:`Program.transition_z`): a tall sub-part printed earlier may reach higher
    than the one printing when the platform turns. At most ``settings.z_max``."""
    lifted = z + settings.safe_height
    clear = program.transition_z
    return min(settings.z_max, lifted if clear is None else max(lifted, clear))
