"""A disk that fills mid-print, for real (issue 38, item 2): hostd's state directory on a small
tmpfs, a print on the emulator, the tmpfs filled, then emptied. Mounting needs root: the test
is skipped, saying so, otherwise (tests/jobs/test_storage_errors.py injects the error)."""

from __future__ import annotations

import asyncio
import contextlib
import os
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest
from hostd_harness import DaemonProc, RpcCallError, make_gcode

pytestmark = pytest.mark.skipif(os.geteuid() != 0, reason="mounting a tmpfs needs root")


@contextlib.contextmanager
def tmpfs(path: Path, size: str) -> Iterator[Path]:
    path.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
                          capture_output=True, text=True, check=False)
    if done.returncode:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip()}")
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], check=False)


def fill(root: Path) -> Path:
    """Write a file until the disk refuses more; the file."""
    filler = root / "filler"
    with open(filler, "wb") as fh:
        with contextlib.suppress(OSError):
            while True:
                fh.write(b"\0" * 65536)
                fh.flush()
    return filler


@pytest.mark.asyncio
@pytest.mark.timeout(180)
async def test_a_disk_that_fills_mid_print_pauses_the_job_and_hostd_recovers_when_emptied(
        tmp_path: Path) -> None:
    with tmpfs(tmp_path / "state", "6m") as state:
        d = DaemonProc(tmp_path, daemon__state_dir=str(state), pause__idle_timeout=1.0,
                       sim__throttle=True, serial__baud=115200)
        await d.start()
        rpc = await d.rpc()
        try:
            async with asyncio.timeout(150):
                job = await rpc.printing(make_gcode(subparts=2, layers=8, per_layer=60), 0.05)
                filler = fill(state)
                paused = await rpc.until_state(job["id"], "paused")
                assert paused["reason"].startswith("storage error: job database")
                assert "database or disk is full" in paused["reason"]
                status = await rpc.call("printer.status")
                assert status["jobs"]["storage"]["failing"] is True
                assert status["jobs"]["current"]["state"] == "paused"
                off = await rpc.until(lambda e: e["event"] == "storage" and e["heaters_off"])
                assert off["failing"]  # pause.idle_timeout passed with the disk still full
                with pytest.raises(RpcCallError) as refused:
                    await rpc.submit_text("next.gcode", "G28\nG1 X1\n")
                assert "internal error" not in refused.value.message
                assert "\n" not in refused.value.message
                filler.unlink()
                await rpc.until(lambda e: e["event"] == "storage" and not e["failing"])
                await rpc.call("job.resume", id=job["id"])
                await rpc.until_state(job["id"], "completed")
            log = [c for _, c in (await rpc.call("sim.log"))["commands"]]
            assert log.index("M140 S0") == log.index("M104 S0") + 1  # off while paused
            assert "M109 S210" in log[log.index("M140 S0"):]  # heated again by the resume
        finally:
            await rpc.close()
            await d.stop()
        assert d.loop_errors() == []
