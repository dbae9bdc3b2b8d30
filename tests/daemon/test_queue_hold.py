"""The queue hold (``daemon.next_job: after_clear``, the default): once a job has left a
part on the platform no new job starts until the operator says the platform is clear
(``queue.start``); the hold survives a restart, an interrupted job can still be resumed,
and a job that extruded nothing leaves the queue running."""

from __future__ import annotations

import asyncio

import pytest
from hostd_harness import executed, file_commands, make_gcode

pytestmark = pytest.mark.asyncio

HOLD = {"daemon__next_job": "after_clear"}


def _job(x: int, layers: int = 2, per_layer: int = 20) -> str:
    return make_gcode(subparts=1, layers=layers, per_layer=per_layer).replace("X1", f"X{x}")


async def test_the_next_job_waits_until_the_platform_is_cleared(daemon_factory):
    d = daemon_factory(**HOLD)
    await d.start()
    a, b = _job(3), _job(4)
    async with asyncio.timeout(60):
        c = await d.rpc()
        await c.call("events.subscribe")
        assert (await c.call("queue.status"))["held"] is False
        ja = await c.submit_text("a.gcode", a)
        jb = await c.submit_text("b.gcode", b)
        await c.until_state(ja["id"], "completed")
        held = await c.until(lambda e: e["event"] == "queue.state")
        assert held["held"] is True and f"job {ja['id']} completed" in held["reason"]
        queue = await c.call("queue.status")
        assert queue == {"held": True, "reason": held["reason"], "ready": 1,
                         "next_job": "after_clear"}
        assert (await c.call("job.get", id=jb["id"]))["state"] == "ready"
        status = await c.call("printer.status")
        assert status["jobs"]["queue"]["held"] is True and status["jobs"]["current"] is None
        started = await c.call("queue.start")
        assert started["held"] is False and started["reason"] is None
        lifted = await c.until(lambda e: e["event"] == "queue.state")
        assert lifted["held"] is False and lifted["reason"] is None  # as queue.status says
        assert (await c.call("job.wait", id=jb["id"]))["state"] == "completed"
        ran = [cmd for cmd in executed((await c.call("sim.log"))["commands"])
               if cmd not in ("M400", "M114")]
        assert ran == file_commands(a) + file_commands(b)
        assert (await c.call("queue.status"))["held"] is True  # b is on the platform now
        await c.call("job.delete", id=jb["id"])  # the reason no longer offers a job
        reason = (await c.call("queue.status"))["reason"]
        assert reason.startswith(f"job {jb['id']} was deleted") and "queue start" in reason
        await c.close()
    assert await d.stop() == 0


async def test_the_hold_survives_a_restart_and_the_operator_can_hold_the_queue(
        daemon_factory):
    d = daemon_factory(**HOLD)
    await d.start()
    async with asyncio.timeout(60):
        c = await d.rpc()
        first = await c.submit_text("a.gcode", _job(3))
        assert (await c.call("job.wait", id=first["id"]))["state"] == "completed"
        await c.close()
        assert await d.stop() == 0
        await d.start()
        c = await d.rpc()
        queue = await c.call("queue.status")
        assert queue["held"] is True and f"job {first['id']} completed" in queue["reason"]
        await c.call("queue.start")
        assert (await c.call("queue.hold"))["reason"] == "held by the operator"
        waiting = await c.submit_text("b.gcode", _job(4))
        assert (await c.call("job.get", id=waiting["id"]))["state"] == "ready"
        assert (await c.call("printer.status"))["jobs"]["current"] is None
        await c.call("events.subscribe", events=["job.state"])
        await c.call("queue.start")
        assert (await c.call("job.wait", id=waiting["id"]))["state"] == "completed"
        await c.close()
    assert await d.stop() == 0


async def test_a_job_that_extruded_nothing_leaves_the_queue_running(daemon_factory):
    d = daemon_factory(**HOLD)
    await d.start()
    async with asyncio.timeout(60):
        c = await d.rpc()
        dry = await c.submit_text("dry.gcode", "G28\nG90\nG1 X10 Y10 F3000\n")
        assert (await c.call("job.wait", id=dry["id"]))["state"] == "completed"
        assert (await c.call("queue.status"))["held"] is False
        await c.close()
    assert await d.stop() == 0


async def test_an_interrupted_job_holds_the_queue_and_can_still_be_resumed(daemon_factory):
    d = daemon_factory(sim__throttle=True, **HOLD)
    await d.start()
    text = _job(3, layers=20, per_layer=100)
    async with asyncio.timeout(90):
        c = await d.rpc()
        await c.call("events.subscribe", events=["job.progress"])
        job = await c.submit_text("long.gcode", text)
        await c.until(lambda e: e["event"] == "job.progress" and e["progress"] > 0.1)
        await c.close()
        assert await d.stop() == 0  # SIGTERM: recorded interrupted
        await d.start()
        c = await d.rpc()
        queue = await c.call("queue.status")
        assert queue["held"] is True and "interrupted" in queue["reason"]
        assert "resume it" in queue["reason"]
        other = await c.submit_text("other.gcode", _job(4))
        resumed = await c.call("job.resume", id=job["id"], **{"from": "layer"})
        assert resumed["state"] == "printing"  # the hold does not stop a resume
        queue = await c.call("queue.status")  # no longer "resume it"; still held
        assert queue["held"] is True and "was resumed" in queue["reason"], queue
        assert (await c.call("job.wait", id=job["id"]))["state"] == "completed"
        assert (await c.call("job.get", id=other["id"]))["state"] == "ready"
        await c.close()
    assert await d.stop() == 0
