"""The files hostd prints from are its own (issue 38, item 3): the spool and the slice cache
are 0700 with files 0600, and a spool file changed after its checks is refused when the job
starts (or resumes), not printed unchecked."""

from __future__ import annotations

import asyncio
import stat
from pathlib import Path

import pytest
from test_manager_races import MARKS, GatedManager, add_job, printed

from hostd.jobs.spool import Spool, SpoolError
from hostd.jobs.states import JobState
from hostd.slice_cache import SliceCache, write_durably


def mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_the_spool_and_the_cache_are_the_daemons_alone(tmp_path: Path) -> None:
    for name in ("spool", "cache"):  # as an older hostd left them: open to the group
        (tmp_path / name).mkdir(mode=0o770)
        (tmp_path / name).chmod(0o770)
        (tmp_path / name / f"{'0' * 64}.gcode").write_text("G28\n")
        (tmp_path / name / f"{'0' * 64}.gcode").chmod(0o660)
    spool = Spool(tmp_path / "spool", 1 << 20)
    cache = SliceCache(tmp_path / "cache")
    sha = spool.put(b"G28\nG1 X1\n", ".gcode")
    write_durably(cache.gcode_path("k"), b"G28\n")
    cache.store("k", {})
    assert mode(tmp_path / "spool") == mode(tmp_path / "cache") == 0o700
    files = [spool.path(sha, ".gcode"), *(tmp_path / "cache").iterdir(),
             *(tmp_path / "spool").iterdir()]
    assert {mode(f) for f in files} == {0o600}


def test_a_file_changed_in_the_spool_is_refused_naming_the_change(tmp_path: Path) -> None:
    spool = Spool(tmp_path / "spool", 1 << 20)
    sha = spool.put(b"G28\nM104 S200\n", ".gcode")
    assert spool.read(sha, ".gcode") == b"G28\nM104 S200\n"
    spool.path(sha, ".gcode").write_bytes(b"G28\nM104 S400\n")  # same name, other content
    with pytest.raises(SpoolError, match=rf"spool file {sha[:12]}.gcode changed after its "
                                         r"checks .*: not used"):
        spool.read(sha, ".gcode")


@pytest.mark.asyncio
@pytest.mark.timeout(30)
@pytest.mark.parametrize("state", [JobState.READY, JobState.INTERRUPTED])
async def test_a_job_whose_file_was_swapped_after_its_checks_fails_unprinted(
        tmp_path: Path, state: JobState) -> None:
    wire: list[str] = []
    mgr = GatedManager(tmp_path, wire)
    job = add_job(mgr, "first", state)
    swapped = f"G90\nM104 S400\nG1 X1 Y{MARKS['first']} F600\n".encode()
    mgr.spool.path(job.gcode_sha or "", ".gcode").write_bytes(swapped)
    mgr.start()
    async with asyncio.timeout(10):
        if state is JobState.INTERRUPTED:
            await mgr.resume(job.id, "layer")
        done = await mgr.wait_finished(job.id)
    assert done.state is JobState.FAILED
    assert "changed after its checks" in done.reason
    assert not printed(wire, "first") and "M104 S400" not in wire
    assert mgr.alive()
    await mgr.stop()
