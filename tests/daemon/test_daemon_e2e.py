"""End to end: hostd as a subprocess on the built-in emulator, driven over the control socket."""

from __future__ import annotations

import asyncio
import base64
import hashlib
import os
import signal
import stat

import pytest
from hostd_harness import RpcCallError, executed, file_commands, make_gcode

pytestmark = pytest.mark.asyncio


async def test_gcode_job_completes_every_line_once_in_order(daemon_factory):
    d = daemon_factory()
    await d.start()
    assert stat.S_IMODE(os.stat(d.socket).st_mode) == 0o660
    text = make_gcode(subparts=3, layers=2, per_layer=30)
    async with asyncio.timeout(60):
        c = await d.rpc()
        await c.call("events.subscribe")
        job = await c.submit_text("pipe3.gcode", text)
        assert job["state"] == "ready" and job["total_lines"] == len(file_commands(text))
        await c.until_state(job["id"], "completed", "failed")
        got = await c.call("job.get", id=job["id"])
        assert got["state"] == "completed" and got["acked_lines"] == got["total_lines"]
        assert [cp["subpart"] for cp in got["checkpoints"]] == [1, 2]
        assert [(cp["a"], cp["c"]) for cp in got["checkpoints"]] == [(30.0, 120.0),
                                                                     (60.0, 240.0)]
        log = (await c.call("sim.log"))["commands"]
        ran = [cmd for cmd in executed(log) if cmd not in ("M400", "M114")]
        assert ran == file_commands(text)
        # each transition ran as a transaction: M400 before, M400 + M114 after the block
        cmds = executed(log)
        for a, cc in (("30", "120"), ("60", "240")):
            i = cmds.index(f"G0 A{a} C{cc} F3000")
            assert cmds[i - 2:i] == ["M400", "G0 Z80 F3000"]
            assert cmds[i + 2:i + 4] == ["M400", "M114"]
        status = await c.call("printer.status")
        assert status["jobs"]["finished"]["completed"] == 1
        assert status["jobs"]["transitions"] == {"total": 2, "failed": 0}
        await c.close()
    assert await d.stop() == 0
    assert not d.socket.exists() and d.loop_errors() == []
    states = [ln.split(": ", 1)[1].strip() for ln in d.stderr if "hostd.jobs.manager: job" in ln]
    steps = ["new -> queued", "queued -> ready", "ready -> printing", "printing -> completed"]
    assert [s.split(" (")[0] for s in states] == [
        f"job {job['id']} 'pipe3.gcode': {step}" for step in steps]


async def test_pause_resume_then_cancel_mid_print(daemon_factory):
    d = daemon_factory()
    await d.start()
    text = make_gcode(subparts=1, layers=20, per_layer=200)
    async with asyncio.timeout(90):
        c = await d.rpc()
        job = await c.printing(text)
        paused = await c.call("job.pause", id=job["id"])
        assert paused["state"] == "paused"
        n = paused["acked_lines"]
        assert 0 < n < paused["total_lines"]
        got = await c.call("job.get", id=job["id"])
        assert got["modal"]["absolute"] is True and got["modal"]["e_absolute"] is False
        assert got["modal"]["hotend"] == 210.0
        # raw G-code is accepted while paused, refused (except the safe set) while printing
        jog = await c.call("printer.gcode", script="G91\nG1 Z2 F600\nG90")  # none is safe
        assert jog["commands"] == ["G91", "G1 Z2 F600", "G90"]  # while printing
        await c.call("job.resume", id=job["id"])
        await c.until(lambda e: e["event"] == "job.progress" and e["acked"] > n + 100)
        with pytest.raises(RpcCallError) as err:
            await c.call("printer.gcode", script="G28")
        assert err.value.code == -32004 and "refused while printing" in err.value.message
        assert (await c.call("printer.gcode", script="M105"))["commands"] == ["M105"]
        with pytest.raises(RpcCallError) as err:  # would stall the firmware's checksum
            await c.call("printer.gcode", script="M117 " + "x" * 120)
        assert err.value.code == -32602 and "line buffer" in err.value.message
        cancelled = await c.call("job.cancel", id=job["id"])
        assert cancelled["state"] == "cancelled"
        cmds = executed((await c.call("sim.log"))["commands"])
        assert cmds[-6:] == ["M104 S0", "M140 S0", "M107", cmds[-3], "G0 A0 C0 F3000", "M84"]
        # pause: retract and lift along Z, no rotation
        k = cmds.index("G1 E-1.0000 F2100")
        assert cmds[k + 1:k + 3] == ["G90", cmds[k + 2]] and cmds[k + 2].startswith("G1 Z")
        assert not any(x.startswith("G0 A") for x in cmds[k - 2:k + 4])
        await c.close()
    await d.stop()


async def test_a_turn_and_a_cooled_hotend_during_a_pause_are_put_back_on_resume(
        daemon_factory):
    """The QA turned the platform and switched the hotend off while a job was paused; the
    resume went on printing at the wrong tilt with the hotend cooling. Now the resume heats
    the hotend back, turns the platform back from the safe Z and lowers onto the point."""
    d = daemon_factory()
    await d.start()
    text = make_gcode(subparts=1, layers=20, per_layer=200)
    async with asyncio.timeout(90):
        c = await d.rpc()
        job = await c.printing(text)
        paused = await c.call("job.pause", id=job["id"])
        await c.call("printer.gcode", script="G0 A30 C45\nM104 S0")
        await c.call("job.resume", id=job["id"])
        await c.until(lambda e: e["event"] == "job.progress"
                      and e["acked"] > paused["acked_lines"] + 50)
        position = (await c.call("printer.gcode", script="M114"))["replies"][0]["position"]
        temps = (await c.call("printer.gcode", script="M105"))["replies"][0]["temperatures"]
        await c.call("job.cancel", id=job["id"])
        cmds = executed((await c.call("sim.log"))["commands"])
        await c.close()
    await d.stop()
    assert (position["A"], position["C"]) == (0.0, 0.0), position
    assert temps["T"]["target"] == 210.0, temps
    turned = cmds.index("G0 A30 C45")
    back = next(i for i, x in enumerate(cmds) if i > turned and x.startswith("G0 A0.0000"))
    assert "M109 S210" in cmds[turned:back]  # hot again before the nozzle goes down


async def test_two_jobs_run_in_submission_order(daemon_factory):
    d = daemon_factory()
    await d.start()
    a = make_gcode(subparts=1, layers=2, per_layer=50).replace("X1", "X3")
    b = make_gcode(subparts=1, layers=2, per_layer=50)
    async with asyncio.timeout(60):
        c = await d.rpc()
        await c.call("events.subscribe", events=["job.state"])
        ja = await c.submit_text("a.gcode", a)
        jb = await c.submit_text("b.gcode", b)
        order = []
        while len(order) < 2:
            ev = await c.until(lambda e: e["new"] == "completed")
            order.append(ev["job_id"])
        assert order == [ja["id"], jb["id"]]
        ga, gb = [await c.call("job.get", id=j["id"]) for j in (ja, jb)]
        assert ga["finished_at"] <= gb["started_at"]
        ran = [x for x in executed((await c.call("sim.log"))["commands"])
               if x not in ("M400", "M114")]
        assert ran == file_commands(a) + file_commands(b)
        await c.close()
    await d.stop()


async def test_bad_uploads_rejected_while_a_print_continues(daemon_factory):
    d = daemon_factory(daemon__max_upload_bytes=200_000)
    await d.start()
    text = make_gcode(subparts=1, layers=10, per_layer=200)
    async with asyncio.timeout(60):
        c = await d.rpc()
        await c.call("events.subscribe", events=["job.state", "job.progress"])
        job = await c.submit_text("long.gcode", text)
        await c.until(lambda e: e["event"] == "job.progress" and e["progress"] > 0.05)
        bad = {
            "corrupt.stl": (os.urandom(1000), "corrupt.stl: truncated binary STL"),
            "number.stl": (b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\n"
                           b"vertex 1 0 x0\nvertex 0 1 0\nendloop\nendfacet\nendsolid x\n",
                           "number.stl: not a readable STL file (line 5: 'vertex 1 0 x0')"),
            "cut.stl": (b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\n",
                        "cut.stl: truncated ASCII STL: no endsolid after line 4: "
                        "'vertex 0 0 0'"),
            "nan.stl": (b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\n"
                        b"vertex 1 0 0\nvertex nan 1 0\nendloop\nendfacet\nendsolid x\n",
                        "nan.stl: 1 triangle corners have NaN or infinite coordinates (the "
                        "first at line 6: 'vertex nan 1 0')"),
            "empty.stl": (b"", "empty.stl: empty upload"),
            "big.gcode": (b"G1 X1\n" * 40_000, "exceeds the limit"),
            "binary.gcode": (b"\xff\xfe\x00G1", "not UTF-8"),
            "part.ply": (b"ply\n", "cannot tell the kind"),
            "part.obj": (b"v 1 2 3", "part.obj: no triangles in the OBJ file"),
            "far.gcode": (b"G28\nG90\nG1 X10 Y10\nG1 X900\n",
                          "far.gcode: line 4: X 900 is outside the machine's travel [0, 500]"
                          " (machine.x_range)"),
            "other.gcode": (b';HOSTD_KINEMATICS {"table_origin": [250, 250, 120]}\nG28\n',
                            "sliced for another machine: table_origin [250, 250, 120] in the"
                            " file's HOSTD_KINEMATICS, [250, 250, 100] in this printer's"),
        }
        for name, (data, reason) in bad.items():
            with pytest.raises(RpcCallError) as err:
                await c.call("job.submit", name=name, data=base64.b64encode(data).decode())
            assert err.value.code == -32003 and reason in err.value.message, name
        with pytest.raises(RpcCallError) as err:
            await c.call("job.submit", name="x.gcode", data="***")
        assert err.value.code == -32602
        for script, message in (("M117 a\x07b", "line 1: control character '\\x07'"),
                                ("M105\nM104 Snan", "line 2: SNAN is not a finite number"),
                                ("M105\x00", "control character '\\x00'"),
                                ("M105\nM104 S9999", "line 2: M104 S9999 is above the "
                                 "hotend's limit 285 °C (machine.max_hotend_temp)"),
                                ("G90\nG1 X9999", "line 2: X 9999 is outside the machine's "
                                 "travel"),
                                ("G1 A200", "line 1: A 200 is outside the machine's travel")):
            with pytest.raises(RpcCallError) as err:  # raw lines: never onto the wire
                await c.call("printer.gcode", script=script)
            assert err.value.code == -32602 and message in err.value.message
        with pytest.raises(RpcCallError) as err:
            await c.call("job.get", id=10**30)
        assert err.value.code == -32602 and "out of range" in err.value.message
        with pytest.raises(RpcCallError) as err:
            await c.call("job.list", states=["printing", "bogus"])
        assert err.value.code == -32602 and "unknown job state 'bogus'" in err.value.message
        for params, message in (({"name": "a\ud800.gcode", "data": "RzI4Cg=="}, "name: not"),
                                ({"name": "a.gcode", "data": "G28 ;\udfff\n", "encoding": "text"},
                                 "data: not Unicode text")):
            with pytest.raises(RpcCallError) as err:  # lone surrogates, which JSON can carry
                await c.call("job.submit", **params)
            assert err.value.code == -32602 and message in err.value.message
        await c.until_state(job["id"], "completed")
        jobs = (await c.call("job.list"))["jobs"]
        assert [j["id"] for j in jobs] == [job["id"]]
        await c.close()
    await d.stop()


async def test_a_file_sent_in_parts_is_the_job_sent_whole(daemon_factory):
    d = daemon_factory(daemon__max_upload_bytes=200_000)
    await d.start()
    text = make_gcode(subparts=2, layers=3, per_layer=80)
    data = text.encode()
    parts = [data[i:i + 1000] for i in range(0, len(data), 1000)]
    b64 = [base64.b64encode(part).decode() for part in parts]
    staging = d.tmp / "state" / "spool"
    async with asyncio.timeout(60):
        c = await d.rpc()
        await c.call("events.subscribe", events=["job.state"])
        offset = 0
        for part, encoded in zip(parts, b64, strict=True):
            assert (await c.call("job.upload", data=encoded, offset=offset)) == {
                "bytes": offset + len(part)}
            offset += len(part)
        job = await c.call("job.submit", name="parts.gcode")
        assert job["upload_sha"] == hashlib.sha256(data).hexdigest()
        assert job["total_lines"] == len(file_commands(text))
        await c.until_state(job["id"], "completed")
        ran = [x for x in executed((await c.call("sim.log"))["commands"])
               if x not in ("M400", "M114")]
        assert ran == file_commands(text)
        # a part out of place, over the limit or not base64 drops the upload, with an error
        refusals = [
            ([(b64[0], 0), (b64[1], 999)], -32602, "offset 999: 1000 bytes received"),
            ([(b64[1], 1000)], -32602, "offset 1000: no upload in progress"),
            ([(b64[0], 0), (base64.b64encode(b"G1 X1\n" * 40_000).decode(), 1000)],
             -32003, "exceeds the limit of 200000 bytes"),
            ([(b64[0], 0), ("QQ==QQ==", 1000)], -32602, "invalid base64"),
        ]
        for sent, code, message in refusals:
            *good, (last, at) = sent
            for encoded, offset in good:
                await c.call("job.upload", data=encoded, offset=offset)
            with pytest.raises(RpcCallError) as err:
                await c.call("job.upload", data=last, offset=at)
            assert err.value.code == code and message in err.value.message, message
            with pytest.raises(RpcCallError) as err:
                await c.call("job.submit", name="parts.gcode")
            assert err.value.code == -32602 and "no upload in parts" in err.value.message
        assert not list(staging.glob(".*.tmp"))  # nothing staged is left behind
        assert [j["id"] for j in (await c.call("job.list"))["jobs"]] == [job["id"]]
        # a client that leaves before it submits leaves nothing either
        gone = await d.rpc()
        await gone.call("job.upload", data=b64[0], offset=0)
        assert len(list(staging.glob(".*.tmp"))) == 1
        await gone.close()
        while (await c.call("printer.status"))["control"]["clients"] > 1:
            pass  # (its connection's end is noticed by the daemon's read loop, not here)
        assert not list(staging.glob(".*.tmp"))
        await c.close()
    await d.stop()


async def test_fifty_subscribers_all_see_the_job_complete(daemon_factory):
    d = daemon_factory()
    await d.start()
    async with asyncio.timeout(60):
        clients = [await d.rpc() for _ in range(50)]
        for c in clients:
            await c.call("events.subscribe")
        status = await clients[0].call("printer.status")
        assert status["control"]["subscribed"] == 50
        job = await clients[0].submit_text("j.gcode", make_gcode(1, 3, 100))
        for c in clients:
            await c.until_state(job["id"], "completed")
        for c in clients:
            await c.close()
    await d.stop()


async def test_sigkill_mid_print_then_resume_from_checkpoint(daemon_factory):
    d = daemon_factory()
    await d.start()
    text = make_gcode(subparts=3, layers=8, per_layer=150)
    cmds = file_commands(text)
    async with asyncio.timeout(90):
        c = await d.rpc()
        await c.call("events.subscribe")
        job = await c.submit_text("pipe3.gcode", text)
        await c.until(lambda e: e["event"] == "subpart_started" and e["subpart"] == 1)
        await c.until(lambda e: e["event"] == "job.progress" and e["subpart"] == 1
                      and e["layer"] >= 2)
        # through the Process, not os.kill: a later send_signal would poll, and so reap, the
        # dead daemon before asyncio's watcher thread, which then reports 255 (bpo-38630)
        assert await d.stop(signal.SIGKILL) == -signal.SIGKILL
        await c.close()

        await d.start()
        c = await d.rpc()
        got = await c.call("job.get", id=job["id"])
        assert got["state"] == "interrupted"
        assert got["acked_lines"] > 0 and f"line {got['acked_lines']}" in got["reason"]
        assert got["subpart"] == 1 and got["layer"] >= 2
        assert got["checkpoints"][-1]["subpart"] == 1
        assert got["modal"]["hotend"] == 210.0
        await c.call("events.subscribe")
        await c.call("job.resume", id=job["id"], **{"from": "checkpoint"})
        await c.until_state(job["id"], "completed", "failed", "paused")
        log = executed((await c.call("sim.log"))["commands"])
        cp_line = got["checkpoints"][-1]["line"]
        first = log.index(cmds[cp_line])
        restart = log[:first]
        assert restart[0] == "G28"
        assert "M109 S210" in restart and "M190 S60" in restart
        rot = restart.index("G0 A30.0000 C120.0000 F5400")
        assert any(x.startswith("G0 Z") for x in restart[:rot])
        assert [x for x in log[first:] if x not in ("M400", "M114")] == cmds[cp_line:]
        final = await c.call("job.get", id=job["id"])
        assert final["state"] == "completed"
        await c.close()
    await d.stop()


async def test_lost_step_pauses_at_the_right_transition(daemon_factory):
    d = daemon_factory(sim__lost_step_axis="C", sim__lost_step_degrees=2.0,
                       sim__lost_step_at_move=2)
    await d.start()
    text = make_gcode(subparts=3, layers=2, per_layer=20)
    async with asyncio.timeout(60):
        c = await d.rpc()
        await c.call("events.subscribe")
        job = await c.submit_text("pipe3.gcode", text)
        failed = await c.until(lambda e: e["event"] == "transition_failed")
        assert failed["subpart"] == 2 and abs(failed["measured"]["C"] - 242.0) < 0.01
        ev = await c.until_state(job["id"], "paused")
        assert "transition to sub-part 2 failed" in ev["reason"]
        status = await c.call("printer.status")
        assert status["jobs"]["transitions"] == {"total": 2, "failed": 1}
        got = await c.call("job.get", id=job["id"])
        assert [cp["subpart"] for cp in got["checkpoints"]] == [1]
        await c.call("job.cancel", id=job["id"])
        await c.close()
    await d.stop()


async def test_sigterm_mid_print_records_interrupted_with_modal_state(daemon_factory):
    d = daemon_factory()
    await d.start()
    text = make_gcode(subparts=1, layers=20, per_layer=200)
    async with asyncio.timeout(60):
        c = await d.rpc()
        await c.call("events.subscribe", events=["job.progress", "job.state"])
        job = await c.submit_text("long.gcode", text)
        await c.until(lambda e: e["event"] == "job.progress" and e["progress"] > 0.1)
        assert await d.stop(signal.SIGTERM) == 0
        assert d.loop_errors() == []  # a client was still connected
        # and it was told what became of the job before the connection closed
        last = await c.until_state(job["id"], "interrupted")
        assert last["old"] == "printing" and "SIGTERM" in last["reason"]
        # the journal tells the operator what became of the job, as a warning
        ended = [ln for ln in d.stderr if ln.startswith(f"WARNING hostd.jobs.manager: job "
                                                        f"{job['id']} 'long.gcode': printing "
                                                        "-> interrupted (")]
        assert len(ended) == 1 and "SIGTERM" in ended[0]
        await c.close()
        await d.start()
        c = await d.rpc()
        got = await c.call("job.get", id=job["id"])
        assert got["state"] == "interrupted" and "SIGTERM" in got["reason"]
        assert got["acked_lines"] > 0 and got["modal"]["hotend"] == 210.0
        assert [h["new"] for h in got["history"]][-2:] == ["printing", "interrupted"]
        await c.close()
    await d.stop()


async def test_temperatures_stay_live_while_a_job_prints(daemon_factory):
    """A heater target changed by the job itself shows in the pushed temperatures and in
    printer.status while the job still prints: hostd queries them during a print too."""
    d = daemon_factory(sim__throttle=True)
    await d.start()
    text = make_gcode(subparts=1, layers=20, per_layer=200)
    first_layer = text.index(";HOSTD_LAYER")
    text = text[:first_layer] + "M104 S215\n" + text[first_layer:]
    async with asyncio.timeout(60):
        c = await d.rpc()
        await c.call("events.subscribe", events=["printer.temperatures"])
        job = await c.submit_text("hot.gcode", text)
        await c.until(lambda e: e["heaters"]["T"]["target"] == 215.0)
        status = await c.call("printer.status")
        assert status["jobs"]["current"]["id"] == job["id"]  # still printing
        assert status["jobs"]["current"]["state"] == "printing"
        assert status["link"]["temperatures"]["T"]["target"] == 215.0
        await c.close()
    await d.stop()


async def test_temperatures_are_published_through_a_heat_up_in_the_job(daemon_factory):
    """An M109 in the job holds the stream (and a temperature query behind it) while the
    hotend heats: the heat-up's own reports still reach subscribers as it goes."""
    d = daemon_factory(sim__realtime=True, sim__time_scale=10.0)  # 20 s time constant: ~2 s
    await d.start()
    text = "M104 S200\nM109 S200\nG1 X1 F600\n"
    async with asyncio.timeout(60):
        c = await d.rpc()
        await c.call("events.subscribe", events=["printer.temperatures", "job.state"])
        job = await c.submit_text("heat.gcode", text)
        await c.until_state(job["id"], "printing")
        seen: list[float] = []
        while True:  # temperatures while the job waits on its M109, until it is done
            ev = await c.until(lambda e: e["event"] in ("printer.temperatures", "job.state"))
            if ev["event"] == "job.state":
                break
            if ev["heaters"]["T"]["target"] == 200.0:
                seen.append(ev["heaters"]["T"]["actual"])
        assert ev["new"] == "completed"
        cmds = [cmd for _, cmd in (await c.call("sim.log"))["commands"]]
        await c.close()
    await d.stop()
    rising = [t for t in seen if 30.0 < t < 190.0]  # reports from the middle of the heat-up
    assert len(rising) >= 2 and rising == sorted(rising)
    # one temperature query at a time: the one held behind the M109, then the end's barrier
    # (queries sent every 2 s through a heat-up of several would pile up behind it)
    assert cmds[cmds.index("M109 S200") + 1:].count("M105") <= 2
