"""Whole-file checks of uploads and sliced G-code, in a worker process of their own.

Every file the daemon queues (an upload, or the slicer's output for an STL job) is checked
whole before the job is accepted: that is how a bad file is refused at submission, and where a
G-code job's line count and estimate come from. An STL is read by the slicer's own reader, so
a corrupt one is refused at submission, naming the line at fault, not when its slice starts.
Parsing G-code is pure Python, about a second for 400 000 lines on a slow machine; trimesh
reads an ASCII STL at the 64 MB upload limit in 1.6 s here. On a thread it would share the GIL
with the event loop, and every wake-up of the serial stream of the job printing meanwhile
would wait for it. So the checks run in a spawned worker (apart from the slicer's, so a check
never queues behind a slice); it reads the file itself, and only a small
:class:`GcodeSummary` comes back.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hostd.jobs.spool import MESH_KINDS, SpoolError, check_gcode
from hostd.printer.envelope import Envelope
from hostd.printer.errors import ProgramError
from hostd.printer.program import Program, parse_program
from hostd.worker_process import WorkerDied, WorkerProcess


@dataclass(frozen=True)
class GcodeSummary:
    """What a job record keeps of its G-code: commands, the slicer's estimate, structure."""

    total: int
    estimate: dict[str, Any]
    subparts: int
    layers: int
    transitions: int


def parse_upload(data: bytes, name: str) -> Program:
    """The program of a G-code file; :class:`SpoolError` naming ``name`` when it is not one."""
    text = check_gcode(data, name)
    try:
        program = parse_program(text)
    except ProgramError as exc:
        raise SpoolError(f"{name}: {exc}") from None
    if program.total == 0:
        raise SpoolError(f"{name}: G-code has no commands")
    return program


@dataclass(frozen=True)
class MeshSummary:
    """What the check of a part to slice found: its format (by content), and where its
    binary STL was written when it came in another (``None``: the upload is the STL)."""

    format: str
    converted: str | None = None


def check_mesh(data: bytes, name: str, kind: str | None = None,
               convert_to: str | None = None) -> MeshSummary:
    """A part upload (STL, 3MF, OBJ) read as its slice will read it
    (:func:`slicer.mesh.read.parse_mesh`): what would stop the slice there (a corrupt,
    truncated or non-finite file, a format hostd does not read) is refused now, in the
    slicer's one line, naming the first bad line of an ASCII STL. A 3MF or OBJ is written as
    binary STL to ``convert_to``, the file the job slices. Repair and placement are left to
    the slice. Imported here, in the worker: the daemon itself never loads trimesh."""
    from slicer.mesh import MeshError, parse_mesh, stl_bytes

    try:
        mesh, fmt = parse_mesh(data, name, kind)
    except MeshError as exc:
        raise SpoolError(str(exc)) from None
    if fmt == "stl" or convert_to is None:
        return MeshSummary(fmt)
    Path(convert_to).write_bytes(stl_bytes(mesh))
    return MeshSummary(fmt, convert_to)


def check_stl(data: bytes, name: str) -> None:
    """An STL upload checked as :func:`check_mesh` checks any part."""
    check_mesh(data, name, "stl")


def check_file(path: str, kind: str, name: str, envelope: Envelope | None = None
               ) -> GcodeSummary | MeshSummary:
    """Runs in the worker: check the file at ``path`` as ``kind`` (a part, ``stl``, ``3mf``
    or ``obj``: read as the slicer reads it, :func:`check_mesh`, and converted next to
    ``path`` when it is no STL; ``gcode``: parsed whole, fitted to the printer's
    ``envelope``, and summarized)."""
    data = Path(path).read_bytes()
    if kind in MESH_KINDS:
        return check_mesh(data, name, kind, f"{path}.stl.tmp")
    program = parse_upload(data, name)
    if envelope is not None:
        try:
            envelope.check(program)
        except ProgramError as exc:
            raise SpoolError(f"{name}: {exc}") from None
    return GcodeSummary(program.total, program.estimate, len(program.subparts),
                        len(program.layers), len(program.transitions))


class FileChecker:
    """Checks files in a worker process, started by the first check."""

    def __init__(self, envelope: Envelope | None = None) -> None:
        self.envelope = envelope
        self.process = WorkerProcess()
        self.checks = 0
        self.refused = 0

    async def check(self, path: Path, kind: str, name: str) -> GcodeSummary | MeshSummary:
        """:func:`check_file` in the worker; :class:`SpoolError` naming ``name`` when the file
        is refused or the worker died (it is started afresh for the next check)."""
        self.checks += 1
        try:
            return await self.process.run(check_file, str(path), kind, name, self.envelope)
        except WorkerDied as exc:
            self.refused += 1
            raise SpoolError(f"{name}: not checked: {exc}") from None
        except SpoolError:
            self.refused += 1
            raise

    async def summarize(self, path: Path, name: str) -> GcodeSummary:
        """The summary of the G-code file at ``path`` (see :meth:`check`)."""
        summary = await self.check(path, "gcode", name)
        assert isinstance(summary, GcodeSummary)
        return summary

    def close(self) -> None:
        self.process.close()

    def status(self) -> dict[str, Any]:
        return {"checks": self.checks, "refused": self.refused,
                "worker_started": self.process.started}
