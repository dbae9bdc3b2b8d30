"""End to end from STL: upload, slice in the worker process, stream, compare with the emulator."""

from __future__ import annotations

import asyncio
import base64
import io

import pytest
from hostd_harness import executed, file_commands

from hostd.printer.program import parse_program
from slicer.mesh.samples import branched_pipe, cylinder, pipe3

pytestmark = pytest.mark.asyncio


def _stl(mesh) -> str:
    buf = io.BytesIO()
    mesh.export(buf, file_type="stl")
    return base64.b64encode(buf.getvalue()).decode()


async def _print_stl(d, name: str, mesh, budget: float):
    async with asyncio.timeout(budget):
        c = await d.rpc()
        await c.call("events.subscribe", events=["job.state"])
        job = await c.call("job.submit", name=name, data=_stl(mesh), encoding="base64")
        assert job["kind"] == "stl"
        await c.until_state(job["id"], "completed", "failed")
        got = await c.call("job.get", id=job["id"])
        log = (await c.call("sim.log"))["commands"]
        await c.close()
    sliced = list((d.tmp / "state" / "cache").glob("*.gcode"))
    assert len(sliced) == 1, sliced
    return got, executed(log), sliced[0].read_text()


def _extras_before(ran: list[str], cmds: list[str]) -> list[list[str]]:
    """What the daemon ran besides the file: ``out[i]`` came just before file command i."""
    out: list[list[str]] = [[] for _ in range(len(cmds) + 1)]
    i = 0
    for x in ran:
        if i < len(cmds) and x == cmds[i]:
            i += 1
        else:
            out[i].append(x)
    assert i == len(cmds), "the file's commands did not all run, in order"
    return out


def _assert_transactions(ran: list[str], gcode: str) -> int:
    """Every transition block ran between M400 and M400 + M114; returns their number."""
    prog = parse_program(gcode)
    extras = _extras_before(ran, prog.commands)
    for t in prog.transitions:
        assert "M400" in extras[t.start], (t, extras[t.start])
        assert extras[t.end][:2] == ["M400", "M114"], (t, extras[t.end])
    return len(prog.transitions)


async def test_stl_job_is_sliced_and_every_line_runs_once_in_order(daemon_factory):
    d = daemon_factory(process__layer_height=0.3)
    await d.start()
    got, ran, gcode = await _print_stl(d, "cyl.stl", cylinder(radius=6, height=3), 180)
    assert got["state"] == "completed", got
    assert got["acked_lines"] == got["total_lines"] == len(file_commands(gcode))
    assert [x for x in ran if x not in ("M400", "M114")] == file_commands(gcode)
    assert ";HOSTD_KINEMATICS" in gcode
    assert await d.stop() == 0


async def test_branched_stl_runs_each_transition_as_a_transaction(daemon_factory):
    d = daemon_factory(process__layer_height=0.3, process__infill_density=0.1)
    await d.start()
    part = branched_pipe(branches=((12.0, 0.0, 45.0),), height=30.0, branch_length=20.0)
    got, ran, gcode = await _print_stl(d, "branch.stl", part, 280)
    assert got["state"] == "completed", got
    assert [x for x in ran if x not in ("M400", "M114")] == file_commands(gcode)
    transitions = _assert_transactions(ran, gcode)
    assert transitions >= 2  # the approach to the root and the turn to the branch
    assert len(got["checkpoints"]) == transitions
    assert await d.stop() == 0


async def test_three_branched_sample_runs_every_transition_as_a_transaction(daemon_factory):
    d = daemon_factory(process__layer_height=0.3, process__infill_density=0.1,
                       process__perimeters=1)
    await d.start()
    got, ran, gcode = await _print_stl(d, "pipe3.stl", pipe3(), 400)
    assert got["state"] == "completed", got
    transitions = _assert_transactions(ran, gcode)
    subparts = gcode.count(";HOSTD_SUBPART ")
    assert subparts == 3 and transitions == subparts  # one turn before every sub-part
    assert [cp["subpart"] for cp in got["checkpoints"]] == list(range(subparts))
    assert await d.stop() == 0


async def test_an_stl_the_slicer_refuses_fails_naming_the_uploaded_file(daemon_factory):
    """A mesh that passes the upload's structural check but not the slicer (an open
    surface): the job fails with the slicer's one line, naming the operator's file, not the
    spool file (its content hash) it is kept under."""
    import trimesh

    d = daemon_factory()
    await d.start()
    sheet = trimesh.Trimesh([[0, 0, 0], [10, 0, 0], [0, 10, 0], [10, 10, 0]],
                            [[0, 1, 2], [1, 3, 2]])
    async with asyncio.timeout(60):
        c = await d.rpc()
        await c.call("events.subscribe", events=["job.state"])
        job = await c.call("job.submit", name="sheet.stl", data=_stl(sheet))
        await c.until_state(job["id"], "failed")
        got = await c.call("job.get", id=job["id"])
        await c.close()
    assert got["reason"].startswith("slicing failed: sheet.stl: "), got["reason"]
    assert job["upload_sha"] not in got["reason"] and "spool" not in got["reason"]
    assert "\n" not in got["reason"]
    assert await d.stop() == 0


@pytest.mark.parametrize("how", ["cancel", "delete"])
async def test_cancelling_a_job_while_it_slices_stops_the_slice(daemon_factory, how: str):
    """The worker is ended, not left to finish a slice nobody wants: the next STL job is
    sliced by a fresh worker, and the cancelled one leaves nothing in the cache. Deleting
    the job does the same (it used to leave the slice running on a removed STL, to fail
    with an internal error)."""
    d = daemon_factory()
    await d.start()
    async with asyncio.timeout(300):
        c = await d.rpc()
        await c.call("events.subscribe", events=["job.state"])
        slow = await c.call("job.submit", name="pipe3.stl", data=_stl(pipe3()))
        await c.until_state(slow["id"], "slicing")
        gone = await c.call(f"job.{how}", id=slow["id"])
        if how == "delete":
            assert gone == {"deleted": slow["id"]}
        else:
            assert gone["state"] == "cancelled"
        small = await c.call("job.submit", name="cyl.stl",
                             data=_stl(cylinder(radius=6, height=3)))
        await c.until_state(small["id"], "completed", "failed")
        got = await c.call("job.get", id=small["id"])
        slicer = (await c.call("printer.status"))["slicer"]
        await c.close()
    assert got["state"] == "completed", got["reason"]
    assert slicer["cancelled"] == 1 and slicer["failures"] == 0
    cache = sorted(p.name for p in (d.tmp / "state" / "cache").iterdir())
    # the small job's G-code, its info and its pictures; nothing of the cancelled slice
    assert all(small["upload_sha"] in n for n in cache), cache
    assert {n.split(".", 1)[1] for n in cache} >= {"gcode", "json"}, cache
    assert await d.stop() == 0
    assert d.loop_errors() == []


async def test_overlapping_shells_pass_the_upload_check_and_are_sliced_as_one(daemon_factory):
    """Two solids concatenated without a union (as CAD exports write them): the upload is
    taken, the slicer merges them, and the job's reason and record say so."""
    import trimesh

    d = daemon_factory(process__layer_height=0.3)
    await d.start()
    cube = trimesh.creation.box([8.0, 8.0, 3.0])
    post = trimesh.creation.box([4.0, 4.0, 5.0])
    post.apply_translation([2.0, 0.0, 1.0])  # through the cube's +x half, 2 mm above it
    async with asyncio.timeout(240):
        c = await d.rpc()
        await c.call("events.subscribe", events=["job.state"])
        job = await c.call("job.submit", name="overlap.stl",
                           data=_stl(trimesh.util.concatenate([cube, post])), encoding="base64")
        ready = await c.until_state(job["id"], "ready", "failed")
        assert ready["reason"] == ("sliced; merged 2 overlapping shells of the file into one "
                                   "solid"), ready
        await c.until_state(job["id"], "completed", "failed")
        got = await c.call("job.get", id=job["id"])
        await c.close()
    assert got["state"] == "completed", got
    assert got["info"]["merged_shells"] == 2
    assert await d.stop() == 0
