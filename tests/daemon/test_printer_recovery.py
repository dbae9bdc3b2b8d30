"""The printer away and back: jobs wait while the link is halted instead of failing one after
another, ``printer.firmware_restart`` brings a halted board back, and a second daemon on the
same state directory or socket is refused without harming the first."""

from __future__ import annotations

import asyncio

import pytest
from hostd_harness import DaemonProc, RpcCallError, executed, file_commands, make_gcode

pytestmark = pytest.mark.asyncio


async def test_queued_jobs_wait_while_halted_and_print_after_a_firmware_restart(
        daemon_factory):
    d = daemon_factory()
    await d.start()
    a = make_gcode(subparts=1, layers=2, per_layer=20).replace("X1", "X3")
    b = make_gcode(subparts=1, layers=2, per_layer=20).replace("X1", "X4")
    async with asyncio.timeout(60):
        c = await d.rpc()
        await c.call("events.subscribe")
        assert (await c.call("printer.estop"))["stopped"] is True
        status = await c.call("printer.status")
        assert status["link"]["state"] == "halted"
        ja = await c.submit_text("a.gcode", a)
        await c.until(lambda e: e["event"] == "printer.state" and e["state"] == "waiting")
        jb = await c.submit_text("b.gcode", b)
        status = await c.call("printer.status")
        assert status["jobs"]["waiting_for_printer"] is True
        listed = {j["id"]: j["state"] for j in (await c.call("job.list"))["jobs"]}
        assert listed == {ja["id"]: "ready", jb["id"]: "ready"}  # not failed
        restarted = await c.call("printer.firmware_restart")
        assert restarted["link"] == "ready"
        for job in (ja, jb):
            assert (await c.call("job.wait", id=job["id"]))["state"] == "completed"
        ran = [cmd for cmd in executed((await c.call("sim.log"))["commands"])
               if cmd not in ("M400", "M114")]
        assert ran == file_commands(a) + file_commands(b)  # the fresh board ran both, in order
        assert (await c.call("printer.status"))["jobs"]["waiting_for_printer"] is False
        await c.close()
    assert await d.stop() == 0
    assert d.loop_errors() == []


async def test_a_firmware_restart_is_refused_while_a_job_is_on_the_printer(daemon_factory):
    d = daemon_factory(sim__throttle=True)
    await d.start()
    text = make_gcode(subparts=1, layers=40, per_layer=200)
    async with asyncio.timeout(60):
        c = await d.rpc()
        await c.call("events.subscribe")
        job = await c.submit_text("long.gcode", text)
        ev = await c.until(lambda e: e["event"] == "job.progress" and e["acked"] > 10)
        assert (ev["state"], ev["stream"]) == ("printing", "streaming")  # job's, streamer's
        with pytest.raises(RpcCallError) as err:
            await c.call("printer.firmware_restart")
        assert err.value.code == -32004 and f"job {job['id']}" in err.value.message
        assert (await c.call("job.get", id=job["id"]))["state"] == "printing"
        assert (await c.call("job.cancel", id=job["id"]))["state"] == "cancelled"
        await c.close()
    await d.stop()


async def _refused(second: DaemonProc) -> str:
    with pytest.raises(RuntimeError, match="hostd exited"):
        await second.start()
    assert second.proc is not None
    assert await second.proc.wait() == 1
    return "".join(second.stderr)


async def test_a_second_daemon_on_the_same_state_directory_is_refused(daemon_factory,
                                                                        tmp_path_factory):
    first = daemon_factory()
    await first.start()
    other = tmp_path_factory.mktemp("second")
    second = DaemonProc(other, daemon__state_dir=str(first.tmp / "state"))
    async with asyncio.timeout(60):
        err = await _refused(second)
        assert "is in use by another hostd (pid " in err and "Traceback" not in err
        assert f"pid {first.proc.pid})" in err
        c = await first.rpc()  # the first is untouched
        assert (await c.call("server.info"))["name"] == "hostd"
        await c.close()
    assert await first.stop() == 0
    again = daemon_factory()  # the lock went with the first daemon
    await again.start()
    assert await again.stop() == 0


async def test_a_second_daemon_on_a_live_socket_leaves_the_socket_alone(daemon_factory,
                                                                        tmp_path_factory):
    first = daemon_factory()
    await first.start()
    other = tmp_path_factory.mktemp("second")
    second = DaemonProc(other, daemon__socket=str(first.socket))
    async with asyncio.timeout(60):
        err = await _refused(second)
        assert "another daemon is listening" in err
        assert first.socket.is_socket()  # it used to remove the first daemon's socket
        c = await first.rpc()
        assert (await c.call("server.info"))["name"] == "hostd"
        await c.close()
    assert await first.stop() == 0
