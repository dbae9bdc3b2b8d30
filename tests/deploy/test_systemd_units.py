from __future__ import annotations

import configparser
import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
UNITS = ROOT / "systemd"
analyze = shutil.which("systemd-analyze")
needs_systemd = pytest.mark.skipif(analyze is None, reason="systemd-analyze not installed")


def _unit(name: str) -> configparser.ConfigParser:
    parser = configparser.ConfigParser(strict=False, interpolation=None)
    parser.optionxform = str  # type: ignore[assignment,method-assign]
    parser.read(UNITS / name)
    return parser


def _service() -> configparser.ConfigParser:
    return _unit("hostd.service")


def test_service_has_the_required_settings() -> None:
    svc = _service()["Service"]
    assert svc["Type"] == "notify"
    assert svc["Restart"] == "on-failure"
    assert "dialout" in svc["SupplementaryGroups"]
    for key in ("RuntimeDirectory", "StateDirectory", "WatchdogSec", "NoNewPrivileges",
                "ProtectSystem", "ProtectHome", "PrivateTmp", "RestrictAddressFamilies",
                "DeviceAllow", "LimitNOFILE"):
        assert key in svc, key


def test_the_units_open_files_hold_the_default_connection_caps() -> None:
    """Issue 38: with no LimitNOFILE, a thousand idle connections used up the open files and
    locked everyone out. The unit's limit holds the default caps and their reserve (hostd
    refuses to start when its caps need more than the limit), and the system call filter
    leaves hostd no way to raise it itself."""
    from hostd.config import defaults
    from hostd.daemon import descriptors_needed

    svc = _service()["Service"]
    assert descriptors_needed(defaults()) <= int(svc["LimitNOFILE"])
    assert "@resources" in svc["SystemCallFilter"]


def _installable(tmp_path: Path) -> Path:
    """Copies of the units whose ExecStart points at an executable that exists here."""
    exe = shutil.which("true") or "/bin/true"
    for unit in UNITS.iterdir():
        text = re.sub(r"/opt/hostd/bin/hostd\b", exe, unit.read_text())
        (tmp_path / unit.name).write_text(text)
    return tmp_path


@needs_systemd
def test_units_verify(tmp_path: Path) -> None:
    units = _installable(tmp_path)
    res = subprocess.run([analyze, "verify", str(units / "hostd.service"),
                          str(units / "hostd.socket")], capture_output=True, text=True,
                         timeout=60)
    problems = [ln for ln in res.stderr.splitlines() if "hostd" in ln]
    assert res.returncode == 0 and not problems, res.stderr


@needs_systemd
def test_security_exposure_below_three(tmp_path: Path) -> None:
    units = _installable(tmp_path)
    res = subprocess.run([analyze, "security", "--offline=true", "--no-pager",
                          str(units / "hostd.service")], capture_output=True, text=True,
                         timeout=60)
    match = re.search(r"Overall exposure level for hostd\.service: ([0-9.]+)", res.stdout)
    if match is None:
        pytest.skip(f"this systemd cannot score unit files offline: {res.stderr.strip()[:200]}")
    assert float(match.group(1)) < 3.0


def test_runtime_directory_outlives_the_service() -> None:
    """hostd.socket's socket lives in /run/hostd: systemd must not delete the directory
    (and the socket with it) each time the service stops."""
    svc = _service()["Service"]
    assert svc["RuntimeDirectory"] == "hostd"
    assert svc.get("RuntimeDirectoryPreserve") == "yes"


def test_the_socket_unit_is_optional_as_the_readme_says() -> None:
    """The README calls hostd.socket optional: the service orders itself after it but
    pulls it in by no dependency (Wants=, Requires=, BindsTo=)."""
    unit = _service()["Unit"]
    for key in ("Wants", "Requires", "BindsTo", "Requisite"):
        assert "hostd.socket" not in unit.get(key, ""), key
    readme = (ROOT / "README.md").read_text()
    assert "`hostd.socket` is optional" in readme
    assert "systemctl enable --now hostd.socket" in readme


def test_loopback_only_network_is_documented_at_metrics_host() -> None:
    """The unit allows only localhost: metrics.host's documentation says how to let a remote
    Prometheus in, in the generated config and README alike."""
    svc = _service()["Service"]
    assert svc["IPAddressDeny"] == "any" and svc["IPAddressAllow"] == "localhost"
    from hostd.config.schema import SCHEMA

    doc = SCHEMA["metrics"]["host"].doc
    assert "IPAddressAllow" in doc
    assert "IPAddressAllow" in (ROOT / "config" / "hostd.yaml").read_text()


def test_the_unit_and_the_install_steps_use_the_config_hostd_reads_by_default() -> None:
    """hostd without --config reads INSTALLED_CONFIG: the README installs the config there
    and the unit checks and runs that file."""
    from hostd.config.paths import INSTALLED_CONFIG

    svc = _service()["Service"]
    assert svc["ExecStart"].endswith(f" --config {INSTALLED_CONFIG}")
    assert svc["ExecStartPre"].endswith(f" --check-config {INSTALLED_CONFIG}")
    readme = (ROOT / "README.md").read_text()
    assert f"install -D -m 0644 config/hostd.yaml {INSTALLED_CONFIG}" in readme


TMPFILES = UNITS / "hostd.tmpfiles.conf"
tmpfiles = shutil.which("systemd-tmpfiles")


def _tmpfiles_lines() -> list[list[str]]:
    text = TMPFILES.read_text()
    return [line.split() for line in text.splitlines() if line.strip() and line[0] != "#"]


def test_run_hostd_is_made_by_tmpfiles_as_the_service_makes_it() -> None:
    """Socket activation before the service first ran made /run/hostd root's (0750): the
    hostd group could not reach the socket. systemd-tmpfiles makes it at boot, before any
    socket unit listens: where the socket unit and the daemon put the socket, owned and
    moded as the service's RuntimeDirectory=."""
    from hostd.config.loader import defaults

    svc, sock = _service()["Service"], _unit("hostd.socket")["Socket"]
    socket_dir = Path(sock["ListenStream"]).parent
    assert socket_dir == Path(defaults()["daemon.socket"]).parent
    assert socket_dir == Path("/run") / svc["RuntimeDirectory"]
    assert _tmpfiles_lines() == [["d", str(socket_dir), svc["RuntimeDirectoryMode"],
                                  svc["User"], svc["Group"], "-"]]
    assert (sock["SocketUser"], sock["SocketGroup"]) == (svc["User"], svc["Group"])


def test_the_install_steps_install_and_apply_the_tmpfiles_snippet() -> None:
    readme = (ROOT / "README.md").read_text()
    steps = readme[readme.index("## Install on a Raspberry Pi"):readme.index("## Configure")]
    install = "sudo install -m 0644 systemd/hostd.tmpfiles.conf /etc/tmpfiles.d/hostd.conf"
    create = "sudo systemd-tmpfiles --create /etc/tmpfiles.d/hostd.conf"
    assert install in steps and create in steps
    assert (steps.index("sudo useradd") < steps.index(install) < steps.index(create)
            < steps.index("systemctl enable"))  # the user first; the directory before a socket


def _root_with_hostd_user(root: Path) -> Path:
    """A directory tree for systemd-tmpfiles --root: a hostd user in its own /etc."""
    (root / "etc").mkdir(parents=True)
    (root / "run").mkdir()
    (root / "etc" / "passwd").write_text("root:x:0:0::/root:/bin/sh\n"
                                         "hostd:x:987:986::/var/lib/hostd:/usr/sbin/nologin\n")
    (root / "etc" / "group").write_text("root:x:0:\nhostd:x:986:\n")
    return root


@pytest.mark.skipif(tmpfiles is None, reason="systemd-tmpfiles not installed")
@pytest.mark.skipif(os.geteuid() != 0, reason="chown to another user needs root")
@pytest.mark.parametrize("socket_first", [False, True])
def test_systemd_tmpfiles_gives_run_hostd_to_hostd(tmp_path: Path, socket_first: bool) -> None:
    """At boot, or after a socket unit already made the directory root's 0750 (the install
    steps run systemd-tmpfiles after the units are in place): hostd:hostd 0750."""
    root = _root_with_hostd_user(tmp_path)
    run_hostd = root / "run" / "hostd"
    if socket_first:
        run_hostd.mkdir(mode=0o750)
    res = subprocess.run([str(tmpfiles), "--create", f"--root={root}", str(TMPFILES)],
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    st = run_hostd.stat()
    assert (st.st_uid, st.st_gid, oct(st.st_mode & 0o7777)) == (987, 986, "0o750")
