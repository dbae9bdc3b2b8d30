"""Raw G-code during a pause (jog, home, heat): the resume brings the machine back to the
paused state, turning the platform and travelling only from a safe height."""

from __future__ import annotations

import asyncio

import pytest
from test_streamer import GCODE, FakePort

from hostd.printer.intervention import Need, need_of, need_of_all
from hostd.printer.modal import ModalState
from hostd.printer.program import parse_program
from hostd.printer.streamer import Hooks, Streamer, StreamSettings, safe_z


@pytest.mark.parametrize(("command", "need"), [
    ("M105", Need.NONE), ("M117 jog done", Need.NONE), ("M106 S255", Need.NONE),
    ("G91", Need.NONE), ("G1 E5 F100", Need.NONE), ("G92 E0", Need.NONE), ("G1 F3000", Need.NONE),
    ("M104 S0", Need.HEAT), ("M190 S80", Need.HEAT),
    ("G0 A30 C45", Need.RETURN), ("g1 z-2", Need.RETURN), ("G2 I5 J0", Need.RETURN),
    ("M600", Need.RETURN),  # unknown to us (a filament change parks the head): assume moved
    ("G28", Need.RESTART), ("g28 x", Need.RESTART), ("M84", Need.RESTART),
    ("G92 X0", Need.RESTART), ("G92", Need.RESTART), ("M502", Need.RESTART),
])
def test_what_a_command_asks_of_the_resume(command: str, need: Need) -> None:
    assert need_of(command) is need


def test_a_script_asks_its_highest_need() -> None:
    assert need_of_all([]) is Need.NONE
    assert need_of_all(["M105", "M104 S0", "G1 X5", "M117 x"]) is Need.RETURN
    assert need_of_all(["G1 X5", "G28 Z"]) is Need.RESTART


SCRIPTS = {
    "none": ["M105", "G91", "G1 E3 F100", "G90"],
    "heat": ["M104 S0", "M140 S90"],
    "turn": ["G0 A30 C45", "M104 S0"],
    "jog down": ["G1 X5 Y5 Z0.1 F600"],  # the nozzle under the part's top: a trap
    "home": ["G28"],
    "shift": ["G92 X0 Y0"],
}


async def _pause_do_resume(script: list[str]) -> tuple[Streamer, dict, list[str]]:
    """Pause after line 7, run ``script`` on the board as an operator would, resume."""
    prog = parse_program(GCODE)
    port = FakePort()
    seen: dict = {}

    def on_paused(s: Streamer, reason: str) -> None:
        seen["modal"] = s.paused_modal.copy()
        for cmd in script:
            port.submit(cmd)
        s.note_raw(script)
        seen["board"] = port.fw.copy()  # where the operator left the machine
        seen["log_len"] = len(port.log)
        s.request_resume()

    def on_resumed(s: Streamer) -> None:
        seen["resumed"] = port.fw.copy()
        seen["resume_len"] = len(port.log)

    st = Streamer(port, prog, StreamSettings(lookahead=1, lift=5, safe_height=50), Hooks(
        progress=lambda s: s.request_pause() if s.acked == 7 else None, paused=on_paused,
        resumed=on_resumed))
    async with asyncio.timeout(5):
        assert await st.run() == "completed"
    return st, seen, port.log[seen["log_len"]:seen["resume_len"]]


@pytest.mark.asyncio
@pytest.mark.parametrize("name", list(SCRIPTS))
async def test_the_resume_puts_the_machine_back_whatever_was_done_meanwhile(name: str) -> None:
    _, seen, resume = await _pause_do_resume(SCRIPTS[name])
    paused: ModalState = seen["modal"]
    back: ModalState = seen["resumed"]
    for axis in "XYZAC":
        assert back.position[axis] == pytest.approx(paused.position[axis]), (axis, resume)
    assert (back.hotend, back.bed) == (paused.hotend, paused.bed), resume
    assert (back.absolute, back.e_absolute, back.fan) == (
        paused.absolute, paused.e_absolute, paused.fan)
    if name in ("home", "shift"):
        moves = [i for i, c in enumerate(resume) if c.startswith(("G0", "G1"))]
        assert resume.index("G28") < moves[0]  # the position means nothing until homed
    if name == "heat":
        assert "M140 S0" in resume and "M109 S200" in resume
        down = [i for i, c in enumerate(resume) if c.startswith("G1 Z")]
        assert resume.index("M109 S200") < down[0], resume  # hot, then down onto the part


@pytest.mark.asyncio
@pytest.mark.parametrize("name", ["turn", "jog down", "home", "shift"])
async def test_after_a_move_by_hand_the_way_back_turns_and_travels_only_from_safe_z(
        name: str) -> None:
    """Replayed from where the operator left the machine, no resume move turns the platform
    or travels in X/Y below the safe Z (a tall sub-part may stand under the nozzle)."""
    st, seen, resume = await _pause_do_resume(SCRIPTS[name])
    board: ModalState = seen["board"]
    clear = safe_z(seen["modal"].position["Z"], st.program, st.settings)
    lowered = False
    for cmd in resume:
        before = dict(board.position)
        board.apply(cmd)
        moved = {a for a in "XYAC" if board.position[a] != pytest.approx(before[a])}
        if cmd.startswith("G28"):
            continue
        if moved:
            assert not lowered and before["Z"] >= clear - 1e-9, (cmd, before["Z"], resume)
        if board.position["Z"] < min(before["Z"], clear - 1e-9):
            lowered = True  # the last move of the way back: straight down onto the point
