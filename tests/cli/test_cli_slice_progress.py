"""What hostctl shows of a slice on a terminal: its stage and percentage on one line, gone
once the slice ends; nothing on a pipe."""

from __future__ import annotations

import io

from hostd.cli.cmd_control import SliceProgress, summary_text


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_the_stages_of_a_slice_share_one_line_of_a_terminal():
    out = Terminal()
    show = SliceProgress(out, "peg.3mf")
    show.update({"stage": "decomposing and planning", "percent": 5.0})
    show.update({"stage": "replay check", "percent": 65.0})
    show.done()
    assert out.getvalue() == ("\r\033[Kslicing peg.3mf: decomposing and planning (5%)"
                              "\r\033[Kslicing peg.3mf: replay check (65%)\r\033[K")


def test_nothing_is_shown_on_a_pipe():
    out = io.StringIO()
    show = SliceProgress(out, "peg.3mf")
    show.update({"stage": "replay check", "percent": 65.0})
    show.done()
    assert out.getvalue() == ""


def test_the_summary_line_names_every_figure():
    assert summary_text({"filament_mm": 1234.56, "mass_g": 3.714, "time_s": 754.0,
                         "subparts": 3, "transitions": 2, "resends": 0}) == (
        "summary: 1234.6 mm of filament (3.71 g), 0:12:34, 3 sub-parts, 2 transitions, "
        "0 resends")
    assert summary_text(None) == ""
