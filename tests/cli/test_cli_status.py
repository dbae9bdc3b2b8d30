"""hostctl status: what it prints of the link."""

from __future__ import annotations

from hostd.cli.cmd_control import link_trouble


def test_link_trouble_names_the_counters_that_are_not_zero() -> None:
    assert link_trouble({"timeouts": 0, "resend_requests": 0, "reconnects": 0}) == ""
    assert link_trouble({"timeouts": 2, "resend_requests": 1, "checksum_errors": 0,
                         "resets": None}) == "2 ok timeouts, 1 resend request"


def test_the_progress_bar_shows_a_dash_before_the_first_layer() -> None:
    import io

    from hostd.cli.cmd_control import ProgressBar

    bar = ProgressBar(io.StringIO(), 1, "part.gcode")
    bar.state = "printing"
    start = bar.render({"progress": 0.01, "subpart": None, "layer": None, "eta_s": None})
    assert "sub-part - layer - ETA --:--" in start and "None" not in start
    later = bar.render({"progress": 0.5, "subpart": 2, "layer": 0, "eta_s": 75})
    assert later.endswith("sub-part 2 layer 0 ETA 0:01:15")
    assert later.startswith("[" + "#" * 15 + "." * 15 + "]  50.0% printing")


def test_an_empty_socket_path_is_refused() -> None:
    import pytest

    from hostd.cli.main import build_parser

    with pytest.raises(SystemExit) as done:
        build_parser().parse_args(["--socket", "", "status"])
    assert done.value.code == 2


class FakeClient:
    """Answers job.list with the jobs given (names as a database might hold them)."""

    def __init__(self, jobs: list[dict]) -> None:
        self.jobs = jobs

    def __enter__(self) -> FakeClient:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def call(self, method: str, **params: object) -> dict:
        assert method == "job.list"
        return {"jobs": self.jobs, "total": len(self.jobs)}


def test_jobs_prints_a_name_with_control_characters_on_one_line(monkeypatch, capsys) -> None:
    import argparse

    from hostd.cli import cmd_control

    job = {"id": 1, "state": "completed", "progress": 1.0, "acked_lines": 3, "total_lines": 3,
           "name": "a\nWARNING fake.gcode\x1b[2J\u2028", "reason": "done\r"}
    monkeypatch.setattr(cmd_control, "_client", lambda args: FakeClient([job]))
    assert cmd_control.cmd_jobs(argparse.Namespace(limit=20, json=False)) == 0
    out = capsys.readouterr().out
    assert out.count("\n") == 1 and "\x1b" not in out and "\r" not in out
    assert "a\\nWARNING fake.gcode\\x1b[2J\\u2028  (done\\r)" in out
    assert cmd_control.printable("pipé 3.stl") == "pipé 3.stl"


def test_the_default_socket_is_defined_once() -> None:
    from pathlib import Path

    import hostd.cli
    from hostd.cli import client, main

    assert main.DEFAULT_SOCKET is client.DEFAULT_SOCKET
    sources = [p.read_text() for p in Path(hostd.cli.__file__).parent.glob("*.py")]
    assert sum(s.count('"/run/hostd/hostd.sock"') for s in sources) == 1


def test_send_hints_how_to_quote_a_command_with_its_parameters() -> None:
    from hostd.cli.cmd_control import _quoting_hint

    assert _quoting_hint(["G28", "M105"]) is None  # every argument a command: no hint
    assert _quoting_hint(["M104", "S200"]) == (
        'quote a command with its parameters: hostctl send "M104 S200"')
    assert _quoting_hint(["M104", "T0", "S200", "T1", "G28", "X", "Y"]) == (
        'quote a command with its parameters: hostctl send "M104 T0 S200" T1 "G28 X Y"')
    # a word with more than letters, digits, spaces and . + -: quoted as shlex quotes it
    assert _quoting_hint(["M117 it's", "X1"]).endswith("""send 'M117 it'"'"'s X1'""")
