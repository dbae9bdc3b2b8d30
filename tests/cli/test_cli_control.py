"""hostctl's daemon verbs against a hostd subprocess: output, --json and exit codes."""

from __future__ import annotations

import asyncio
import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "daemon"))
from hostd_harness import DaemonProc, make_gcode

ROOT = Path(__file__).resolve().parents[2]


async def hostctl(sock: Path, *args: str) -> tuple[int, str, str]:
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "hostd.cli.main", "--socket", str(sock), *args,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE, cwd=str(ROOT))
    out, err = await proc.communicate()
    return proc.returncode or 0, out.decode(), err.decode()


@pytest.mark.asyncio
async def test_hostctl_verbs_and_exit_codes(tmp_path):
    d = DaemonProc(tmp_path)
    gcode = tmp_path / "part.gcode"
    gcode.write_text(make_gcode(subparts=2, layers=2, per_layer=40))
    async with asyncio.timeout(90):
        rc, _, err = await hostctl(tmp_path / "none.sock", "status")
        assert rc == 3 and err.startswith("hostctl: cannot connect to hostd")
        await d.start()
        try:
            rc, out, err = await hostctl(d.socket, "print", str(gcode), "--wait")
            assert rc == 0, err
            assert "job 1 completed" in out and "100.0%" in out
            rc, out, _ = await hostctl(d.socket, "jobs", "--json")
            jobs = json.loads(out)
            assert rc == 0 and jobs[0]["state"] == "completed"
            rc, out, _ = await hostctl(d.socket, "status", "--json")
            assert rc == 0 and json.loads(out)["jobs"]["finished"]["completed"] == 1
            rc, out, _ = await hostctl(d.socket, "status")
            assert rc == 0 and "no job printing" in out
            rc, out, _ = await hostctl(d.socket, "send", "M114", "--json")
            assert rc == 0 and "position" in json.loads(out)["replies"][0]
            rc, _, err = await hostctl(d.socket, "pause")
            assert rc == 4 and err.startswith("hostctl: no job is printing")
            rc, _, err = await hostctl(d.socket, "print", str(tmp_path / "missing.stl"))
            assert rc == 2 and "missing.stl" in err
            empty = tmp_path / "empty.gcode"
            empty.write_text("")
            rc, _, err = await hostctl(d.socket, "print", str(empty))
            assert rc == 4 and "empty upload" in err
            rc, out, _ = await hostctl(d.socket, "print", str(gcode), "--json")
            assert rc == 0 and json.loads(out)["id"] == 2
        finally:
            await d.stop()
