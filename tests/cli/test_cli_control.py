"""hostctl's daemon verbs against a hostd subprocess: output, --json and exit codes."""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import json
import os
import signal
import sys
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "daemon"))
from hostd_harness import DaemonProc, hostctl, make_gcode

from hostd.cli.cmd_control import PART_BYTES

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.asyncio
async def test_hostctl_verbs_and_exit_codes(tmp_path):
    d = DaemonProc(tmp_path)
    gcode = tmp_path / "part.gcode"
    gcode.write_text(make_gcode(subparts=2, layers=2, per_layer=40))
    async with asyncio.timeout(90):
        rc, _, err = await hostctl(tmp_path / "none.sock", "status")
        assert rc == 3 and err.startswith("hostctl: cannot connect to hostd")
        await d.start()
        try:
            rc, out, err = await hostctl(d.socket, "print", str(gcode), "--wait")
            assert rc == 0, err
            assert "job 1 completed" in out and "100.0%" in out
            rc, out, _ = await hostctl(d.socket, "jobs", "--json")
            listed = json.loads(out)
            assert rc == 0 and listed["total"] == 1 and listed["jobs"][0]["state"] == "completed"
            rc, out, _ = await hostctl(d.socket, "status", "--json")
            assert rc == 0 and json.loads(out)["jobs"]["finished"]["completed"] == 1
            rc, out, _ = await hostctl(d.socket, "status")
            assert rc == 0 and "no job printing" in out and "link trouble" not in out
            rc, out, _ = await hostctl(d.socket, "send", "M114", "--json")
            assert rc == 0 and "position" in json.loads(out)["replies"][0]
            rc, _, err = await hostctl(d.socket, "pause")
            assert rc == 4 and err.startswith("hostctl: no job is printing")
            rc, _, err = await hostctl(d.socket, "print", str(tmp_path / "missing.stl"))
            assert rc == 2 and "missing.stl" in err
            empty = tmp_path / "empty.gcode"
            empty.write_text("")
            rc, _, err = await hostctl(d.socket, "print", str(empty))
            assert rc == 2 and "empty.gcode: empty upload" in err  # a bad input file
            rc, out, _ = await hostctl(d.socket, "print", str(gcode), "--json")
            assert rc == 0 and json.loads(out)["id"] == 2
            plain = tmp_path / "part.txt"  # an extension that says nothing
            plain.write_bytes(gcode.read_bytes())
            rc, _, err = await hostctl(d.socket, "print", str(plain))
            assert rc == 2 and "give the kind (hostctl print --kind)" in err
            rc, out, _ = await hostctl(d.socket, "print", str(plain), "--kind", "gcode", "--json")
            assert rc == 0 and json.loads(out)["kind"] == "gcode"
            rc, out, _ = await hostctl(d.socket, "jobs", "--limit", "2")
            shown = [int(line.split()[0]) for line in out.splitlines()[1:]]
            assert rc == 0 and shown == [2, 3]  # the newest, oldest first
            assert out.splitlines()[0].startswith("(1 older jobs not shown")
            rc, out, _ = await hostctl(d.socket, "jobs", "--limit", "2", "--json")
            listed = json.loads(out)  # job.list's result: how many were left out too
            assert rc == 0 and [j["id"] for j in listed["jobs"]] == [2, 3]
            assert listed["total"] == 3
            rc, out, _ = await hostctl(d.socket, "jobs", "--limit", "0", "--json")
            assert rc == 0 and [j["id"] for j in json.loads(out)["jobs"]] == [1, 2, 3]
            rc, _, err = await hostctl(d.socket, "jobs", "--limit", "-1")
            assert rc == 2 and "whole number" in err
            rc, out, _ = await hostctl(d.socket, "delete", "1")
            assert rc == 0 and out.strip() == "job 1 deleted"
            rc, out, _ = await hostctl(d.socket, "jobs", "--limit", "0", "--json")
            assert [j["id"] for j in json.loads(out)["jobs"]] == [2, 3]
            rc, _, err = await hostctl(d.socket, "delete", "1")
            assert rc == 4 and "1" in err
        finally:
            await d.stop()


@pytest.mark.asyncio
async def test_hostctl_sends_a_large_file_in_parts(tmp_path):
    """A file over one part goes as job.upload parts then job.submit: the same job as the
    file, in one request per part; over the daemon's limit, refused with the limit named."""
    d = DaemonProc(tmp_path, daemon__max_upload_bytes=4 * PART_BYTES)
    big = tmp_path / "big.gcode"
    big.write_text(make_gcode(subparts=2, layers=10, per_layer=600))
    data = big.read_bytes()
    parts = -(-len(data) // PART_BYTES)
    assert 1 < parts <= 4
    too_big = tmp_path / "huge.gcode"
    too_big.write_bytes(b"G1 X1\n" * (4 * PART_BYTES // 6 + 1))
    async with asyncio.timeout(90):
        await d.start()
        try:
            rc, out, _ = await hostctl(d.socket, "status", "--json")
            before = json.loads(out)["control"]["requests_total"]
            rc, out, err = await hostctl(d.socket, "print", str(big), "--json")
            assert rc == 0, err
            job = json.loads(out)
            assert job["upload_sha"] == hashlib.sha256(data).hexdigest()
            rc, out, _ = await hostctl(d.socket, "status", "--json")
            # the limit (server.info), the parts, the submission, and this status call
            assert json.loads(out)["control"]["requests_total"] - before == parts + 3
            rc, out, _ = await hostctl(d.socket, "status", "--json")
            before = json.loads(out)["control"]["requests_total"]
            rc, _, err = await hostctl(d.socket, "print", str(too_big))
            assert rc == 2 and f"exceeds the limit of {4 * PART_BYTES} bytes" in err
            assert str(too_big) in err and "daemon.max_upload_bytes" in err
            rc, out, _ = await hostctl(d.socket, "status", "--json")
            # refused from the file's size: no part was sent (nor the file read)
            assert json.loads(out)["control"]["requests_total"] - before == 2
        finally:
            await d.stop()


async def print_wait_until_hostd_stops(d: DaemonProc, *options: str) -> tuple[int, str, str]:
    """``hostctl print --wait`` of a long job, and hostd stopped (SIGTERM) mid-print."""
    gcode = d.tmp / "long.gcode"
    gcode.write_text(make_gcode(subparts=1, layers=20, per_layer=200))
    await d.start()
    watcher = await d.rpc()
    await watcher.call("events.subscribe", events=["job.progress"])
    printing = asyncio.create_task(hostctl(d.socket, "print", str(gcode), "--wait",
                                           *options))
    await watcher.until(lambda e: e["progress"] > 0.05)
    await d.stop()
    done = await printing
    await watcher.close()
    return done


@pytest.mark.asyncio
async def test_print_wait_tells_how_to_resume_when_hostd_stops_mid_print(tmp_path):
    """hostd stopped (SIGTERM) mid-print: ``hostctl print --wait`` shows the job interrupted,
    and how to resume it, not a bare lost connection."""
    d = DaemonProc(tmp_path, sim__throttle=True)
    async with asyncio.timeout(90):
        rc, out, err = await print_wait_until_hostd_stops(d)
    assert rc == 1, err
    lines = out.splitlines()
    assert lines[-2].startswith("job 1 interrupted: daemon stopped (SIGTERM) at line ")
    assert lines[-1] == "resume it with: hostctl resume 1 [--from layer|subpart|checkpoint]"
    async with asyncio.timeout(60):  # after a restart, status still names the job
        await d.start()
        try:
            rc, out, _ = await hostctl(d.socket, "status")
        finally:
            await d.stop()
    assert rc == 0 and "no job printing\nlast job 1 interrupted at line " in out
    assert "resume: hostctl resume 1 [--from layer|subpart|checkpoint]" in out


@pytest.mark.asyncio
async def test_status_shows_the_link_trouble_of_a_noisy_line(tmp_path):
    d = DaemonProc(tmp_path, sim__bit_flip_prob=0.02)  # seeded: some lines arrive garbled
    gcode = tmp_path / "part.gcode"
    gcode.write_text(make_gcode(subparts=1, layers=2, per_layer=100))
    async with asyncio.timeout(60):
        await d.start()
        try:
            rc, _, err = await hostctl(d.socket, "print", str(gcode), "--wait")
            assert rc == 0, err
            rc, out, _ = await hostctl(d.socket, "status")
            rc_json, raw, _ = await hostctl(d.socket, "status", "--json")
        finally:
            await d.stop()
    link = json.loads(raw)["link"]
    assert rc == rc_json == 0 and link["resend_requests"] > 0
    (line,) = [ln for ln in out.splitlines() if "link trouble" in ln]
    assert f"{link['resend_requests']} resend request" in line


@pytest.mark.asyncio
async def test_status_after_an_estop_and_firmware_restart(tmp_path):
    """An estop mid-print: status names the failed job and its line; a job queued meanwhile
    is held (print and status say so, with the way out); firmware-restart brings the board
    back and the held job prints."""
    d = DaemonProc(tmp_path, sim__throttle=True)
    long = tmp_path / "long.gcode"
    long.write_text(make_gcode(subparts=1, layers=20, per_layer=200))
    short = tmp_path / "short.gcode"
    short.write_text(make_gcode(subparts=1, layers=2, per_layer=20))
    async with asyncio.timeout(90):
        await d.start()
        try:
            watcher = await d.rpc()
            await watcher.call("events.subscribe")
            rc, out, _ = await hostctl(d.socket, "print", str(long), "--json")
            await watcher.until(lambda e: e["event"] == "job.progress" and e["acked"] > 10)
            rc, out, _ = await hostctl(d.socket, "estop")
            assert rc == 0 and "emergency stop sent" in out
            await watcher.until_state(1, "failed")
            rc, out, _ = await hostctl(d.socket, "print", str(short))
            assert rc == 0 and out.splitlines() == [  # why it does not start: the board
                "job 2 ready: short.gcode",
                "queue held: the printer is not ready (link halted): hostctl "
                "firmware-restart brings it back"]
            await watcher.until(lambda e: e["event"] == "printer.state"
                                and e["state"] == "waiting")
            rc, out, _ = await hostctl(d.socket, "status")
            assert rc == 0 and "link: halted" in out
            assert "last job 1 failed at line " in out
            assert "held: the printer is not ready" in out and "firmware-restart" in out
            rc, out, err = await hostctl(d.socket, "firmware-restart")
            assert rc == 0 and out.strip() == "firmware restarted: link ready", err
            assert (await watcher.call("job.wait", id=2))["state"] == "completed"
            rc, out, _ = await hostctl(d.socket, "status")
            assert "held:" not in out and "link: ready" in out
            await watcher.close()
        finally:
            await d.stop()


@pytest.mark.asyncio
async def test_hostctl_queue_shows_and_lifts_the_hold(tmp_path):
    d = DaemonProc(tmp_path, daemon__next_job="after_clear")
    part = tmp_path / "part.gcode"
    part.write_text(make_gcode(subparts=1, layers=2, per_layer=20))
    async with asyncio.timeout(90):
        await d.start()
        try:
            rc, out, err = await hostctl(d.socket, "print", str(part), "--wait")
            assert rc == 0 and "job 1 completed" in out, err
            rc, out, _ = await hostctl(d.socket, "queue")
            assert rc == 0 and out.splitlines()[0] == (
                "queue held: job 1 completed: clear the platform, then hostctl queue start")
            rc, out, _ = await hostctl(d.socket, "print", str(part))
            assert rc == 0 and out.splitlines() == [
                "job 2 ready: part.gcode",
                "queue held: job 1 completed: clear the platform, then hostctl queue start"]
            rc, out, _ = await hostctl(d.socket, "status")
            assert "queue: 1 waiting\n  held: job 1 completed: clear the platform" in out
            rc, out, _ = await hostctl(d.socket, "queue", "start", "--json")
            assert rc == 0 and json.loads(out)["held"] is False
            watcher = await d.rpc()
            assert (await watcher.call("job.wait", id=2))["state"] == "completed"
            await watcher.close()
            rc, out, _ = await hostctl(d.socket, "queue", "hold")
            assert rc == 0 and out.startswith("queue held: job 2 completed")
            rc, _, err = await hostctl(d.socket, "print", str(tmp_path))
            assert rc == 2 and err.strip() == f"hostctl: {tmp_path}: not a regular file"
        finally:
            await d.stop()


@pytest.mark.asyncio
async def test_print_wait_says_when_the_hold_starts_after_the_job_was_queued(tmp_path):
    d = DaemonProc(tmp_path, daemon__next_job="after_clear", sim__throttle=True)
    first, second = tmp_path / "first.gcode", tmp_path / "second.gcode"
    first.write_text(make_gcode(subparts=1, layers=10, per_layer=100))
    second.write_text(make_gcode(subparts=1, layers=2, per_layer=20))
    async with asyncio.timeout(90):
        await d.start()
        try:
            watcher = await d.rpc()
            await watcher.call("events.subscribe", events=["job.progress", "queue.state"])
            rc, _, _ = await hostctl(d.socket, "print", str(first))
            await watcher.until(lambda e: e["event"] == "job.progress" and e["acked"] > 10)
            waiting = asyncio.create_task(hostctl(d.socket, "print", str(second), "--wait"))
            await watcher.until(lambda e: e["event"] == "queue.state" and e["held"])
            await watcher.call("queue.start")
            rc, out, err = await waiting
            await watcher.close()
        finally:
            await d.stop()
    assert rc == 0, err
    lines = out.splitlines()
    held = [i for i, line in enumerate(lines) if line.startswith("queue held: job 1 completed")]
    assert held and lines[-2].startswith("job 2 completed")
    assert lines[-1].startswith("summary: ")  # the end-of-job summary (issue 36)


@contextlib.asynccontextmanager
async def running(tmp_path: Path, **overrides: Any) -> AsyncIterator[DaemonProc]:
    """A hostd subprocess, started, and stopped at the end."""
    d = DaemonProc(tmp_path, **overrides)
    await d.start()
    try:
        yield d
    finally:
        await d.stop()


async def hostctl_to_closed_pipe(sock: Path, *args: str) -> tuple[int, str]:
    """hostctl with a stdout whose reader is already gone (``hostctl ... | head``)."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "hostd.cli.main", "--socket", str(sock), *args,
            stdout=write_end, stderr=asyncio.subprocess.PIPE, cwd=str(ROOT))
    finally:
        os.close(write_end)
    _, err = await proc.communicate()
    return proc.returncode or 0, err.decode()


@pytest.mark.asyncio
async def test_output_to_a_reader_that_went_away_exits_quietly_with_141(tmp_path):
    async with asyncio.timeout(60), running(tmp_path) as d:
        for args in (("status",), ("status", "--json"), ("jobs",), ("watch",),
                     ("watch", "--json")):
            rc, err = await hostctl_to_closed_pipe(d.socket, *args)
            assert (rc, err) == (141, ""), args


@pytest.mark.asyncio
async def test_send_exits_by_the_documented_table(tmp_path):
    """A command the firmware answers with an error is refused (4), also with --json; a
    line the daemon refuses as bad params (a heater target over the limit) is bad input
    (2); a command that runs is 0."""
    async with asyncio.timeout(60), running(tmp_path) as d:
        rc, out, err = await hostctl(d.socket, "send", "M42 P13 S255")
        assert rc == 4, (out, err)
        assert err.startswith('hostctl: the firmware refused M42 P13 S255: Unknown command')
        rc, out, err = await hostctl(d.socket, "send", "--json", "M42 P13 S255", "M105")
        res = json.loads(out)
        assert rc == 4 and res["errors"] == [
            {"command": "M42 P13 S255", "reply": 'Unknown command: "M42 P13 S255"'}]
        assert "temperatures" in res["replies"][1]
        rc, _, err = await hostctl(d.socket, "send", "M104 S999")
        assert rc == 2 and "above the hotend's limit" in err
        rc, out, _ = await hostctl(d.socket, "send", "M105")
        assert rc == 0 and "temperatures" in out
        rc, out, err = await hostctl(d.socket, "send", "G90", "M104", "S200", "M105")
        assert (rc, out) == (2, "")  # one argument, one line: S200 is no command
        assert err == ("hostctl: script: line 3: 'S200' is not a G-code command (a G, M or T "
                       "code and its number); quote a command with its parameters: hostctl "
                       'send G90 "M104 S200" M105\n')
        rc, _, err = await hostctl(d.socket, "send", "M105", "hello")
        assert rc == 2 and "'HELLO' is not a G-code command" in err and "quote" not in err


@pytest.mark.asyncio
async def test_a_job_name_with_a_newline_is_refused_at_submit(tmp_path):
    odd = tmp_path / "a\nWARNING fake.gcode"
    odd.write_text(make_gcode(subparts=1, layers=1, per_layer=5))
    async with asyncio.timeout(60), running(tmp_path) as d:
        c = await d.rpc()
        msg = await c.raw("job.submit", name="a\nWARNING fake.gcode", data="G28\n",
                          encoding="text")
        assert msg["error"]["code"] == -32602
        assert "name: control character '\\n'" in msg["error"]["message"]
        await c.close()
        rc, _, err = await hostctl(d.socket, "print", str(odd))
        assert rc == 2 and "control character" in err and err.count("\n") == 1
        rc, out, _ = await hostctl(d.socket, "jobs", "--json")
        assert rc == 0 and json.loads(out) == {"jobs": [], "total": 0}


@pytest.mark.asyncio
async def test_print_of_a_corrupt_ascii_stl_exits_2_naming_its_line_and_the_print_goes_on(
        tmp_path):
    """A corrupt ASCII STL is refused at submission (not when its slice starts): one line
    naming the file and the line, exit 2; the daemon and the job printing carry on."""
    long = tmp_path / "long.gcode"
    long.write_text(make_gcode(subparts=1, layers=20, per_layer=200))
    bad = tmp_path / "bad.stl"
    bad.write_bytes(b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 x0\n"
                    b"vertex 0 1 0\nendloop\nendfacet\nendsolid x\n")
    async with asyncio.timeout(90), running(tmp_path, sim__throttle=True) as d:
        watcher = await d.rpc()
        await watcher.call("events.subscribe", events=["job.progress"])
        rc, _, err = await hostctl(d.socket, "print", str(long))
        assert rc == 0, err
        await watcher.until(lambda e: e["event"] == "job.progress" and e["acked"] > 10)
        rc, out, err = await hostctl(d.socket, "print", str(bad))
        assert (rc, out) == (2, "")
        assert err == "hostctl: bad.stl: not a readable STL file (line 5: 'vertex 1 0 x0')\n"
        rc, out, _ = await hostctl(d.socket, "jobs", "--json")
        listed = json.loads(out)["jobs"]
        assert rc == 0 and [(j["id"], j["state"]) for j in listed] == [(1, "printing")]
        await watcher.close()


def _sigint_default() -> None:
    """Ctrl-C as at a terminal: a suite run in the background of a non-interactive shell
    (``make test &``) hands its children SIGINT ignored, and Python then keeps it so."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.asyncio
async def test_ctrl_c_of_print_wait_says_the_job_goes_on_and_estop_takes_json(tmp_path):
    long = tmp_path / "long.gcode"  # long enough to be printing still when SIGINT comes
    long.write_text(make_gcode(subparts=1, layers=60, per_layer=200))  # under load too
    async with asyncio.timeout(90), running(tmp_path, sim__throttle=True) as d:
        watcher = await d.rpc()
        await watcher.call("events.subscribe")
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "hostd.cli.main", "--socket", str(d.socket), "print",
            str(long), "--wait", stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE, cwd=str(ROOT), preexec_fn=_sigint_default)
        await watcher.until(lambda e: e["event"] == "job.progress" and e["acked"] > 10)
        proc.send_signal(signal.SIGINT)
        _, err = await proc.communicate()
        assert proc.returncode == 130
        assert err.decode().strip() == ("hostctl: interrupted: job 1 goes on (hostctl "
                                        "watch follows it; hostctl cancel 1 stops it)")
        assert (await watcher.call("job.get", id=1))["state"] == "printing"
        rc, out, _ = await hostctl(d.socket, "estop", "--json")
        assert rc == 0 and json.loads(out) == {"stopped": True}
        await watcher.until_state(1, "failed")
        rc, out, _ = await hostctl(d.socket, "firmware-restart", "--json")
        assert rc == 0 and json.loads(out) == {"link": "ready"}
        await watcher.close()


@pytest.mark.asyncio
async def test_print_wait_json_prints_only_the_final_job_and_a_failure_on_stderr(tmp_path):
    """``print --wait --json``: stdout holds one JSON document, the job as ``job.get`` gives
    it once the job ended (no event stream); a job that failed exits 1 with one line on
    stderr, in the words of the text mode's last line."""
    import trimesh

    part = tmp_path / "part.gcode"
    part.write_text(make_gcode(subparts=1, layers=2, per_layer=20))
    wide = tmp_path / "wide.stl"  # wider than the platform: its slice fails
    trimesh.creation.box([400.0, 400.0, 10.0]).export(wide, file_type="stl")
    async with asyncio.timeout(90), running(tmp_path, daemon__next_job="at_once") as d:
        rc, out, err = await hostctl(d.socket, "print", str(part), "--wait", "--json")
        assert (rc, err) == (0, "")
        c = await d.rpc()
        assert json.loads(out) == await c.call("job.get", id=1)  # one document: the job
        assert json.loads(out)["state"] == "completed" and "history" in json.loads(out)
        rc, out, err = await hostctl(d.socket, "print", str(wide), "--wait", "--json")
        job = json.loads(out)
        assert rc == 1 and job == await c.call("job.get", id=2) and job["state"] == "failed"
        assert err == f"hostctl: job 2 failed: {job['reason']}\n"
        assert "does not fit" in job["reason"]
        await c.close()


@pytest.mark.asyncio
async def test_print_wait_json_says_how_to_resume_when_hostd_stops_mid_print(tmp_path):
    """hostd stopped mid-print under ``print --wait --json``: exit 1, one line on stderr
    naming the job interrupted and how to resume it; stdout holds the job or nothing (hostd
    may close the connection before it answers ``job.get``), never events."""
    d = DaemonProc(tmp_path, sim__throttle=True)
    async with asyncio.timeout(90):
        rc, out, err = await print_wait_until_hostd_stops(d, "--json")
    assert rc == 1 and err.count("\n") == 1, err
    assert err.startswith("hostctl: job 1 interrupted: daemon stopped (SIGTERM) at line ")
    assert "resume it with: hostctl resume 1 [--from layer|subpart|checkpoint]" in err
    assert out == "" or json.loads(out)["state"] == "interrupted"
