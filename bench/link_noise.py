"""The link on a noisy line: hostd's window and ping-pong modes against Printrun's printcore, on
OctoPrint's virtual printer with a share of the host's lines corrupted (one bit flipped in the
checksummed part: ``bench/virtual_printer.py``).

Each host streams the same job, ``G91`` and N relative extrusions ``G1 E1 F60000``, to a new
virtual printer behind a pseudo-terminal (opened as a serial port: printcore numbers and
checksums lines only on one; its default 64-byte receive buffer and 4-slot queue; each way paced
as a wire of ``--baud``, 10 bits a byte) with the same seeded noise, and prints lines/s, the
lines corrupted, resends and the ``ok`` timeouts hostd waited out. Every run is checked: the
printer's E at the end must be N (each line executed exactly once: a line lost or run twice
moves it), else the bench stops (printcore's run is only marked: it loses lines on this
emulator).

Runs in the OctoPrint venv (``make test-octoprint`` builds it; printcore needs
``.venv-octoprint/bin/pip install printrun`` too):
``PYTHONPATH=. .venv-octoprint/bin/python bench/link_noise.py [--lines N] [--noise 0.01]
[--seed S] [--repeat R] [--baud 115200] [--hosts window,pingpong,printcore]``.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import re
import sys
import threading
import time
from typing import Any

from bench.virtual_printer import Noise, serve_pty
from hostd.link import LinkSettings, SerialLink
from hostd.link.replies import Position

RX_BUFFER = 64  # the virtual printer's default receive buffer
BAUD = 115200  # the port's nominal rate; the wire's pace is --baud
VIRTUAL = {"simulateReset": False, "simulated_errors": []}
"""No reset at connection, and none of the errors the virtual printer makes by default at
lines 100-115 (among them one that loses a line): the noise is the only fault."""
_E = re.compile(r"E:?(-?[0-9.]+)")


def job(n: int) -> list[str]:
    return ["G91", *(["G1 E1 F60000"] * n), "M400"]  # M400: E counts every move done


async def run_hostd(mode: str, n: int, share: float, seed: int, baud: int) -> dict[str, Any]:
    """Stream the job with hostd's link in ``mode``; its figures."""
    noise = Noise(share, seed)
    path, close = serve_pty(VIRTUAL, noise, baud)
    link = SerialLink(LinkSettings(port=path, baud=BAUD, flow_control=mode,
                                   rx_buffer_bytes=RX_BUFFER))
    await link.connect()
    try:
        t0 = time.perf_counter()
        acked = [i async for i in link.stream(job(n))]
        wall = time.perf_counter() - t0
        pos = await link.query("M114")
        status = link.status()
    finally:
        await link.close()
        close()
    e = pos.axes.get("E") if isinstance(pos, Position) else None
    return {"host": f"hostd {mode}", "wall": wall, "lines_s": n / wall, "e": e,
            "acked": len(acked), "corrupted": noise.corrupted, "resent": status["lines_resent"],
            "timeouts": status["timeouts"]}


def run_printcore(n: int, share: float, seed: int, baud: int) -> dict[str, Any]:
    """Stream the job with Printrun's printcore (its own threads); its figures."""
    from printrun import gcoder
    from printrun.printcore import printcore

    noise = Noise(share, seed)
    path, close = serve_pty(VIRTUAL, noise, baud)
    online, done, position = threading.Event(), threading.Event(), threading.Event()
    replies: list[str] = []
    core = printcore()
    core.onlinecb = online.set
    core.endcb = done.set
    resends = [0]

    def received(line: str) -> None:
        if line.lower().startswith("resend"):
            resends[0] += 1
        if line.startswith("X:") or " E:" in line:
            replies.append(line)
            position.set()

    core.recvcb = received
    core.connect(path, BAUD)
    try:
        if not online.wait(30):
            sys.exit("link_noise: printcore did not come online")
        t0 = time.perf_counter()
        core.startprint(gcoder.LightGCode(job(n)))
        if not done.wait(600):
            sys.exit("link_noise: printcore did not finish")
        wall = time.perf_counter() - t0
        core.send_now("M114")
        position.wait(10)
    finally:
        core.disconnect()
        close()
    found = _E.search(replies[-1]) if replies else None
    return {"host": "printcore", "wall": wall, "lines_s": n / wall,
            "e": float(found[1]) if found else None, "acked": n,
            "corrupted": noise.corrupted, "resent": resends[0], "timeouts": 0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lines", type=int, default=3000)
    ap.add_argument("--noise", type=float, default=0.01)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--baud", type=int, default=115200, help="the wire's pace (0: none)")
    ap.add_argument("--hosts", default="window,pingpong,printcore")
    args = ap.parse_args()
    print(f"{args.lines} lines, {args.noise:.1%} of them corrupted (seed {args.seed}+run), "
          f"wire at {args.baud} baud")
    print(f"{'host':18} {'lines/s':>8} {'wall s':>7} {'corrupt':>7} {'resends':>7} "
          f"{'timeouts':>8}")
    for run in range(args.repeat):
        for host in args.hosts.split(","):
            seed = args.seed + run
            if host == "printcore":
                r = run_printcore(args.lines, args.noise, seed, args.baud)
            else:
                r = asyncio.run(run_hostd(host, args.lines, args.noise, seed, args.baud))
            wrong = r["e"] is None or abs(r["e"] - args.lines) > 1e-6
            if wrong and host != "printcore":
                sys.exit(f"link_noise: {r['host']} ended at E {r['e']}, not {args.lines}: a "
                         "line was lost or executed twice")
            note = f"  E {r['e']}, not {args.lines}: lines lost or run twice" if wrong else ""
            print(f"{r['host']:18} {r['lines_s']:8.1f} {r['wall']:7.2f} {r['corrupted']:7d} "
                  f"{r['resent']:7d} {r['timeouts']:8d}{note}")
    sys.stdout.flush()
    # printcore leaves a non-daemon reader thread blocked on the closed pty: without this the
    # interpreter waits for it forever after the last figure
    os._exit(0)


if __name__ == "__main__":
    main()
