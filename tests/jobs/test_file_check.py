"""File checks run in a worker process: the same summary as a parse here, the same refusals,
and a worker that dies is replaced."""

from __future__ import annotations

import asyncio
import os
import signal
import struct
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "daemon"))
from hostd_harness import make_gcode

from hostd.jobs import file_check
from hostd.jobs.file_check import FileChecker, GcodeSummary, parse_upload
from hostd.jobs.spool import SpoolError


def local_summary(data: bytes, name: str) -> GcodeSummary:
    program = parse_upload(data, name)
    return GcodeSummary(program.total, program.estimate, len(program.subparts),
                        len(program.layers), len(program.transitions))


def written(tmp_path: Path, name: str, data: bytes) -> Path:
    path = tmp_path / name
    path.write_bytes(data)
    return path


def binary_stl(triangles: int, extra: bytes = b"") -> bytes:
    return b"\0" * 80 + struct.pack("<I", triangles) + b"\0" * 50 * triangles + extra


def nan_stl(triangles: int, bad: int) -> bytes:
    """A binary STL whose triangle ``bad`` has a NaN coordinate (its second corner's y)."""
    rows = []
    for i in range(triangles):
        corners = [0.0, 0.0, float(i), 1.0, 0.0, float(i), 0.0, 1.0, float(i)]
        if i == bad:
            corners[4] = float("nan")
        rows.append(struct.pack("<12fH", 0.0, 0.0, 1.0, *corners, 0))
    return b"\0" * 80 + struct.pack("<I", triangles) + b"".join(rows)


def ascii_stl(second: str = "vertex 1 0 0", third: str = "vertex 0 1 0") -> bytes:
    """An ASCII STL of one triangle whose second and third corners (lines 5 and 6) are
    ``second`` and ``third``."""
    return (f"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\n{second}\n{third}\n"
            "endloop\nendfacet\nendsolid x\n").encode()


@pytest.mark.asyncio
@pytest.mark.timeout(120)
async def test_the_worker_summarizes_as_a_parse_here_would(tmp_path: Path,
                                                           monkeypatch: pytest.MonkeyPatch):
    files = [make_gcode(s, layers, per_layer).encode()
             for s, layers, per_layer in ((1, 1, 1), (3, 4, 25), (4, 2, 7))]
    expected = [local_summary(data, "part.gcode") for data in files]

    def not_here(data: bytes, name: str) -> None:
        raise AssertionError("parsed in the daemon's process")

    monkeypatch.setattr(file_check, "parse_upload", not_here)  # the spawned worker has its own
    checker = FileChecker()
    try:
        got = [await checker.summarize(written(tmp_path, f"{i}.gcode", data), "part.gcode")
               for i, data in enumerate(files)]
        stl = await checker.check(written(tmp_path, "a.stl", binary_stl(3)), "stl", "a.stl")
        assert checker.status() == {"checks": 4, "refused": 0, "worker_started": True}
    finally:
        checker.close()
    assert got == expected
    assert [g.subparts for g in got] == [1, 3, 4] and got[1].transitions == 2
    assert stl == file_check.MeshSummary("stl")


@pytest.mark.asyncio
@pytest.mark.timeout(120)
@pytest.mark.parametrize(("kind", "data", "message"), [
    ("gcode", b"\xff\xfe\x00binary", "not UTF-8"),
    ("gcode", b"G1 X1\n\0G1 X2\n", "NUL"),
    ("gcode", b"; only a comment\n\n", "no commands"),
    ("stl", binary_stl(2)[:-7], r"truncated binary STL: header declares 2 triangles \(184 "
     r"bytes\) but the file has 177 bytes"),
    ("stl", b"solid x\nfacet normal 0 0 1\n", "truncated ASCII STL: no endsolid after line 2: "
     "'facet normal 0 0 1'"),
    ("stl", nan_stl(3, 2), r"1 triangle corners have NaN or infinite coordinates \(the "
     r"first in triangle 2\)"),
    ("stl", ascii_stl("vertex 1 0 NaN"), r"1 triangle corners have NaN or infinite "
     r"coordinates \(the first at line 5: 'vertex 1 0 NaN'\)"),
    ("stl", ascii_stl("vertex 1 0 0", "vertex 0 1 -inf"), r"\(the first at line 6: "
     "'vertex 0 1 -inf'"),
    ("stl", ascii_stl("vertex 1e999 0 0"), "NaN or infinite coordinates \\(the first at line 5"),
    ("stl", ascii_stl("vertex 1 0 x0"), r"not a readable STL file \(line 5: 'vertex 1 0 x0'\)"),
    ("stl", ascii_stl("vertex 1 0"), r"not a readable STL file \(line 5: 'vertex 1 0'\)"),
    ("stl", ascii_stl().split(b"endloop")[0], "truncated ASCII STL: no endsolid after line 6: "
     "'vertex 0 1 0'"),
    ("stl", ascii_stl() + b"solid y\nfacet normal 0 0 1\n", "truncated ASCII STL: no endsolid "
     "after line 11: 'facet normal 0 0 1'"),
])
async def test_a_bad_file_is_refused_naming_it(tmp_path: Path, kind: str, data: bytes,
                                               message: str):
    checker = FileChecker()
    try:
        with pytest.raises(SpoolError, match=f"bad.{kind}: .*{message}"):
            await checker.check(written(tmp_path, "f", data), kind, f"bad.{kind}")
        ok = await checker.summarize(written(tmp_path, "g", b"G28\nG1 X1 Y1\n"), "good.gcode")
    finally:
        checker.close()
    assert ok.total == 2  # the worker carries on
    assert checker.status()["refused"] == 1


@pytest.mark.asyncio
@pytest.mark.timeout(120)
async def test_a_worker_that_dies_fails_its_check_and_is_replaced(tmp_path: Path):
    checker = FileChecker()
    try:
        await checker.summarize(written(tmp_path, "w", b"G28\n"), "warm.gcode")  # it is up
        pool = checker.process._pool
        assert pool is not None
        pids = list(pool._processes)  # (the executor's own record of its workers)
        big = written(tmp_path, "big", make_gcode(3, 40, 2000).encode())
        check = asyncio.create_task(checker.summarize(big, "big.gcode"))
        await asyncio.sleep(0)  # the call is on its way to the worker
        for pid in pids:
            os.kill(pid, signal.SIGKILL)
        with pytest.raises(SpoolError, match=r"big\.gcode: not checked: the worker process died"):
            await check
        again = await checker.summarize(written(tmp_path, "n", b"G28\nG1 X1\n"), "next.gcode")
    finally:
        checker.close()
    assert again.total == 2
    assert checker.status()["refused"] == 1


@pytest.mark.parametrize("file_type", ["stl", "stl_ascii"])
def test_the_upload_check_and_the_slicer_both_take_overlapping_shells(tmp_path: Path,
                                                                      file_type: str):
    """Solids concatenated without a union: the upload-time check does not refuse them before
    the slicer sees them, and the slicer takes them (as their union)."""
    import trimesh

    from slicer.mesh.read import load_mesh

    cube = trimesh.creation.box([20.0, 20.0, 20.0])
    post = trimesh.creation.box([10.0, 10.0, 30.0])
    post.apply_translation([5.0, 0.0, 5.0])
    path = tmp_path / "overlap.stl"
    trimesh.util.concatenate([cube, post]).export(path, file_type=file_type)
    assert file_check.check_file(str(path), "stl", "overlap.stl") == file_check.MeshSummary("stl")
    mesh, placement = load_mesh(path)
    assert placement.merged_shells == 2 and mesh.volume == pytest.approx(9000.0)


@pytest.mark.parametrize("tail", [b"\0\0padding", -7])
def test_the_upload_check_and_the_slicer_agree_on_a_binary_stl_of_another_length(
        tmp_path: Path, tail: bytes | int):
    """Bytes past the declared triangles (some exporters pad) are taken by both; a file
    shorter than its count says is refused by both."""
    import trimesh

    from slicer.mesh.errors import MeshError
    from slicer.mesh.read import load_mesh

    path = tmp_path / "box.stl"
    trimesh.creation.box([20.0, 20.0, 20.0]).export(path, file_type="stl")
    data = path.read_bytes()
    path.write_bytes(data + tail if isinstance(tail, bytes) else data[:tail])
    if isinstance(tail, bytes):
        assert file_check.check_file(str(path), "stl", "box.stl") == file_check.MeshSummary("stl")
        assert load_mesh(path)[0].volume == pytest.approx(8000.0)
    else:
        with pytest.raises(SpoolError, match=r"box\.stl: truncated binary STL"):
            file_check.check_file(str(path), "stl", "box.stl")
        with pytest.raises(MeshError, match="truncated binary STL"):
            load_mesh(path)


@pytest.mark.parametrize("data", [
    ascii_stl("vertex 1 0 x0"), ascii_stl("vertex 1 0"), ascii_stl("vertex 1 0 NaN"),
    ascii_stl().split(b"endloop")[0], ascii_stl() + b"solid y\nfacet normal 0 0 1\n",
    ascii_stl("vertex 1 0 0", "vertex 0 1 0\nvertex 0 0 1"),
])
def test_the_upload_check_refuses_a_corrupt_ascii_stl_as_the_slicer_does(tmp_path: Path,
                                                                          data: bytes):
    """The upload check is the slicer's reader: the same one line, naming the upload."""
    from slicer.mesh.errors import MeshError
    from slicer.mesh.read import load_mesh

    path = written(tmp_path, "part.stl", data)
    with pytest.raises(SpoolError) as upload:
        file_check.check_file(str(path), "stl", "part.stl")
    with pytest.raises(MeshError) as slicer:
        load_mesh(path)
    assert str(upload.value) == str(slicer.value).replace(str(path), "part.stl")
    assert str(upload.value).startswith("part.stl: ") and "\n" not in str(upload.value)


def test_an_ascii_stl_named_in_latin_1_is_taken_by_the_upload_check_as_by_the_slicer(
        tmp_path: Path):
    """Bytes outside ASCII in the solid's name stop neither (the slicer reads them as ``?``)."""
    import trimesh

    from slicer.mesh.read import load_mesh

    text = trimesh.creation.box([20.0, 20.0, 20.0]).export(file_type="stl_ascii")
    path = written(tmp_path, "box.stl", ("solid café\n" + text.split("\n", 1)[1])
                   .encode("latin-1"))
    assert file_check.check_file(str(path), "stl", "box.stl") == file_check.MeshSummary("stl")
    assert load_mesh(path)[0].volume == pytest.approx(8000.0)


def test_a_3mf_upload_is_checked_and_kept_as_the_binary_stl_it_slices(tmp_path: Path):
    """A part sent as 3MF (even as ``stl``: the content says) is written as binary STL next
    to the upload: the spool keeps that, and the slice reads it."""
    import trimesh
    from mesh_files import IDENTITY, three_mf

    from slicer.mesh import parse_stl

    box = trimesh.creation.box((4.0, 4.0, 4.0))
    path = written(tmp_path, ".upload-1.tmp", three_mf(box, "centimeter", [IDENTITY]))
    summary = file_check.check_file(str(path), "stl", "box.3mf")
    assert isinstance(summary, file_check.MeshSummary) and summary.format == "3mf"
    assert summary.converted == f"{path}.stl.tmp"
    mesh = parse_stl(Path(summary.converted).read_bytes(), "box")
    assert mesh.extents.tolist() == pytest.approx([40.0, 40.0, 40.0])


@pytest.mark.parametrize("kind", ["stl", "3mf", "obj"])
def test_an_unsupported_format_is_refused_as_such_whatever_it_was_sent_as(tmp_path: Path,
                                                                         kind: str):
    path = written(tmp_path, "part.bin", b"ply\nformat binary_little_endian 1.0\n")
    with pytest.raises(SpoolError) as err:
        file_check.check_file(str(path), kind, "part.ply")
    assert str(err.value) == ("part.ply: unsupported format: PLY (hostd reads STL, 3MF and "
                              "OBJ)")
