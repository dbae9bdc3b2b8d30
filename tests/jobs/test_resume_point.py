"""Where a resumed job starts, and that rebuilding its modal state leaves the event loop free."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import pytest

from hostd.events import EventBus
from hostd.jobs.manager import JobManager
from hostd.jobs.spool import Spool
from hostd.jobs.store import JobStore
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
