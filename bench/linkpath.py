"""The daemon's Python work per streamed line, without a port: link shell, protocol, streamer.

Run: ``.venv/bin/python bench/linkpath.py [--layers N] [--by-function]``, or
``bench/linkpath.py --base CHECKOUT [--rounds 10]`` to compare the cold figure of another
version of this repository (e.g. made by ``git worktree add /tmp/base <commit>``) with this
one's, the two run alternately, each in a fresh process.

A fake port answers the complete lines of each write with one ``ok`` each, handed over
together on a later loop turn (as the ``ok`` that one read of a real port finds: about two at
250000 baud with the read hold, ``bench/daemon.py``'s ``acked_lines_per_read``; ``--per-read
1`` hands each ``ok`` over on a turn of its own); the modal state is read whenever 30 more
lines are acknowledged, as a status poll at 20 Hz does at 250000 baud. Printed:

- ``bytecodes_per_line``: Python bytecodes executed per line (a trace count, the same on
  every run and every machine: it moves only when the code does);
- ``distinct_bytecodes_per_read``: the bytecodes (code object and offset) a read runs, each
  counted once per read however often it runs (the same on every run). On a cold CPU an
  instruction costs most the first time a wake-up runs it, so this is the count that should
  follow the live figure. On 2026-12-03 the live figure rose with the straight-line work
  that three patches added per read (judged with ``bench/ab_daemon.py --together``), and a
  change that cut an eighth of the bytecodes per line but left this count nearly as it was
  (1407 against 1423) did not move it: this is the count to cut. A guide, not a measure;
- ``warm_us_per_line``: wall microseconds per line, the best of three runs, the replies
  handed over as soon as the loop turns;
- ``cold_cpu_us_per_line``: CPU microseconds per line (the process's) when the replies come
  as the live daemon's held reads find them, ``per_read`` every 3.5 ms (``--gap``). Between
  two reads the process sleeps and its caches go cold, on this VM as in the daemon: the same
  code then costs several times the warm figure, and this is the one that tracks
  :mod:`daemon`'s live CPU (without its port, emulator and clients). It is measured on fewer
  lines (``--cold-layers``) and drifts with the VM's spells: compare versions with
  ``--base``.

These are for comparing versions, not for the target (:mod:`daemon` has the live figure).
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from types import FrameType
from typing import Any

HERE = Path(__file__).resolve()
ROOT = Path(sys.argv[sys.argv.index("--root") + 1]).resolve() if "--root" in sys.argv \
    else HERE.parents[1]  # the checkout whose daemon code is measured
# that checkout's own bench/daemon.py, which puts its checkout first on the path: this
# file's neighbour would put this checkout there, and every hostd import would come from it
sys.path[:0] = [str(ROOT / "bench"), str(ROOT)]

from daemon import synthetic_gcode  # noqa: E402

from hostd.config.loader import defaults  # noqa: E402
from hostd.daemon import LinkPort  # noqa: E402
from hostd.link.link import SerialLink  # noqa: E402
from hostd.link.settings import link_settings_from_config  # noqa: E402
from hostd.link.transport import Connection, LineReceiver  # noqa: E402
from hostd.printer.program import parse_program  # noqa: E402
from hostd.printer.settings import stream_settings_from_config  # noqa: E402
from hostd.printer.streamer import Hooks, Streamer  # noqa: E402

if not Path(sys.modules["hostd"].__file__ or "").resolve().is_relative_to(ROOT):
    raise SystemExit(f"hostd was imported from {sys.modules['hostd'].__file__}, not {ROOT}")

STATUS_EVERY = 30  # lines between two reads of the modal state (20 Hz at ~600 lines/s)


class AnsweringTransport:
    """Takes the link's bytes; every complete line earns one ``ok``, handed over on a later
    loop turn ``per_read`` at a time (or after a millisecond, when fewer are due)."""

    def __init__(self, receiver: LineReceiver, loop: asyncio.AbstractEventLoop,
                 per_read: int) -> None:
        self.receiver, self.loop, self.per_read = receiver, loop, per_read
        self.partial = b""
        self.due = 0  # oks earned and not handed over
        self.late: asyncio.TimerHandle | None = None
        self.closing = False

    def write(self, data: bytes) -> None:
        *lines, self.partial = (self.partial + data).split(b"\n")
        self.due += len(lines)
        if self.due >= self.per_read:
            self.loop.call_soon(self.receiver.data_received, b"ok\n" * self.due)
            self.due = 0
        elif self.due and self.late is None:
            self.late = self.loop.call_later(0.001, self.hand_over)

    def hand_over(self) -> None:
        self.late = None
        if self.due:
            self.receiver.data_received(b"ok\n" * self.due)
            self.due = 0

    def is_closing(self) -> bool:
        return self.closing

    def close(self) -> None:
        self.closing = True


class PacedTransport(AnsweringTransport):
    """The wire at a pace: every ``gap`` seconds, up to ``per_read`` of the ``ok`` due are
    handed over, as the live daemon's held reads find them."""

    def __init__(self, receiver: LineReceiver, loop: asyncio.AbstractEventLoop,
                 per_read: int, gap: float) -> None:
        super().__init__(receiver, loop, per_read)
        self.gap = gap
        self.tick = loop.call_later(gap, self.hand_over)

    def write(self, data: bytes) -> None:
        *lines, self.partial = (self.partial + data).split(b"\n")
        self.due += len(lines)

    def hand_over(self) -> None:
        if self.closing:
            return
        count = min(self.due, self.per_read)
        if count:
            self.due -= count
            self.receiver.data_received(b"ok\n" * count)
        self.tick = self.loop.call_later(self.gap, self.hand_over)


async def stream(text: str, per_read: int, tracer: Callable[..., Any] | None = None,
                 gap: float = 0.0) -> tuple[float, int]:
    """Stream ``text`` through the real link and streamer: (seconds, lines). With ``gap``,
    the replies come at the pace of :class:`PacedTransport`."""
    cfg = defaults()
    loop = asyncio.get_running_loop()

    async def opener(*_: object) -> Connection:
        receiver = LineReceiver()
        port = (PacedTransport(receiver, loop, per_read, gap) if gap
                else AnsweringTransport(receiver, loop, per_read))
        return Connection(port, receiver)  # type: ignore[arg-type]

    link = SerialLink(link_settings_from_config(cfg), opener=opener)
    await link.connect()
    program = parse_program(text)

    polled = [0]  # acknowledged lines at the last status poll

    def progress(st: Streamer) -> None:  # called once per acknowledged batch of lines
        if st.acked - polled[0] >= STATUS_EVERY:
            polled[0] = st.acked
            st.modal  # noqa: B018  (a status poll brings the modal state up to date)

    streamer = Streamer(LinkPort(link), program, stream_settings_from_config(cfg),
                        Hooks(progress=progress))
    if tracer is not None:
        sys.settrace(tracer)
    t0 = time.perf_counter()
    try:
        await streamer.run()
    finally:
        sys.settrace(None)
    seconds = time.perf_counter() - t0
    await link.close()
    return seconds, program.total


def count_bytecodes(text: str, per_read: int) -> tuple[Counter[str], int]:
    """Bytecodes executed while streaming ``text``, by function; and the line count."""
    counts: Counter[str] = Counter()

    def tracer(frame: FrameType, event: str, arg: object) -> Callable[..., Any]:
        frame.f_trace_opcodes = True
        if event == "opcode":
            code = frame.f_code
            counts[f"{Path(code.co_filename).name}:{code.co_name}"] += 1
        return tracer

    _, lines = asyncio.run(stream(text, per_read, tracer))
    return counts, lines


def footprint_per_read(text: str, per_read: int) -> tuple[float, dict[str, float]]:
    """Distinct bytecodes (code object and offset) executed per read, on average, and that
    mean by function.

    A read here is everything from one ``data_received`` of the port's replies to the next:
    the link, the protocol, the streamer when its batch is acknowledged, the loop's own
    Python. On a cold CPU an instruction costs most the first time a wake-up runs it, and
    little when a loop runs it again: this counts each once per read.
    """
    reads: list[set[tuple[int, int]]] = [set()]
    start = LineReceiver.data_received.__code__
    codes: dict[int, str] = {}

    def tracer(frame: FrameType, event: str, arg: object) -> Callable[..., Any]:
        frame.f_trace_opcodes = True
        code = frame.f_code
        if event == "call" and code is start:
            reads.append(set())
        elif event == "opcode":
            reads[-1].add((id(code), frame.f_lasti))
            codes.setdefault(id(code), f"{Path(code.co_filename).name}:{code.co_name}")
        return tracer

    asyncio.run(stream(text, per_read, tracer))
    counted = reads[2:-1]  # not the connection, the first read or the end of the stream
    by_function = Counter(codes[c] for sites in counted for c, _ in sites)
    mean = {name: n / len(counted) for name, n in by_function.most_common()}
    return sum(map(len, counted)) / len(counted), mean


def cold_us_per_line(text: str, per_read: int, gap: float) -> float:
    """Process CPU microseconds per line, the replies paced by ``gap``."""
    cpu = time.process_time()
    _, lines = asyncio.run(stream(text, per_read, gap=gap))
    return 1e6 * (time.process_time() - cpu) / lines


def compare(base: Path, rounds: int, args: argparse.Namespace) -> int:
    """The cold figure of ``base`` and of this checkout, alternately, in fresh processes."""
    figures: dict[str, list[float]] = {"base": [], "this": []}
    order = [("base", base), ("this", HERE.parents[1])]
    for k in range(rounds):
        for tag, checkout in order if k % 2 == 0 else order[::-1]:
            out = subprocess.run(
                [sys.executable, str(HERE), "--cold-only", "--root", str(checkout),
                 "--per-read", str(args.per_read), "--gap", str(args.gap),
                 "--cold-layers", str(args.cold_layers)],
                capture_output=True, text=True, check=True).stdout
            figures[tag].append(float(out.split()[-1]))
            print(f"{tag:>5} cold_cpu_us_per_line {figures[tag][-1]:8.2f}", flush=True)
    for tag, values in figures.items():
        print(f"{tag:>5} mean {statistics.mean(values):8.2f} "
              f"median {statistics.median(values):8.2f}")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--layers", type=int, default=40, help="layers of 200 lines (default 40)")
    ap.add_argument("--by-function", action="store_true", help="the 25 costliest functions")
    ap.add_argument("--per-read", type=int, default=2,
                    help="replies handed over together (default 2, as the live daemon reads)")
    ap.add_argument("--gap", type=float, default=0.0035,
                    help="seconds between two reads for the cold figure (default 0.0035)")
    ap.add_argument("--cold-layers", type=int, default=10,
                    help="layers of 200 lines for the cold figure (default 10)")
    ap.add_argument("--cold-only", action="store_true", help="print the cold figure alone")
    ap.add_argument("--root", type=Path, help="measure the daemon code of this checkout")
    ap.add_argument("--base", type=Path, help="compare the cold figure with this checkout")
    ap.add_argument("--rounds", type=int, default=10, help="rounds of --base (default 10)")
    args = ap.parse_args()
    if args.base is not None:
        return compare(args.base, args.rounds, args)
    cold_text = synthetic_gcode(subparts=1, layers=args.cold_layers, per_layer=200)
    if args.cold_only:
        print(f"{cold_us_per_line(cold_text, args.per_read, args.gap):.3f}")
        return 0
    text = synthetic_gcode(subparts=1, layers=args.layers, per_layer=200)
    runs = [asyncio.run(stream(text, args.per_read)) for _ in range(3)]
    lines = runs[0][1]
    counts, _ = count_bytecodes(text, args.per_read)
    footprint, sites = footprint_per_read(text, args.per_read)
    cold = cold_us_per_line(cold_text, args.per_read, args.gap)
    print(f"linkpath bench: {lines} lines, one ok each, {args.per_read} per read, no port")
    print(f"{'bytecodes_per_line':28} {sum(counts.values()) / lines:10.1f}")
    print(f"{'distinct_bytecodes_per_read':28} {footprint:10.1f}")
    print(f"{'warm_us_per_line':28} {1e6 * min(s for s, _ in runs) / lines:10.2f}")
    print(f"{'cold_cpu_us_per_line':28} {cold:10.2f}")
    if args.by_function:
        for name, n in counts.most_common(25):
            print(f"  {n / lines:8.1f}  {name}")
        print("distinct bytecodes per read, by function:")
        for name, n in list(sites.items())[:25]:
            print(f"  {n:8.1f}  {name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
