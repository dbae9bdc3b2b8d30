"""What lost ``ok`` s cost a stream: wall time, stalls, timeouts and nudges.

A plain ``ok`` lost on the wire leaves the host counting one line more in flight than there
is, so its byte credit of the firmware's receive buffer shrinks by that line. For each
``lost_ok_prob`` this streams a job of synthetic five-axis lines (~65 bytes, every axis:
``bench/stream.py``'s worst case) through ``SerialLink`` to the in-process emulator
(``sim://``, wire throttled to baud/10 bytes/s, planner as fast as possible, so the wire is
the bottleneck) and prints: the ``ok`` s the emulator dropped, wall time, lines/s, the
``serial.ok_timeout`` s (each a stall of that long), the starve nudges
(``serial.starve_timeout``), resent lines and the longest wait between two acknowledgement
batches of the stream. The board's executed log is checked: every line once, in order.

Run: ``.venv/bin/python bench/lost_ok.py [--lines N] [--baud B] [--seed S]
[--probs 0,0.001,0.01] [--starve-timeout S]`` (the link's default unless given).
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import time

from stream import five_axis_job  # bench/stream.py: the script's directory is on sys.path

from hostd.link import LinkSettings, SerialLink
from hostd.sim.settings import SimSettings

HOST_OWN = {"M105", "M110", "M115"}  # the link's own commands: nudges, handshake, M115


async def run(prob: float, lines: list[str], baud: int, seed: int,
              starve: float | None) -> dict[str, float]:
    """Stream ``lines`` once with ``prob`` of each ``ok`` lost; return the figures."""
    sim = SimSettings(baud=baud, throttle=True, lost_ok_prob=prob, seed=seed)
    extra = {} if starve is None else {"starve_timeout": starve}
    link = SerialLink(LinkSettings(port="sim://", baud=baud, **extra), sim)
    await link.connect()
    try:
        assert link.connection is not None and link.connection.emulator is not None
        firmware = link.connection.emulator.firmware
        t0 = last = time.perf_counter()
        gap = 0.0
        async for _ in link.stream(lines):
            now = time.perf_counter()
            gap, last = max(gap, now - last), now
        wall = time.perf_counter() - t0
        status = link.status()
    finally:
        await link.close()
    done = [c for n, c in firmware.log if n and c.split()[0] not in HOST_OWN]
    if done != lines:
        sys.exit(f"lost_ok: the board executed {len(done)} of {len(lines)} lines, or not in "
                 "order: something was lost or repeated")
    return {"lost": firmware.faults.lost_oks, "wall": wall, "lines_s": len(lines) / wall,
            "timeouts": status["timeouts"], "starve": status.get("starve_nudges", 0),
            "resent": status["lines_resent"], "gap": gap}


async def main(n: int, baud: int, seed: int, probs: list[float],
               starve: float | None) -> None:
    lines = five_axis_job(n)
    # (getattr: the same bench also runs a checkout from before the setting)
    timeout = getattr(LinkSettings(), "starve_timeout", "none") if starve is None else starve
    print(f"{n} five-axis lines, {baud} baud throttled, sim://, seed {seed}, "
          f"starve_timeout {timeout}")
    print(f"{'lost_ok_prob':>12} {'oks lost':>8} {'wall s':>7} {'lines/s':>7} "
          f"{'timeouts':>8} {'starve':>6} {'resent':>6} {'longest wait s':>14}")
    for prob in probs:
        r = await run(prob, lines, baud, seed, starve)
        print(f"{prob:>12g} {r['lost']:>8.0f} {r['wall']:>7.1f} {r['lines_s']:>7.0f} "
              f"{r['timeouts']:>8.0f} {r['starve']:>6.0f} {r['resent']:>6.0f} "
              f"{r['gap']:>14.2f}", flush=True)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--lines", type=int, default=3000)
    parser.add_argument("--baud", type=int, default=250000)
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--probs", default="0,0.001,0.01",
                        help="comma-separated lost_ok_prob values")
    parser.add_argument("--starve-timeout", type=float, default=None,
                        help="serial.starve_timeout (0: off); the link's default if not given")
    args = parser.parse_args()
    asyncio.run(main(args.lines, args.baud, args.seed,
                     [float(p) for p in args.probs.split(",")], args.starve_timeout))
