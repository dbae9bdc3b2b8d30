"""Where a resumed job starts, and that rebuilding its modal state leaves the event loop free."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import pytest

from hostd.events import EventBus
from hostd.jobs.manager import JobManager
from hostd.jobs.spool import Spool
from hostd.jobs.store import Job, JobStore
from hostd.printer.modal import ModalState
from hostd.printer.program import Program, parse_program
from hostd.printer.streamer import StreamSettings


def _gcode(layers: int = 4, per_layer: int = 25) -> str:
    out = ["M83", "M104 S205", "G90"]
    for k in range(layers):
        out.append(";HOSTD_LAYER " + json.dumps({"subpart": 0, "index": k}))
        out += [f"G1 X{i * 0.5 + k:.3f} Y{k * 0.2:.3f} Z{0.2 * (k + 1):.3f} E0.0{i % 7 + 1}"
                for i in range(per_layer)]
    return "\n".join(out) + "\n"


class _Recording(Program):
    """A program that notes the thread its modal state is rebuilt on."""

    threads: list[int]

    def modal_before(self, index: int) -> ModalState:
        self.threads.append(threading.get_ident())
        return super().modal_before(index)


@pytest.mark.asyncio
@pytest.mark.timeout(30)
async def test_resume_from_a_layer_rebuilds_the_modal_state_off_the_loop(tmp_path: Path):
    program = parse_program(_gcode())
    recording = _Recording()
    recording.__dict__.update(program.__dict__)
    recording.threads = []
    store = JobStore(tmp_path / "jobs.db")
    manager = JobManager(store, Spool(tmp_path / "spool", 1 << 20), None, lambda: None,
                         EventBus(), StreamSettings())
    job = store.add("part.gcode", "gcode", "0" * 64)
    store.update(job.id, acked_lines=60)
    start, modal, prelude = await manager._resume_point(store.get(job.id), recording, "layer")
    assert start == program.resume_index(60, "layer")
    assert modal.snapshot() == program.modal_before(start).snapshot()
    assert recording.threads and threading.get_ident() not in recording.threads
    assert prelude[0] == "G28" and f"G0 Z{modal.position['Z']:.4f} F600" in prelude


PLAIN = "M140 S60\nM104 S210\nM190 S60\nM109 S210\nG90\nM83\nG28\n" + "".join(
    f"G1 X{10 + i} Y20 Z{0.2 * (1 + i // 10):.1f} E0.5 F1200\n" for i in range(40))
"""A file from another slicer: no ;HOSTD_LAYER markers."""


def _stopped_at(tmp_path: Path, acked: int) -> tuple[JobManager, Job]:
    """A manager and a job of its store interrupted after ``acked`` lines."""
    store = JobStore(tmp_path / "jobs.db")
    manager = JobManager(store, Spool(tmp_path / "spool", 1 << 20), None, lambda: None,
                         EventBus(), StreamSettings())
    job = store.add("other.gcode", "gcode", "0" * 64)
    store.update(job.id, acked_lines=acked)
    return manager, store.get(job.id)


@pytest.mark.asyncio
@pytest.mark.timeout(30)
async def test_a_file_without_layer_markers_resumes_from_its_last_acknowledged_line(
        tmp_path: Path):
    program = parse_program(PLAIN)
    manager, job = _stopped_at(tmp_path, 30)
    start, modal, prelude = await manager._resume_point(job, program, "layer")
    assert start == 30  # not 0: the first moves are not printed again on the part
    assert modal.snapshot() == program.modal_before(30).snapshot()
    assert (modal.hotend, modal.bed, modal.e_absolute) == (210, 60, False)
    p = modal.position
    assert prelude[:5] == ["G28", "M140 S60", "M104 S210", "M190 S60", "M109 S210"]
    safe, over, down = (next(i for i, c in enumerate(prelude) if c.startswith(text))
                        for text in ("G0 Z", f"G0 X{p['X']:.4f} Y{p['Y']:.4f}",
                                     f"G0 Z{p['Z']:.4f}"))
    assert safe < over < down  # up to the safe Z, over the point, down onto it
    assert "M83" in prelude[down:]


@pytest.mark.asyncio
@pytest.mark.timeout(30)
@pytest.mark.parametrize("scope", ["subpart", "checkpoint"])
async def test_a_subpart_or_checkpoint_resume_of_a_file_without_markers_is_refused(
        tmp_path: Path, scope: str):
    from hostd.jobs.resume import ResumeRefused

    manager, job = _stopped_at(tmp_path, 30)
    with pytest.raises(ResumeRefused, match=rf"cannot resume from its {scope}: its file has "
                                            r"no ;HOSTD_LAYER markers.* line 30"):
        await manager._resume_point(job, parse_program(PLAIN), scope)
