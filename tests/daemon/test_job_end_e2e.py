"""A part from a slicer's file to the end of its job (issue 36, items 4 and 5): a 3MF sliced
with its stages told, printed on sim://, its summary in ``hostctl print --wait`` and
``hostctl job N``, the ``notify.command`` hook given the job's JSON; a part whose slice fails
makes ``hostctl print`` exit 1 with the reason on stderr, with or without ``--wait``."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
import trimesh
from hostd_harness import DaemonProc, hostctl, make_gcode
from mesh_files import IDENTITY, three_mf

from slicer.mesh.samples import cylinder
from slicer.pipeline import STAGES

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.asyncio


@contextlib.asynccontextmanager
async def fifo_lines(path: Path) -> AsyncIterator[asyncio.StreamReader]:
    """Lines written to the FIFO ``path`` (made here), read on the loop: the test holds a
    writer of its own, so a hook's writer closing is no end of the stream."""
    os.mkfifo(path)
    reader_fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    writer_fd = os.open(path, os.O_WRONLY)
    loop = asyncio.get_running_loop()
    stream = asyncio.StreamReader()
    transport, _ = await loop.connect_read_pipe(
        lambda: asyncio.StreamReaderProtocol(stream), os.fdopen(reader_fd, "rb"))
    try:
        yield stream
    finally:
        transport.close()
        os.close(writer_fd)


async def test_a_3mf_job_slices_with_its_stages_prints_and_ends_with_its_summary(tmp_path):
    part = tmp_path / "peg.3mf"
    part.write_bytes(three_mf(cylinder(radius=6.0, height=12.0), None, [IDENTITY]))
    d = DaemonProc(tmp_path, notify__command=f"cat > {tmp_path / 'hook'}")
    async with asyncio.timeout(240), fifo_lines(tmp_path / "hook") as hook:
        await d.start()
        try:
            watcher = await d.rpc()
            await watcher.call("events.subscribe", events=["job.slicing"])
            rc, out, err = await hostctl(d.socket, "print", str(part), "--wait")
            assert rc == 0, err
            told: list[dict[str, Any]] = []
            while not watcher.events.empty():
                told.append(watcher.events.get_nowait())
            hooked = json.loads(await hook.readline())
            rc_job, shown, _ = await hostctl(d.socket, "job", "1")
            job = json.loads((await hostctl(d.socket, "job", "1", "--json"))[1])
            await watcher.close()
        finally:
            await d.stop()
    assert "job 1 completed" in out
    summary = job["info"]["summary"]
    assert summary["filament_mm"] > 0 and summary["subparts"] >= 1
    assert summary["resends"] == 0 and summary["transitions"] == summary["transitions_planned"]
    assert out.splitlines()[-1].startswith(f"summary: {summary['filament_mm']:.1f} mm of "
                                           "filament (")
    assert job["kind"] == "stl" and job["info"]["format"] == "3mf"
    stages = [e["stage"] for e in told]
    assert stages[0] == STAGES[0][0] and stages[-1] == "done"
    assert [e["percent"] for e in told] == sorted(e["percent"] for e in told)
    assert {e["job_id"] for e in told} == {1}
    assert rc_job == 0 and shown.startswith("job 1 completed: peg.3mf")
    assert "  file: 3mf," in shown and f"  {out.splitlines()[-1]}" in shown
    history = shown.split("  history:\n")[1].splitlines()
    assert [line.strip().split("  ")[1] for line in history] == [
        "new -> queued", "queued -> slicing", "slicing -> ready", "ready -> printing",
        "printing -> completed"]
    assert hooked["id"] == 1 and hooked["state"] == "completed"
    assert hooked["info"]["summary"] == summary and "history" in hooked


@pytest.mark.parametrize("wait", [False, True])
async def test_print_of_a_part_whose_slice_fails_exits_1_with_the_reason_on_stderr(
        tmp_path, wait):
    """Without ``--wait`` too: hostctl waits for the slice (exit 0 before: the failure was
    seen only in ``hostctl jobs``)."""
    wide = tmp_path / "wide.stl"  # wider than the platform: its slice fails
    trimesh.creation.box([400.0, 400.0, 10.0]).export(wide, file_type="stl")
    d = DaemonProc(tmp_path)
    async with asyncio.timeout(120):
        await d.start()
        try:
            rc, out, err = await hostctl(d.socket, "print", str(wide),
                                         *(["--wait"] if wait else []))
            c = await d.rpc()
            job = await c.call("job.get", id=1)
            await c.close()
        finally:
            await d.stop()
    assert job["state"] == "failed" and "does not fit" in job["reason"]
    assert rc == 1 and err == f"hostctl: job 1 failed: {job['reason']}\n"
    assert f"job 1 failed: {job['reason']}" in out if wait else out == ""


async def test_a_failing_notify_command_is_a_warning_and_the_queue_goes_on(tmp_path):
    gcode = tmp_path / "part.gcode"
    gcode.write_text(make_gcode(subparts=1, layers=2, per_layer=10))
    d = DaemonProc(tmp_path, notify__command="echo 'no mail server' >&2; exit 3")
    async with asyncio.timeout(90):
        await d.start()
        try:
            c = await d.rpc()
            await c.call("events.subscribe", events=["job.state"])
            for _ in (1, 2):
                rc, _, err = await hostctl(d.socket, "print", str(gcode), "--wait")
                assert rc == 0, err
            status = await c.call("printer.status")
            await c.close()
        finally:
            await d.stop()
    warned = [line for line in d.stderr if "notify.command for job" in line]
    assert warned and warned[0].rstrip().endswith(
        "notify.command for job 1 (completed): exit status 3: no mail server")
    assert status["notify"]["runs"] >= 1
