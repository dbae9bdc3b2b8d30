"""A job's name shows as it is (issue 38, item 8): a name holding a bidirectional override
or another control or formatting character, which would change how ``hostctl jobs`` shows
it, is refused at submission."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from hostd.events import EventBus
from hostd.jobs.manager import JobManager
from hostd.jobs.spool import Spool, SpoolError
from hostd.jobs.store import JobStore
from hostd.printer.streamer import StreamSettings


def manager(tmp_path: Path) -> JobManager:
    return JobManager(JobStore(tmp_path / "jobs.db"), Spool(tmp_path / "spool", 1 << 20),
                      None, lambda: None, EventBus(), StreamSettings())


@pytest.mark.asyncio
@pytest.mark.timeout(30)
@pytest.mark.parametrize(("name", "code"), [
    ("invoice\u202egcode.stl", "U+202E"),  # shows as "invoicelts.edocg"
    ("part\u2066x\u2069.gcode", "U+2066"), ("a\u200fb.gcode", "U+200F"),
    ("two\nlines.gcode", "U+000A"), ("bell\x07.gcode", "U+0007"),
])
async def test_a_name_that_would_show_as_something_else_is_refused(
        tmp_path: Path, name: str, code: str) -> None:
    mgr = manager(tmp_path)
    with pytest.raises(SpoolError, match=rf"job name '.*' holds {re.escape(code)} \(.*\): "
                                         r".*rename the file"):
        await mgr.submit(name, b"G28\nG1 X1\n", "gcode")
    assert mgr.store.count() == 0
    assert list((tmp_path / "spool").iterdir()) == []  # nothing kept of it


@pytest.mark.asyncio
@pytest.mark.timeout(30)
async def test_names_in_any_script_pass(tmp_path: Path) -> None:
    mgr = manager(tmp_path)
    for name in ("pièce.gcode", "קובץ.gcode", "部品 2.gcode", "ملف.gcode"):
        assert (await mgr.submit(name, b"G28\n", "gcode")).name == name
