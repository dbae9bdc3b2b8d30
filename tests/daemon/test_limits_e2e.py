"""Issues 37 and 38: what clients may cost a running daemon, measured on a live one.

The flood comes from ``bench/flood.py``'s own load generator in a process of its own. Each
test compares figures of its own run (a rate before the flood and during it, the RSS before
and after), never a wall-clock time alone.
"""

from __future__ import annotations

import asyncio
import json
import socket
import sys
from pathlib import Path
from typing import Any

import pytest
from hostd_harness import ROOT, DaemonProc, Rpc, free_port, scrape

# rates before and during a flood: with other tests beside them the load differs between
# the two windows, so these run alone (`make pytest`, the "serial" marker)
pytestmark = [pytest.mark.asyncio, pytest.mark.serial]

FLOOD = ROOT / "bench" / "flood.py"


def plain_moves(lines: int) -> str:
    moves = [f"G1 X{200 + (i % 50) * 0.5:.1f} Y{200 + (i % 40) * 0.5:.1f} E0.02 F6000"
             for i in range(lines)]
    return "\n".join(["G90", "M83", *moves]) + "\n"


async def acked(c: Rpc) -> int:
    return int((await c.call("printer.status"))["link"]["lines_acked"])


async def rate(c: Rpc, seconds: float) -> float:
    """Lines the link acknowledged per second over ``seconds`` (a measuring window)."""
    loop = asyncio.get_running_loop()
    a0, t0 = await acked(c), loop.time()
    await asyncio.sleep(seconds)  # the window measured, not a wait for something
    return (await acked(c) - a0) / (loop.time() - t0)


async def flood(sock: Path, seconds: float, *args: str) -> asyncio.subprocess.Process:
    """The bench's flood on ``sock``, once it has begun."""
    proc = await asyncio.create_subprocess_exec(
        sys.executable, str(FLOOD), "--worker", str(sock), "--seconds", str(seconds), *args,
        stdout=asyncio.subprocess.PIPE, cwd=str(ROOT))
    assert proc.stdout is not None
    assert await proc.stdout.readline() == b"flooding\n"
    return proc


async def tally(proc: asyncio.subprocess.Process) -> dict[str, Any]:
    out, _ = await proc.communicate()
    return dict(json.loads(out))


def status_of(pid: int, key: str) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    raise KeyError(key)


@pytest.mark.timeout(120)
async def test_the_stream_keeps_its_pace_through_a_flood(daemon_factory):
    """20 clients writing 50 ``printer.status`` requests at once, again and again: before,
    the daemon answered a connection's requests back to back while the port waited (and
    every connection's in each pass of the loop); now requests take turns, one a pass, and
    a share of the loop's time, so the link acknowledges lines at its unloaded pace."""
    d = daemon_factory(sim__throttle=True, serial__baud=115200)
    await d.start()
    async with asyncio.timeout(100):
        c = await d.rpc()
        await c.printing(plain_moves(12000), progress=0.02)
        unloaded = await rate(c, 3.0)
        proc = await flood(d.socket, 5.0, "--clients", "20", "--pipeline", "50",
                           "--slowloris", "0", "--big", "0")
        flooded = await rate(c, 4.0)
        served = await tally(proc)
        await c.close()
    assert served["status_calls"] > 1000  # the flood was served, not refused
    assert flooded / unloaded >= 0.85, (flooded, unloaded)
    assert not d.loop_errors()
    await d.stop()


def hold_connections(family: int, address: Any, n: int) -> list[socket.socket]:
    held = []
    for _ in range(n):
        s = socket.socket(family, socket.SOCK_STREAM)
        s.connect(address)
        held.append(s)
    return held


@pytest.mark.timeout(120)
async def test_idle_connections_lock_nobody_out_and_cost_no_thread(daemon_factory):
    """Issue 38: a thousand idle connections to the metrics port cost a thread each and, with
    the control socket's, used up the open files: every accept then logged a traceback, and
    nobody could connect. Now each listener holds at most its cap, a silent connection
    makes room for a new one, and a refusal is logged once a minute at most."""
    port = free_port()
    d = daemon_factory(metrics__enabled=True, metrics__port=port)  # the default caps
    await d.start(limit_files=256)
    assert d.proc is not None
    async with asyncio.timeout(100):
        c = await d.rpc()
        threads = status_of(d.proc.pid, "Threads")
        held = await asyncio.to_thread(hold_connections, socket.AF_INET, ("127.0.0.1", port),
                                       300)
        held += await asyncio.to_thread(hold_connections, socket.AF_UNIX, str(d.socket), 300)
        body = await scrape(port)  # room made for it
        status = await (await d.rpc()).call("printer.status")  # and for a new client
        assert status_of(d.proc.pid, "Threads") <= threads
        for s in held:
            s.close()
        await c.close()
    assert "hostd_connections_open" in body
    conns = status["connections"]
    assert conns["open"]["control"] <= 64 and conns["open"]["metrics"] <= 8
    assert conns["dropped"]["room"] > 0
    log = "".join(d.stderr)
    assert "Traceback" not in log and "out of system resource" not in log
    assert len(log) < 5000, log[-2000:]
    await d.stop()


async def unfinished(sock: Path, size: int) -> asyncio.StreamWriter:
    """A connection sending ``size`` bytes of a request it never finishes."""
    _, w = await asyncio.open_unix_connection(str(sock))
    chunk = b"x" * (1 << 20)
    try:
        for _ in range(size // len(chunk)):
            w.write(chunk)
            await w.drain()
    except ConnectionError:
        pass  # closed for it: the point
    return w


@pytest.mark.timeout(120)
async def test_unfinished_frames_cost_bounded_memory(daemon_factory):
    """Issue 38: 10 connections each holding an unfinished 80 MB frame raised RSS to 889 MB.
    Each connection now reads at most daemon.max_request_bytes of a request, and all of them
    together daemon.max_buffered_bytes; the daemon's RSS grows by a few MB, not by what the
    clients sent."""
    d = daemon_factory()
    await d.start()
    assert d.proc is not None
    async with asyncio.timeout(100):
        c = await d.rpc()
        before = status_of(d.proc.pid, "VmRSS")
        writers = await asyncio.gather(*(unfinished(d.socket, 40 << 20) for _ in range(10)))
        peak = status_of(d.proc.pid, "VmHWM")
        status = await c.call("printer.status")
        for w in writers:
            w.close()
        await c.close()
    assert (peak - before) / 1024 < 40, (before, peak)  # kB: 400 MB sent
    limits = status["control"]["limits"]
    assert limits["dropped"]["too_large"] == 10
    assert limits["buffered_bytes"] < 100  # the status request itself, while answered
    await d.stop()


@pytest.mark.timeout(60)
async def test_a_limit_too_low_for_the_caps_is_a_start_error(tmp_path: Path):
    d = DaemonProc(tmp_path, daemon__max_connections=500)
    with pytest.raises(RuntimeError, match=r"daemon\.max_connections: the connection caps "
                                           r"need 628 open files"):
        await d.start(limit_files=256)
    assert d.proc is not None and await d.proc.wait() == 1
