"""Issue 38's abuse of the client-facing servers, items 4 and 5, as figures.

Run: ``.venv/bin/python bench/abuse.py [--checkout DIR]`` (another version of this
repository, e.g. a ``git worktree`` of an older commit, to compare). hostd runs on ``sim://``
with at most 1024 open files (the unit's ``LimitNOFILE=``), and two abuses follow, on
loopback and the Unix socket only, bounded in count and time:

- ``idle``: ``--idle`` (1000) connections to the metrics port and as many to the control
  socket, opened and held for ``--hold`` (30) seconds, sending nothing. Printed: hostd's
  threads, the log's size and tracebacks, and whether a new client got ``printer.status``
  answered meanwhile (``locked_out`` when not within 5 s).
- ``frames``: ``--frames`` (10) connections each sending an unfinished frame of
  ``--frame-mb`` (80) MB. Printed: hostd's RSS before and its peak (``VmHWM``).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import socket
import sys
import tempfile
import time
from pathlib import Path

from flood import ROOT, spawn_daemon

FILES = 1024  # the unit's LimitNOFILE=


async def spawn(checkout: Path, tmp: Path, metrics: int | None
                ) -> tuple[asyncio.subprocess.Process, asyncio.Task[list[str]]]:
    return await spawn_daemon(tmp, "sim://", 115200, 127, None, checkout, metrics, FILES)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def proc_status(pid: int, key: str) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    return -1


def hold(family: int, address: object, n: int) -> list[socket.socket]:
    """``n`` connections opened (each given up after a second when it cannot connect)."""
    held = []
    for _ in range(n):
        s = socket.socket(family, socket.SOCK_STREAM)
        s.settimeout(1.0)
        try:
            s.connect(address)
        except OSError:
            s.close()
            continue
        held.append(s)
    return held


async def answered(sock: Path) -> bool:
    """Whether a new client gets ``printer.status`` answered within 5 s."""
    try:
        async with asyncio.timeout(5):
            r, w = await asyncio.open_unix_connection(str(sock), limit=1 << 22)
            w.write(b'{"jsonrpc": "2.0", "id": 1, "method": "printer.status"}\n')
            reply = json.loads(await r.readline())
            w.close()
            return "result" in reply
    except (OSError, TimeoutError, ValueError):
        return False


async def idle(args: argparse.Namespace, tmp: Path) -> dict[str, object]:
    port = free_port()
    proc, log = await spawn(args.checkout, tmp, port)
    try:
        threads0 = proc_status(proc.pid, "Threads")
        held = await asyncio.to_thread(hold, socket.AF_INET, ("127.0.0.1", port), args.idle)
        held += await asyncio.to_thread(hold, socket.AF_UNIX, str(tmp / "hostd.sock"),
                                        args.idle)
        end = time.monotonic() + args.hold
        served = []
        while time.monotonic() < end:
            served.append(await answered(tmp / "hostd.sock"))
            await asyncio.sleep(1.0)  # a client asking once a second
        threads = proc_status(proc.pid, "Threads")
        for s in held:
            s.close()
    finally:
        proc.terminate()
        await proc.wait()
    text = "".join(await log)
    return {"connections_held": len(held), "threads_before": threads0, "threads": threads,
            "status_answered": f"{sum(served)} of {len(served)}",
            "log_bytes": len(text), "tracebacks": text.count("Traceback")}


async def frames(args: argparse.Namespace, tmp: Path) -> dict[str, object]:
    proc, log = await spawn(args.checkout, tmp, None)
    try:
        before = proc_status(proc.pid, "VmRSS")
        await asyncio.gather(*(_unfinished(tmp / "hostd.sock", args.frame_mb)
                               for _ in range(args.frames)))
        peak = proc_status(proc.pid, "VmHWM")
    finally:
        proc.terminate()
        await proc.wait()
    await log
    return {"rss_before_mb": round(before / 1024, 1), "rss_peak_mb": round(peak / 1024, 1)}


async def _unfinished(sock: Path, mb: int) -> None:
    _, w = await asyncio.open_unix_connection(str(sock))
    chunk = b"x" * (1 << 20)
    with contextlib.suppress(ConnectionError):
        for _ in range(mb):
            w.write(chunk)
            await w.drain()
    w.close()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkout", type=Path, default=ROOT, metavar="DIR")
    ap.add_argument("--idle", type=int, default=1000)
    ap.add_argument("--hold", type=float, default=30.0)
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--frame-mb", type=int, default=80)
    args = ap.parse_args()
    for name, run in (("idle", idle), ("frames", frames)):
        with tempfile.TemporaryDirectory(prefix="hostd-abuse-") as tmp:
            print(name, json.dumps(asyncio.run(run(args, Path(tmp)))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
