from __future__ import annotations

import asyncio
import gc
from collections import deque

import pytest

from hostd.link.errors import LinkLost, NotConnected
from hostd.link.replies import HeaterReading, Position, Temperatures
from hostd.printer.modal import ModalState
from hostd.printer.program import parse_program
from hostd.printer.streamer import BARRIER, Hooks, Streamer, StreamSettings

GCODE = """\
;HOSTD_ESTIMATE {"filament_mm": 10.0, "time_s": 20.0}
G28
M104 S200
M109 S200
G90
M82
;HOSTD_SUBPART {"index": 0, "parent": null}
;HOSTD_LAYER {"subpart": 0, "index": 0}
G1 X10 Y10 Z0.2 E1 F1200 ; first
G1 X20 Y10 E2
;HOSTD_LAYER {"subpart": 0, "index": 1}
G1 X20 Y20 Z0.4 E3
G1 X10 Y20 E4
;HOSTD_TRANSITION {"from": 0, "to": 1, "a": 30, "c": 90, "x": 100, "y": 100, "z": 60}
G0 Z60 F3000
G0 A30 C90 F3000
G0 X100 Y100 F6000
;HOSTD_TRANSITION_END
;HOSTD_SUBPART {"index": 1, "parent": 0}
;HOSTD_LAYER {"subpart": 1, "index": 0}
G1 X101 Y100 Z60.2 E5
G1 X101 Y101 E6
;HOSTD_LAYER {"subpart": 1, "index": 1}
G1 X100 Y101 Z60.4 E7
M104 S0
"""


class FakePort:
    """A tiny firmware: executes in order, acks on the next loop turn, answers M114/M105."""

    def __init__(self, lost_c_after: int | None = None) -> None:
        self.log: list[str] = []
        self.fw = ModalState()
        self.lost_c_after = lost_c_after
        self.acks = 0

    def submit(self, command: str) -> asyncio.Future[None]:
        self.log.append(command)
        self.fw.apply(command)
        if self.lost_c_after is not None and len(self.log) == self.lost_c_after:
            self.fw.position["C"] += 1.5  # the C stepper lost steps
        fut = asyncio.get_running_loop().create_future()
        asyncio.get_running_loop().call_soon(self._ack, fut, len(self.log))
        return fut

    def _ack(self, fut: asyncio.Future[None], seq: int) -> None:
        self.acks = max(self.acks, seq)  # the submission number of the last line acked
        fut.set_result(None)

    def submit_many(self, commands: list[str]) -> tuple[int, asyncio.Future[None]]:
        first = len(self.log) + 1
        futs = [self.submit(c) for c in commands]
        return first, futs[-1]

    def withdraw(self, first: int, last: int) -> int:
        return 0  # every line goes out as it is submitted

    def acknowledged(self) -> int:
        return self.acks

    async def query(self, command: str):
        self.log.append(command)
        if command == "M114":
            return (Position({k: self.fw.position[k] for k in "XYZAC"}),)
        return (Temperatures({"T": HeaterReading(self.fw.hotend, self.fw.hotend)}),)


class FailingPort(FakePort):
    """Acknowledges the first ``good`` lines on the next loop turns, then loses the link:
    every line not yet acknowledged fails with the last acknowledged one named."""

    def __init__(self, good: int) -> None:
        super().__init__()
        self.good = good
        self.lost = False
        self.futs: list[asyncio.Future[int]] = []

    def submit(self, command: str) -> asyncio.Future[int]:  # type: ignore[override]
        if self.lost:
            raise NotConnected("link is disconnected", self.good)
        self.log.append(command)
        loop = asyncio.get_running_loop()
        fut: asyncio.Future[int] = loop.create_future()
        self.futs.append(fut)
        seq = len(self.futs)
        loop.call_soon(fut.set_result if seq <= self.good else self._lose, seq)
        return fut

    def _lose(self, _seq: int) -> None:
        self.lost = True
        for fut in self.futs:
            if not fut.done():
                fut.set_exception(LinkLost("port lost", self.good))


LAYERED = "G90\nM83\n" + "".join(
    (f';HOSTD_LAYER {{"subpart": 0, "index": {i // 5}}}\n' if i % 5 == 0 else "")
    + f"G1 X{i} Y{i % 7} Z{0.2 * (1 + i // 5):.1f} E0.1 F1200\n" for i in range(40))


EXTRA = {"M400", "M114", "M105"}


def file_commands(log: list[str], extras: list[str]) -> list[str]:
    """The file's commands as executed: the log minus the host's own commands, matched as a
    subsequence (the log must hold exactly ``len(extras)`` more lines than the file)."""
    prog_cmds = parse_program(GCODE).commands
    it, out = 0, []
    for cmd in log:
        if it < len(prog_cmds) and cmd == prog_cmds[it]:
            out.append(cmd)
            it += 1
    assert len(log) == len(out) + len(extras)
    return out


@pytest.mark.asyncio
async def test_program_markers():
    prog = parse_program(GCODE)
    assert prog.total == 16 and prog.estimate == {"filament_mm": 10.0, "time_s": 20.0}
    assert [(m.subpart, m.layer) for m in prog.layers] == [(0, 0), (0, 1), (1, 0), (1, 1)]
    (tr,) = prog.transitions
    assert (tr.start, tr.end, tr.subpart, tr.parent) == (9, 12, 1, 0)
    assert tr.target == {"X": 100.0, "Y": 100.0, "Z": 60.0, "A": 30.0, "C": 90.0}
    assert prog.resume_index(15, "layer") == 14 and prog.resume_index(15, "subpart") == 12
    assert prog.commands[5] == "G1 X10 Y10 Z0.2 E1 F1200"


@pytest.mark.asyncio
async def test_stream_completes_every_line_once_in_order_with_transaction():
    prog = parse_program(GCODE)
    port = FakePort()
    checkpoints, events, progress = [], [], []
    hooks = Hooks(progress=lambda s: progress.append(s.acked),
                  checkpoint=lambda s, tr, pose: checkpoints.append((tr.subpart, pose["A"],
                                                                     pose["C"], tr.end)),
                  event=lambda name, data: events.append(name))
    st = Streamer(port, prog, StreamSettings(lookahead=4), hooks)
    async with asyncio.timeout(5):
        assert await st.run() == "completed"
    assert file_commands(port.log, st.stats.extra_commands) == prog.commands
    i = port.log.index("G0 Z60 F3000")
    assert port.log[i - 3:i] == ["M400", "M105", "M109 S200"] or port.log[i - 2:i] == [
        "M400", "M105"]
    j = port.log.index("G0 X100 Y100 F6000")
    assert port.log[j + 1:j + 4] == [BARRIER, "M400", "M114"]  # the block's lines all acked
    assert checkpoints == [(1, 30.0, 90.0, 12)]
    assert "subpart_started" in events and "job.subpart" in events
    assert progress == sorted(progress) and progress[-1] == prog.total
    assert st.stats.transitions == 1 and st.stats.transition_failures == 0


@pytest.mark.asyncio
async def test_pause_records_modal_state_and_resume_restores_it():
    prog = parse_program(GCODE)
    port = FakePort()
    paused = asyncio.Event()
    seen: dict = {}
    st: Streamer

    def on_progress(s: Streamer) -> None:
        if s.acked == 7:
            s.request_pause()

    def on_paused(s: Streamer, reason: str) -> None:
        seen["modal"] = s.paused_modal.snapshot()
        seen["acked"] = s.acked
        seen["log_len"] = len(port.log)
        paused.set()

    st = Streamer(port, prog, StreamSettings(lookahead=1, lift=5), Hooks(
        progress=on_progress, paused=on_paused))
    async with asyncio.timeout(5):
        task = asyncio.create_task(st.run())
        await paused.wait()
        assert seen["modal"] == prog.modal_before(seen["acked"]).snapshot()
        pause_cmds = port.log[seen["log_len"] - 6:seen["log_len"]]
        assert pause_cmds == ["M400", "M83", "G1 E-1.0000 F2100", "G90", "G1 Z5.2000 F600",
                              "M400"]  # lookahead 1: paused right after line 7, at Z0.2
        assert not any(c.startswith(("G0 A", "G1 A")) for c in pause_cmds)  # no rotation
        st.request_resume()
        assert await task == "completed"
    after = port.log[seen["log_len"]:]
    assert after[:3] == ["G90", "G1 X20.0000 Y10.0000 F7200", "G1 Z0.2000 F600"]
    assert "G92 E2.00000" in after and "M82" in after and "G1 F1200" in after
    assert file_commands(port.log, st.stats.extra_commands) == prog.commands


class HookedPort(FakePort):
    """Calls ``on(command)`` as each command is submitted (an operator acting meanwhile)."""

    def __init__(self, on) -> None:
        super().__init__()
        self.on = on

    def submit(self, command: str) -> asyncio.Future[None]:
        fut = super().submit(command)
        self.on(command)
        return fut


@pytest.mark.asyncio
@pytest.mark.parametrize("then", ["cancel", "resume"])
async def test_a_cancel_or_resume_asked_during_the_pause_moves_is_kept(then: str):
    # Before: the pause cleared the resume flag after its retract and lift, so a cancel asked
    # meanwhile was lost (the job stayed paused; the next resume cancelled it) and a resume
    # left it paused.
    prog = parse_program(GCODE)
    st: Streamer

    def on(command: str) -> None:
        if command == "G1 Z5.2000 F600":  # the pause's lift, on its way
            st.request_cancel() if then == "cancel" else st.request_resume()

    port = HookedPort(on)
    st = Streamer(port, prog, StreamSettings(lookahead=1, lift=5), Hooks(
        progress=lambda s: s.request_pause() if s.acked == 7 else None))
    async with asyncio.timeout(5):
        result = await st.run()  # no further request: the one asked is enough
    assert result == ("cancelled" if then == "cancel" else "completed")
    assert ("G1 X10 Y20 E4" in port.log) == (then == "resume")


@pytest.mark.asyncio
async def test_cancel_runs_end_script():
    prog = parse_program(GCODE)
    port = FakePort()
    st = Streamer(port, prog, StreamSettings(lookahead=2, safe_height=50), Hooks(
        progress=lambda s: s.request_cancel() if s.acked == 6 else None))
    async with asyncio.timeout(5):
        assert await st.run() == "cancelled"
    # safe_z filled as the slicer does, and as high as the file's transitions lift (Z60):
    # Z + safe_height alone (50.2) would turn the platform under a taller earlier sub-part
    assert port.log[-6:] == ["M104 S0", "M140 S0", "M107", "G0 Z60.0 F3000",
                             "G0 A0 C0 F3000", "M84"]
    assert "G1 X10 Y20 E4" not in port.log


@pytest.mark.asyncio
async def test_a_cancel_ends_as_high_as_the_files_transitions_lift_not_their_approach():
    """The slicer's transition lifts to its marker's ``safe_z`` (above everything printed)
    and then approaches the next sub-part lower down; a cancel (and a restart) must turn the
    platform no lower than that lift. Before, the approach Z (60) was taken: the QA saw a
    return turn 27 mm below the file's own on pipe2."""
    text = GCODE.replace('"z": 60}', '"z": 60, "safe_z": 95.5}').replace(
        "G0 Z60 F3000\nG0 A30", "G0 Z95.5 F3000\nG0 A30")
    prog = parse_program(text)
    assert prog.transitions[0].safe_z == 95.5 and prog.transition_z == 95.5
    port = FakePort()
    st = Streamer(port, prog, StreamSettings(lookahead=2, safe_height=50), Hooks(
        progress=lambda s: s.request_cancel() if s.acked == 6 else None))
    async with asyncio.timeout(5):
        assert await st.run() == "cancelled"
    assert port.log[-3:] == ["G0 Z95.5 F3000", "G0 A0 C0 F3000", "M84"]


@pytest.mark.asyncio
async def test_a_cancel_fills_format_specs_as_the_slicer_and_the_config_check_do():
    # Before: the cancel filled {safe_z} as a string, so "{safe_z:.1f}" (accepted by the
    # config check, which fills a float) failed the cancel and left the heaters on.
    prog = parse_program(GCODE)
    port = FakePort()
    end = "M104 S0\nG0 Z{safe_z:.1f} F3000\nM140 S{bed_temperature:.0f}\n"
    st = Streamer(port, prog, StreamSettings(lookahead=2, safe_height=50, end_gcode=end,
                                             end_values={"bed_temperature": 0}),
                  Hooks(progress=lambda s: s.request_cancel() if s.acked == 6 else None))
    async with asyncio.timeout(5):
        assert await st.run() == "cancelled"
    assert port.log[-3:] == ["M104 S0", "G0 Z60.0 F3000", "M140 S0"]


@pytest.mark.asyncio
async def test_lost_step_pauses_at_transition_and_resume_rehomes_and_rotates():
    prog = parse_program(GCODE)
    port = FakePort()
    port.lost_c_after = None
    paused = asyncio.Event()
    events: list[tuple[str, dict]] = []
    reasons: list[str] = []

    def on_event(name: str, data: dict) -> None:
        events.append((name, data))
        if name == "job.subpart":
            return

    def on_paused(s: Streamer, reason: str) -> None:
        reasons.append(reason)
        paused.set()

    # lose steps while the block rotates (the 2nd block command is the A/C move)
    orig_submit = port.submit

    def submit(command: str):
        fut = orig_submit(command)
        if command.startswith("G0 A30"):
            port.fw.position["C"] += 1.5
        return fut

    port.submit = submit  # type: ignore[method-assign]
    st = Streamer(port, prog, StreamSettings(lookahead=4), Hooks(paused=on_paused,
                                                                 event=on_event))
    async with asyncio.timeout(5):
        task = asyncio.create_task(st.run())
        await paused.wait()
        assert "transition to sub-part 1 failed" in reasons[0] and "C 91.5" in reasons[0]
        (failed,) = [d for n, d in events if n == "transition_failed"]
        assert failed["measured"]["C"] == 91.5 and failed["expected"]["C"] == 90.0
        n = len(port.log)
        st.request_resume()
        assert await task == "completed"
    after = port.log[n:]
    first_layer = prog.commands[12]
    k = after.index(first_layer)
    restart = after[:k]
    assert restart[0] == "G28" and "M109 S200" in restart
    assert restart.index("G0 Z120.0000 F600") < restart.index("G0 A30.0000 C90.0000 F3000")
    assert st.stats.transition_failures == 1


@pytest.mark.asyncio
@pytest.mark.parametrize("good", [0, 3, 4, 6, 9, 17])
async def test_a_lost_link_leaves_the_acknowledged_count_exact(good: int) -> None:
    """Batches of four lines (lookahead 8) with the link lost after ``good`` lines: the
    streamer stops with the link's error and counts exactly the lines acknowledged, also
    when the loss falls inside a batch."""
    prog = parse_program(LAYERED)
    port = FailingPort(good)
    st = Streamer(port, prog, StreamSettings(lookahead=8))
    async with asyncio.timeout(5):
        with pytest.raises(LinkLost):
            await st.run()
    assert st.acked == good and port.log == prog.commands[:len(port.log)]
    assert len(port.log) > good  # lines were out beyond the last acknowledged one
    mark = prog.layer_at(good - 1) if good else prog.layer_at(0)
    assert (st.subpart, st.layer) == ((mark.subpart, mark.layer) if mark else (None, None))


class SlowPort(FakePort):
    """Acknowledges one line per loop turn, in order; counts the lines out at once."""

    def __init__(self) -> None:
        super().__init__()
        self.waiting: deque[asyncio.Future[None]] = deque()
        self.most_out = 0

    def submit(self, command: str) -> asyncio.Future[None]:
        self.log.append(command)
        self.fw.apply(command)
        fut = asyncio.get_running_loop().create_future()
        self.waiting.append(fut)
        self.most_out = max(self.most_out, len(self.waiting))
        if len(self.waiting) == 1:
            asyncio.get_running_loop().call_soon(self._ack_one)
        return fut

    def _ack_one(self) -> None:
        self.waiting.popleft().set_result(None)
        if self.waiting:
            asyncio.get_running_loop().call_soon(self._ack_one)


@pytest.mark.asyncio
@pytest.mark.parametrize(("lookahead", "most"), [(1, 1), (2, 2), (5, 4), (16, 16)])
async def test_at_most_lookahead_lines_are_out(lookahead: int, most: int) -> None:
    """However slowly the lines are acknowledged, the streamer keeps the link fed with up to
    ``lookahead`` lines submitted and not yet acknowledged, never more: whole batches of half
    the lookahead (two of two lines for a lookahead of 5)."""
    prog = parse_program(LAYERED)
    port = SlowPort()
    st = Streamer(port, prog, StreamSettings(lookahead=lookahead))
    async with asyncio.timeout(5):
        assert await st.run() == "completed"
    assert port.log == [*prog.commands, BARRIER, "M400"]  # done when the moves are
    assert port.most_out == most


@pytest.mark.asyncio
@pytest.mark.parametrize("lookahead", [4, 16])
@pytest.mark.parametrize("read_every", [1, 3, 7])
async def test_modal_state_and_layer_are_those_of_the_acknowledged_prefix(read_every: int,
                                                                         lookahead: int):
    """Read now and then (as a status poll does), the modal state is always the one the
    acknowledged commands leave, and the layer the one of the last acknowledged command."""
    prog = parse_program(GCODE)
    seen: list[int] = []

    def check(s: Streamer) -> None:
        seen.append(s.acked)
        assert 0 <= s.status()["inflight"] <= lookahead  # lines submitted, not yet acked
        if len(seen) % read_every == 0:
            assert s.modal.snapshot() == prog.modal_before(s.acked).snapshot()
        mark = prog.layer_at(s.acked - 1)
        assert (s.subpart, s.layer) == ((mark.subpart, mark.layer) if mark else (None, None))

    st = Streamer(FakePort(), prog, StreamSettings(lookahead=lookahead),
                  Hooks(progress=check))
    async with asyncio.timeout(5):
        assert await st.run() == "completed"
    assert seen[-1] == prog.total and st.modal.snapshot() == prog.modal_before(
        prog.total).snapshot()


@pytest.mark.asyncio
async def test_a_pause_asked_inside_a_transition_waits_for_the_whole_block():
    prog = parse_program(GCODE)
    (tr,) = prog.transitions
    port = FakePort()
    paused = asyncio.Event()

    def on_progress(s: Streamer) -> None:
        if s.acked == tr.start + 1:  # the block's first command is done, two are to come
            s.request_pause()

    st = Streamer(port, prog, StreamSettings(lookahead=1), Hooks(
        progress=on_progress, paused=lambda s, reason: paused.set()))
    async with asyncio.timeout(5):
        task = asyncio.create_task(st.run())
        await paused.wait()
        block = prog.commands[tr.start:tr.end]
        i = port.log.index(block[0])
        # the block, then its M400 and read-back, and only then the pause
        assert port.log[i:i + len(block) + 3] == [*block, BARRIER, "M400", "M114"]
        assert port.log[i + len(block) + 3] == "M400" and st.acked == tr.end
        st.request_resume()
        assert await task == "completed"
    assert file_commands(port.log, st.stats.extra_commands) == prog.commands


class BatchPort(FakePort):
    """As the serial link does: one future a batch, for its last line. The first ``good``
    lines are acknowledged; then nothing is, until :meth:`close` fails what is out."""

    def __init__(self, good: int) -> None:
        super().__init__()
        self.good = good
        self.futs: list[asyncio.Future[None]] = []

    def submit_many(self, commands: list[str]) -> tuple[int, asyncio.Future[None]]:
        first = len(self.log) + 1
        self.log.extend(commands)
        fut = asyncio.get_running_loop().create_future()
        if len(self.log) <= self.good:
            fut.set_result(None)
        else:
            self.futs.append(fut)
        return first, fut

    async def query(self, command: str):
        self.log.append(command)  # answered only if the link lives on
        fut = asyncio.get_running_loop().create_future()
        self.futs.append(fut)
        return (await fut,)

    def close(self) -> None:
        for fut in self.futs:
            if not fut.done():  # as the link: a query cancelled by its caller is let be
                fut.set_exception(LinkLost("port lost: closed", self.good))


def never_retrieved(contexts: list[dict]) -> list[str]:
    return [c["message"] for c in contexts if "never retrieved" in c.get("message", "")]


@pytest.mark.asyncio
@pytest.mark.parametrize("ending", ["link lost", "cancelled, then closed"])
@pytest.mark.parametrize("where", ["streaming", "final drain"])
async def test_batches_left_out_are_let_go_without_a_never_retrieved_error(ending: str,
                                                                          where: str):
    """A run ended by the link's error, or cancelled at shutdown with the link closed after
    it, leaves no batch future (nor the drain's barrier) whose exception asyncio would log
    as never retrieved."""
    loop = asyncio.get_running_loop()
    contexts: list[dict] = []
    loop.set_exception_handler(lambda _loop, context: contexts.append(context))
    try:
        # 40 lines: two batches acknowledged, two out, then it waits for credit; or 12: the
        # third batch out, then the drain at the end waits with its barrier
        prog = parse_program(LAYERED if where == "streaming" else
                             "\n".join(LAYERED.splitlines()[:14]) + "\n")
        port = BatchPort(good=8)
        st = Streamer(port, prog, StreamSettings(lookahead=8))
        async with asyncio.timeout(5):
            task = asyncio.create_task(st.run())
            while (len(port.log) < 16 if where == "streaming" else BARRIER not in port.log):
                await asyncio.sleep(0)
            if ending == "link lost":
                port.close()
                with pytest.raises(LinkLost):
                    await task
            else:
                task.cancel()
                with pytest.raises(asyncio.CancelledError):
                    await task
                port.close()
            await asyncio.sleep(0)  # the callbacks of the futures just failed run
        assert len(st._inflight) >= 1  # batches were still out when the run ended
        del port, st, task
        gc.collect()
    finally:
        loop.set_exception_handler(None)
    assert never_retrieved(contexts) == []


@pytest.mark.asyncio
async def test_a_cancel_whose_end_script_cannot_be_filled_still_turns_the_heaters_off():
    prog = parse_program(GCODE)
    port = FakePort()
    st = Streamer(port, prog, StreamSettings(lookahead=2, end_gcode="G0 Z{unknown}\n"),
                  Hooks(progress=lambda s: s.request_cancel() if s.acked == 6 else None))
    async with asyncio.timeout(5):
        assert await st.run() == "cancelled"
    assert port.log[-4:] == ["M104 S0", "M140 S0", "M107", "M84"]
