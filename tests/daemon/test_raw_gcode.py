"""The raw G-code policy of hostd/printer/raw_gcode.py, without a daemon: the checks of a file,
the safe set while a job prints, anything while it is paused (noted for the resume)."""

from __future__ import annotations

import pytest

from hostd.errors import PrinterBusy
from hostd.link.replies import Echo, ErrorReply, Ok
from hostd.printer.errors import ScriptRefused
from hostd.printer.raw_gcode import RAW_MAX_LINES, RawReplies, admit, check_script


class Job:
    """A streamer's state and what it noted."""

    def __init__(self, state: str) -> None:
        self.state = state
        self.noted: list[str] = []

    def note_raw(self, commands: list[str]) -> None:
        self.noted += commands


def test_a_script_is_checked_as_a_file_is() -> None:
    assert check_script("G28\nM104 S200 ; heat\n", None) == ["G28", "M104 S200"]
    with pytest.raises(ScriptRefused, match=r"^script: no G-code commands$"):
        check_script("; nothing\n", None)
    with pytest.raises(ScriptRefused, match=f"more than {RAW_MAX_LINES} commands"):
        check_script("M105\n" * (RAW_MAX_LINES + 1), None)
    with pytest.raises(ScriptRefused, match=r"^script: line 1"):
        check_script("S200\n", None)


def test_only_the_safe_set_goes_while_a_job_prints() -> None:
    printing = Job("streaming")
    admit(["M105", "M104 S210"], printing)
    with pytest.raises(PrinterBusy, match="refused while printing: G28"):
        admit(["M105", "G28"], printing)
    assert printing.noted == []


def test_anything_goes_while_paused_and_the_resume_is_told() -> None:
    paused = Job("paused")
    admit(["G28", "G1 X5"], paused)  # type: ignore[arg-type]  (a stand-in streamer)
    assert paused.noted == ["G28", "G1 X5"]
    admit(["G28"], None)  # no job: nothing to ask


def test_the_replies_name_the_commands_the_firmware_refused() -> None:
    ran = RawReplies(["M105", "M999", "M42"],
                     [Ok(), Echo("Unknown command: \"M999\""), ErrorReply("bad", "other")])
    assert [c for c, _ in ran.refused()] == ["M999", "M42"]
