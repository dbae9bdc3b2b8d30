"""hostd refuses a state directory it cannot use with one line naming it, and exits 1."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.timeout(60)
@pytest.mark.parametrize("blocked", ["spool", "cache"])
def test_a_file_where_a_state_directory_belongs_is_a_one_line_error(
        tmp_path: Path, blocked: str):
    state = tmp_path / "state"
    state.mkdir()
    (state / blocked).write_text("not a directory")
    config = tmp_path / "hostd.yaml"
    config.write_text(yaml.safe_dump({
        "daemon": {"socket": str(tmp_path / "hostd.sock"), "state_dir": str(state)},
        "metrics": {"enabled": False}, "serial": {"port": "sim://"}}))
    done = subprocess.run([sys.executable, "-m", "hostd.main", "--config", str(config)],
                          cwd=ROOT, capture_output=True, text=True, timeout=50, check=False)
    assert done.returncode == 1, done.stderr
    assert "Traceback" not in done.stderr
    errors = [line for line in done.stderr.splitlines() if "ERROR" in line]
    assert len(errors) == 1 and "daemon.state_dir" in errors[0]
    assert str(state / blocked) in errors[0]
    assert not (tmp_path / "hostd.sock").exists()
