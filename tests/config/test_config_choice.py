"""Which configuration hostd runs on: ``--config``, else the installed /etc/hostd/hostd.yaml;
with neither it refuses in one line (exit 2) rather than run on the built-in emulator."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

import hostd.daemon
import hostd.main
from hostd.config import Config
from hostd.config.paths import DEFAULT_CONFIG


def _config(path: Path, port: str) -> Path:
    path.write_text(yaml.safe_dump({"serial": {"port": port}}))
    return path


@pytest.fixture
def started(monkeypatch: pytest.MonkeyPatch) -> list[Config]:
    """The configurations the daemon was started with (it is not started)."""
    configs: list[Config] = []

    def run_daemon(config: Config) -> int:
        configs.append(config)
        return 0

    monkeypatch.setattr(hostd.daemon, "run_daemon", run_daemon)
    return configs


def test_without_config_and_no_installed_one_hostd_refuses_naming_both_ways(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
        started: list[Config]):
    installed = tmp_path / "etc" / "hostd.yaml"
    monkeypatch.setattr(hostd.main, "INSTALLED_CONFIG", installed)
    assert hostd.main.main([]) == 2
    out, err = capsys.readouterr()
    assert (out, started) == ("", [])
    assert err == (f"hostd: no configuration: {installed} does not exist; pass --config FILE "
                   f"(--config {DEFAULT_CONFIG} runs on the built-in defaults: the emulator, "
                   "serial.port sim://)\n")


def test_without_config_the_installed_one_is_read(tmp_path: Path,
                                                  monkeypatch: pytest.MonkeyPatch,
                                                  started: list[Config]):
    installed = _config(tmp_path / "hostd.yaml", "/dev/ttyACM0")
    monkeypatch.setattr(hostd.main, "INSTALLED_CONFIG", installed)
    assert hostd.main.main([]) == 0
    assert [(c.source, c["serial.port"]) for c in started] == [(str(installed),
                                                               "/dev/ttyACM0")]


def test_config_names_the_file_even_when_one_is_installed(tmp_path: Path,
                                                          monkeypatch: pytest.MonkeyPatch,
                                                          started: list[Config]):
    monkeypatch.setattr(hostd.main, "INSTALLED_CONFIG",
                        _config(tmp_path / "installed.yaml", "/dev/ttyACM0"))
    assert hostd.main.main(["--config", str(DEFAULT_CONFIG)]) == 0
    assert [(c.source, c["serial.port"]) for c in started] == [(str(DEFAULT_CONFIG), "sim://")]


def test_an_installed_config_that_cannot_be_read_is_named_with_its_error(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
        started: list[Config]):
    """/etc/hostd a file, not a directory: not "does not exist", but the file and why."""
    (tmp_path / "etc").write_text("")
    installed = tmp_path / "etc" / "hostd.yaml"
    monkeypatch.setattr(hostd.main, "INSTALLED_CONFIG", installed)
    assert hostd.main.main([]) == 2
    err = capsys.readouterr().err
    assert started == [] and err.startswith(f"hostd: {installed}: cannot read: ")
    assert err.count("\n") == 1 and "Not a directory" in err


def test_hostctl_finds_the_daemon_of_a_default_socket_without_a_config():
    """hostctl reads no configuration: its default socket is the daemon's default one."""
    from hostd.cli.client import DEFAULT_SOCKET
    from hostd.config.loader import defaults

    assert DEFAULT_SOCKET == defaults()["daemon.socket"]
