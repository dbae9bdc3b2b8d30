"""hostctl verbs that talk to the daemon: print, status, jobs, job, pause, resume, cancel,
send, estop, firmware-restart, watch.

Exit codes (see :mod:`hostd.cli.errors`): 0 ok, 1 the job failed/was cancelled/interrupted,
2 bad arguments or input file, 3 daemon unreachable, 4 the daemon refused the request.
"""

from __future__ import annotations

import argparse
import base64
import json
import re
import shlex
import stat
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hostd.cli.client import Client, RpcFailure, socket_path
from hostd.cli.errors import (
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_REFUSED,
    EXIT_UNREACHABLE,
    EXIT_USAGE,
    CliError,
)
from hostd.cli.options import add_allow_overhang, add_decompose_options, decompose_overrides
from hostd.cli.text import event_text, printable

FINAL = {"completed", "failed", "cancelled", "interrupted"}
PART_BYTES = 3 << 16
"""Bytes of a file a message carries when it is sent in parts (256 KiB of base64)."""
SUBMIT_TIMEOUT = 600.0
"""Seconds ``job.submit`` may take: the daemon checks the whole file (parses a G-code)
before it answers, which for the largest files on a Pi takes far more than a plain call."""
JOBS_SHOWN = 20
"""Jobs ``hostctl jobs`` lists unless ``--limit`` says: the newest."""


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser("print", help="upload FILE (STL, 3MF, OBJ or G-code) and print "
                              "it")
    p.add_argument("file", help="the STL, 3MF, OBJ or G-code file to print")
    p.add_argument("--wait", action="store_true", help="show progress until the job ends")
    p.add_argument("--kind", choices=("stl", "3mf", "obj", "gcode"),
                   help="what FILE is, when its extension does not say (.stl, .3mf, .obj, "
                        ".gcode)")
    add_decompose_options(p)
    add_allow_overhang(p, "a part: print it")
    _json_flag(p, "the job (with --wait: as job.get gives it, once the job ended)")
    p.set_defaults(func=cmd_print)

    p = subparsers.add_parser("status", help="printer and current job")
    _json_flag(p, "printer.status's snapshot of every component")
    p.set_defaults(func=cmd_status)

    p = subparsers.add_parser("jobs", help="the job list (the newest jobs)")
    _json_flag(p, "job.list's {jobs, total} (total: every job, also those not shown)")
    p.add_argument("--limit", type=_count, default=JOBS_SHOWN, metavar="N",
                   help=f"show the newest N jobs (default {JOBS_SHOWN}; 0: all)")
    p.set_defaults(func=cmd_jobs)

    p = subparsers.add_parser("job", help="one job whole: its figures, end-of-job summary "
                              "and state history")
    p.add_argument("id", type=int, help="job id")
    _json_flag(p, "the job as job.get gives it (with history and checkpoints)")
    p.set_defaults(func=cmd_job)

    for verb, helptext in (("pause", "pause the current job"),
                           ("cancel", "cancel a job (default: the current one)")):
        p = subparsers.add_parser(verb, help=helptext)
        p.add_argument("id", nargs="?", type=int,
                       help="job id (default: the job on the printer)")
        _json_flag(p, "the job")
        p.set_defaults(func=cmd_job_verb, method=f"job.{verb}")

    p = subparsers.add_parser("resume", help="resume a paused or interrupted job")
    p.add_argument("id", nargs="?", type=int,
                   help="job id (default: the job on the printer, else the last paused or "
                        "interrupted one)")
    p.add_argument("--from", dest="scope", default=None,
                   choices=("layer", "subpart", "checkpoint"),
                   help="for an interrupted job: restart at the start of its layer (default), "
                        "of its sub-part, or at its last checkpoint (these two print again "
                        "the layers of the sub-part already done)")
    _json_flag(p, "the job")
    p.set_defaults(func=cmd_resume)

    p = subparsers.add_parser("send", help="send raw G-code lines")
    p.add_argument("gcode", nargs="+", metavar="GCODE",
                   help='one G-code line per argument: quote a command with its parameters '
                        '(hostctl send "M104 S200" M105)')
    _json_flag(p, "{commands, replies, errors}")
    p.set_defaults(func=cmd_send)

    p = subparsers.add_parser("delete", help="forget a finished job and its files")
    p.add_argument("id", type=int, help="job id (a finished job: not printing or paused)")
    _json_flag(p, "{deleted: ID}")
    p.set_defaults(func=cmd_delete)

    p = subparsers.add_parser("estop", help="emergency stop (M112)")
    _json_flag(p, "{stopped: true}")
    p.set_defaults(func=cmd_estop)
    p = subparsers.add_parser("firmware-restart",
                              help="reset the firmware and reconnect (after estop or a halt)")
    _json_flag(p, "{link}")
    p.set_defaults(func=cmd_firmware_restart)

    p = subparsers.add_parser("queue", help="show the queue hold, or start/hold the queue "
                              "(start: the platform is clear, the next job may print)")
    p.add_argument("action", nargs="?", choices=("start", "hold"),
                   help="start: the platform is clear, lift the hold; hold: start no new "
                        "job (default: show the hold)")
    _json_flag(p, "{held, reason, ready, next_job}")
    p.set_defaults(func=cmd_queue)

    p = subparsers.add_parser("watch", help="print the daemon's event stream")
    _json_flag(p, "each event as the daemon sends it, one per line,")
    p.set_defaults(func=cmd_watch)


def _json_flag(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument("--json", action="store_true",
                   help=f"print {what} as JSON on stdout (an error stays one line on stderr)")


def _client(args: argparse.Namespace, timeout: float | None = 30.0) -> Client:
    return Client(socket_path(getattr(args, "socket", None)), timeout)


def _emit_json(data: Any) -> None:
    print(json.dumps(data, indent=None, sort_keys=True))


def cmd_print(args: argparse.Namespace) -> int:
    path = Path(args.file)
    options = slice_options(args)
    size = _upload_size(path)
    with _client(args, timeout=600.0) as c:
        limit = c.call("server.info").get("max_upload_bytes")
        if isinstance(limit, int) and size > limit:  # before reading a file of any size
            raise CliError(f"{path}: {size} bytes exceeds the limit of {limit} bytes "
                           "(daemon.max_upload_bytes)", EXIT_USAGE)
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise CliError(f"{path}: {exc.strerror or exc}", EXIT_USAGE) from None
        if args.wait or _is_part(path, args.kind):  # events to follow: subscribed first
            c.call("events.subscribe", events=list(WAIT_EVENTS if args.wait else SLICE_EVENTS))
        job = _submit(c, path.name, data, None if args.json else _upload_progress(path.name),
                      kind=args.kind, options=options)
        if not args.wait:
            return _submitted(c, job, args.json)
        try:  # from here on the job exists: Ctrl-C leaves it printing, and says so
            if not args.json:
                _say_held(c)
            final, reason = _follow(c, job, args.json)
            if args.json:
                _emit_final(c, job["id"], final, reason)
            else:
                _show_end(c, job["id"], final, reason)
        except KeyboardInterrupt:
            raise CliError(f"interrupted: job {job['id']} goes on (hostctl watch follows it; "
                           f"hostctl cancel {job['id']} stops it)", EXIT_INTERRUPTED) from None
    return EXIT_OK


SLICE_EVENTS = ("job.state", "job.slicing")
"""What ``print`` without ``--wait`` follows: the slice of a part, to its outcome."""
WAIT_EVENTS = (*SLICE_EVENTS, "job.progress", "job.subpart", "subpart_started",
               "transition_failed", "queue.state")
"""What ``print --wait`` follows."""
SLICED = frozenset({"ready", "printing", "paused", "completed"})
"""States a job is in once its slice has succeeded."""


PART_SUFFIXES = frozenset({".stl", ".3mf", ".obj"})


def _is_part(path: Path, kind: str | None) -> bool:
    """Whether the file is a part the daemon slices (its slice is waited for)."""
    return kind != "gcode" if kind is not None else path.suffix.lower() in PART_SUFFIXES


def _submitted(c: Client, job: dict[str, Any], as_json: bool) -> int:
    """``print`` without ``--wait``: the job queued; a part's slice waited for, its stages
    shown on a terminal, and a failed one an error (exit 1, its reason on stderr)."""
    if job.get("kind") == "stl" and job["state"] in ("queued", "slicing"):
        try:
            job = {**job, **_await_slice(c, job)}
        except KeyboardInterrupt:
            raise CliError(f"interrupted: job {job['id']} is still queued (hostctl watch "
                           f"follows it; hostctl cancel {job['id']} stops it)",
                           EXIT_INTERRUPTED) from None
    if job["state"] not in SLICED | {"queued", "slicing"}:
        raise CliError(f"job {job['id']} {job['state']}: {job.get('reason') or ''}",
                       EXIT_FAILED)
    if as_json:
        _emit_json(job)
    else:
        print(f"job {job['id']} {job['state']}: {job['name']}")
        _say_held(c)
    return EXIT_OK


def _await_slice(c: Client, job: dict[str, Any]) -> dict[str, Any]:
    """Follow ``job``'s slice until it has a result: ``{state, reason}`` then."""
    show = SliceProgress(sys.stderr, str(job["name"]))
    for event, data in c.events():
        if data.get("job_id") != job["id"]:
            continue
        if event == "job.slicing":
            show.update(data)
        elif event == "job.state" and data["new"] not in ("queued", "slicing"):
            show.done()
            return {"state": data["new"], "reason": data.get("reason", "")}
    show.done()
    raise CliError(f"job {job['id']}: hostd closed the connection while it sliced",
                   EXIT_UNREACHABLE)


class SliceProgress:
    """``slicing part.stl: replay check (65%)`` on one line of a terminal (nothing when the
    output is no terminal)."""

    def __init__(self, out: Any, name: str) -> None:
        self.out = out
        self.tty = bool(getattr(out, "isatty", lambda: False)())
        self.name = name
        self.shown = False

    @staticmethod
    def text(name: str, data: dict[str, Any]) -> str:
        return f"slicing {printable(name)}: {data.get('stage')} ({data.get('percent', 0):.0f}%)"

    def update(self, data: dict[str, Any]) -> None:
        if self.tty:
            self.out.write("\r\033[K" + self.text(self.name, data))
            self.out.flush()
            self.shown = True

    def done(self) -> None:
        if self.shown:
            self.out.write("\r\033[K")
            self.out.flush()
            self.shown = False


def _show_end(c: Client, job_id: int, state: str, reason: str) -> None:
    """``print --wait`` once the job ended: its summary, or (not completed) the reason as
    an error (exit 1)."""
    if state != "completed":
        raise CliError(f"job {job_id} {state}: {reason}", EXIT_FAILED)
    try:
        job = c.call("job.get", id=job_id)
    except CliError:
        return  # hostd went away after the job ended: the summary is in hostctl job
    line = summary_text((job.get("info") or {}).get("summary"))
    if line:
        print(line, flush=True)


def summary_text(summary: dict[str, Any] | None) -> str:
    """``summary: 1234.5 mm of filament (3.71 g), 0:12:34, 3 sub-parts, 2 transitions,
    0 resends``, or ``""`` for a job without one."""
    if not summary:
        return ""
    mass = summary.get("mass_g")
    return (f"summary: {summary.get('filament_mm', 0):.1f} mm of filament"
            + ("" if mass is None else f" ({mass:.2f} g)")
            + f", {_hms(float(summary.get('time_s') or 0))}, "
            f"{summary.get('subparts', 0)} sub-parts, {summary.get('transitions', 0)} "
            f"transitions, {summary.get('resends', 0)} resends")


def slice_options(args: argparse.Namespace) -> dict[str, Any]:
    """``job.submit``'s slice parameters for the options given (none for the others)."""
    out: dict[str, Any] = dict(decompose_overrides(args))
    if args.allow_overhang:
        out["allow_overhang"] = True
    return out


def _emit_final(c: Client, job_id: int, state: str, reason: str) -> None:
    """``print --wait --json`` once the job ended: the job as ``job.get`` gives it on stdout;
    when it did not complete, :class:`CliError` (exit 1) with the text mode's last line."""
    ended = f"job {job_id} {state}: {reason}" + (
        f"; {_resume_hint(job_id)}" if state == "interrupted" else "")
    try:
        _emit_json(c.call("job.get", id=job_id))
    except CliError as exc:  # hostd stopped (the job interrupted) before it answered
        if state == "completed" or exc.code != EXIT_UNREACHABLE:
            raise
        raise CliError(f"{ended} ({exc})", EXIT_FAILED) from None
    if state != "completed":
        raise CliError(ended, EXIT_FAILED)


def _resume_hint(job_id: int) -> str:
    return f"resume it with: hostctl resume {job_id} [--from layer|subpart|checkpoint]"


def _upload_size(path: Path) -> int:
    """Size of the regular file at ``path``; :class:`CliError` (exit 2) naming it if it is
    missing, unreadable or not a regular file (a directory, a pipe, a device)."""
    try:
        st = path.stat()
    except OSError as exc:
        raise CliError(f"{path}: {exc.strerror or exc}", EXIT_USAGE) from None
    if not stat.S_ISREG(st.st_mode):
        raise CliError(f"{path}: not a regular file", EXIT_USAGE)
    return st.st_size


LINK_WAY_OUT = {"halted": ": hostctl firmware-restart brings it back",
                "disconnected": ": the job starts once the link is back (hostd reconnects)"}
"""What brings a link that is not ready back, by its state."""


def _say_held(c: Client) -> None:
    """A line for each reason the job will not start yet: the queue is held (a part on the
    platform, the operator), the printer is not ready (the link halted or down)."""
    queue = c.call("queue.status")
    if queue.get("held"):
        print(f"queue held: {queue.get('reason')}", flush=True)
    state = (c.call("printer.status").get("link") or {}).get("state", "?")
    if state != "ready":
        print(f"queue held: the printer is not ready (link {state})"
              f"{LINK_WAY_OUT.get(state, '')}", flush=True)


def _submit(c: Client, name: str, data: bytes,
            progress: Callable[[int, int], None] | None = None,
            kind: str | None = None, options: dict[str, Any] | None = None) -> dict[str, Any]:
    """Queue the file: in one ``job.submit``, or when it is larger than :data:`PART_BYTES` in
    parts (``job.upload``), so that no message holds the daemon's event loop long;
    ``progress(sent, total)`` after each part. ``options``: ``job.submit``'s slice
    parameters (``allow_overhang``, ``seed``, ``parts``)."""
    extra = options or {}
    if len(data) > PART_BYTES:
        view = memoryview(data)
        for offset in range(0, len(data), PART_BYTES):
            part = base64.b64encode(view[offset:offset + PART_BYTES]).decode()
            c.call("job.upload", data=part, offset=offset)
            if progress is not None:
                progress(min(offset + PART_BYTES, len(data)), len(data))
        return c.call("job.submit", timeout=SUBMIT_TIMEOUT, name=name, kind=kind, **extra)
    return c.call("job.submit", timeout=SUBMIT_TIMEOUT, name=name, kind=kind,
                  data=base64.b64encode(data).decode(), **extra)


def _upload_progress(name: str) -> Callable[[int, int], None] | None:
    """``uploading NAME: 42% of 27.2 MB`` on one line of a terminal's stderr (else nothing)."""
    if not sys.stderr.isatty():
        return None

    def show(sent: int, total: int) -> None:
        end = "\r\033[K" if sent == total else ""
        sys.stderr.write(f"\ruploading {name}: {100 * sent // total}% of {total / 1e6:.1f} MB"
                         + end)
        sys.stderr.flush()

    return show


def _follow(c: Client, job: dict[str, Any], quiet: bool) -> tuple[str, str]:
    """Follow the job's events until it ends: its final state and reason. Progress and
    state changes are shown on stdout unless ``quiet``."""
    job_id, state = job["id"], job["state"]
    bar = ProgressBar(sys.stdout, job_id, job["name"])
    bar.state = state
    if state in FINAL:
        return str(state), str(job.get("reason") or "")
    for event, data in c.events():
        if event == "queue.state":  # the job waits for the platform (or may go now)
            if data.get("held") and bar.state in ("queued", "slicing", "ready") and not quiet:
                bar.line_break(f"queue held: {data.get('reason')}")
            continue
        if data.get("job_id") != job_id:
            continue
        if event == "job.state":
            bar.state = data["new"]
            bar.reason = data.get("reason", "")
            if not quiet:
                bar.line_break(f"job {job_id} {data['new']}: {bar.reason}")
                if data["new"] == "interrupted":
                    bar.line_break(_resume_hint(job_id))
            if data["new"] in FINAL:
                return str(data["new"]), str(bar.reason or "")
        elif not quiet:
            _show_job_event(bar, event, data)
    return "interrupted", ""


def _show_job_event(bar: ProgressBar, event: str, data: dict[str, Any]) -> None:
    """A job event other than a state change, on the progress bar's terminal."""
    if event == "job.progress":
        bar.update(data)
    elif event == "job.slicing":
        bar.slicing(data)
    elif event == "subpart_started":
        bar.line_break(f"sub-part {data.get('subpart')} started at A {data.get('a')} "
                       f"C {data.get('c')} (checkpoint)")
    elif event == "transition_failed":
        bar.line_break(f"transition to sub-part {data.get('subpart')} failed: "
                       f"{data.get('reason')}")


class ProgressBar:
    """``[#####.....]  42.0% printing  sub-part 1  layer 7  ETA 0:03:12`` on one line."""

    WIDTH = 30

    def __init__(self, out: Any, job_id: int, name: str) -> None:
        self.out = out
        self.tty = bool(getattr(out, "isatty", lambda: False)())
        self.job_id, self.name = job_id, name
        self.state, self.reason = "queued", ""
        self.last_pct = -10.0

    def render(self, p: dict[str, Any]) -> str:
        ratio = float(p.get("progress") or 0.0)
        filled = int(ratio * self.WIDTH)
        eta = p.get("eta_s")
        eta_s = "--:--" if eta is None else _hms(float(eta))
        return (f"[{'#' * filled}{'.' * (self.WIDTH - filled)}] {ratio * 100:5.1f}% "
                f"{self.state:<9} sub-part {_or_dash(p.get('subpart'))} "
                f"layer {_or_dash(p.get('layer'))} "
                f"ETA {eta_s}")

    def update(self, p: dict[str, Any]) -> None:
        text = self.render(p)
        pct = float(p.get("progress") or 0.0) * 100
        if self.tty:
            self.out.write("\r" + text)
            self.out.flush()
        elif pct - self.last_pct >= 10 or pct >= 100:
            self.last_pct = pct
            print(text, file=self.out, flush=True)

    def slicing(self, data: dict[str, Any]) -> None:
        """A slice's stage: on the bar's line of a terminal, else a line of its own."""
        text = SliceProgress.text(self.name, data)
        if self.tty:
            self.out.write("\r\033[K" + text)
            self.out.flush()
        else:
            print(text, file=self.out, flush=True)

    def line_break(self, text: str) -> None:
        if self.tty:
            self.out.write("\r\033[K")
        print(text, file=self.out, flush=True)


def _or_dash(value: Any) -> str:
    """A sub-part or layer number, ``-`` before the first (the start script runs)."""
    return "-" if value is None else str(value)


def _hms(seconds: float) -> str:
    s = max(0, int(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


LINK_TROUBLE = (("timeouts", "ok timeout"), ("resend_requests", "resend request"),
                ("checksum_errors", "checksum error"), ("resets", "firmware reset"),
                ("reconnects", "reconnect"))


def link_trouble(link: dict[str, Any]) -> str:
    """``2 ok timeouts, 1 resend request``: the link's non-zero trouble counters, or ``""``."""
    counts = [(int(link.get(key) or 0), name) for key, name in LINK_TROUBLE]
    return ", ".join(f"{n} {name}{'s' if n > 1 else ''}" for n, name in counts if n)


def cmd_status(args: argparse.Namespace) -> int:
    with _client(args) as c:
        snap = c.call("printer.status")
    if args.json:
        _emit_json(snap)
        return EXIT_OK
    link = snap.get("link", {})
    jobs = snap.get("jobs", {})
    print(f"printer: {snap['daemon']['info'].get('machine')}  link: "
          f"{link.get('state', '?')}  port: {link.get('port')}")
    trouble = link_trouble(link)
    if trouble:
        print(f"  link trouble since hostd started: {trouble}")
    for name, t in (link.get("temperatures") or {}).items():
        print(f"  {name}: {t.get('actual')} / {t.get('target')} °C")
    cur = jobs.get("current")
    if cur:
        eta = cur.get("remaining_s")
        print(f"job {cur['id']} {cur['state']}: {printable(cur['info']['name'])}  "
              f"{cur['progress'] * 100:.1f}%  sub-part {_or_dash(cur['subpart'])}  layer "
              f"{_or_dash(cur['layer'])}  ETA {'--' if eta is None else _hms(eta)}")
        if cur.get("pause_reason"):
            print(f"  paused: {cur['pause_reason']}")
    else:
        print("no job printing")
        _print_last(jobs.get("latest"))
    print(f"queue: {jobs.get('queue_length', 0)} waiting")
    queue = jobs.get("queue") or {}
    if queue.get("held"):
        print(f"  held: {queue.get('reason')}")
    if jobs.get("waiting_for_printer"):
        print(f"  held: the printer is not ready (link {link.get('state', '?')})")
    if link.get("state") == "halted":
        print("the board is halted (estop, a firmware kill or a link too noisy): "
              "hostctl firmware-restart brings it back")
    return EXIT_OK


def _print_last(last: dict[str, Any] | None) -> None:
    """The last job that printed, when it needs the operator (interrupted or failed)."""
    if not last or last.get("state") not in ("interrupted", "failed"):
        return
    print(f"last job {last['id']} {last['state']} at line {last['acked']}/{last['total']}"
          f" (sub-part {_or_dash(last['subpart'])}, layer {_or_dash(last['layer'])})")
    if last["state"] == "interrupted":
        print(f"  resume: hostctl resume {last['id']} [--from layer|subpart|checkpoint]")


def _count(text: str) -> int:
    """An argparse type: a whole number ≥ 0."""
    if not text.isdigit():
        raise argparse.ArgumentTypeError(f"expected a whole number ≥ 0, got {text!r}")
    return int(text)


def cmd_jobs(args: argparse.Namespace) -> int:
    with _client(args) as c:
        listed = c.call("job.list", limit=args.limit)
    if args.json:
        _emit_json(listed)  # {jobs, total}: how many were left out, too
        return EXIT_OK
    jobs = listed["jobs"]
    if not jobs:
        print("no jobs")
    older = listed.get("total", len(jobs)) - len(jobs)
    if older > 0:
        print(f"({older} older jobs not shown: hostctl jobs --limit 0 lists them all)")
    for j in jobs:
        print(f"{j['id']:>4}  {j['state']:<11} {j['progress'] * 100:5.1f}%  "
              f"line {j['acked_lines']}/{j['total_lines']}  {printable(j['name'])}"
              + _slice_flags(j)
              + (f"  ({printable(j['reason'])})" if j.get("reason") else ""))
    return EXIT_OK


def _slice_flags(job: dict[str, Any]) -> str:
    """``  [--allow-overhang --seed 3]``: the slice options a job was submitted with."""
    flags = (["--allow-overhang"] if job.get("allow_overhang") else []) + [
        f"--{k} {v}" for k, v in sorted((job.get("slice_options") or {}).items())]
    return f"  [{' '.join(flags)}]" if flags else ""


def cmd_job(args: argparse.Namespace) -> int:
    with _client(args) as c:
        job = c.call("job.get", id=args.id)
    if args.json:
        _emit_json(job)
        return EXIT_OK
    for line in job_lines(job):
        print(line)
    return EXIT_OK


def job_lines(job: dict[str, Any]) -> list[str]:
    """``hostctl job N``: the job whole, a line a fact, then its state history."""
    info = job.get("info") or {}
    est = job.get("estimate") or {}
    lines = [f"job {job['id']} {job['state']}: {printable(job['name'])}"
             + (f" ({printable(job['reason'])})" if job.get("reason") else ""),
             f"  file: {info.get('format', job['kind'])}, {job['total_lines']} G-code lines"
             + (f", sliced in {info['slice_s']:.1f} s" if "slice_s" in info else ""),
             f"  progress: {job['progress'] * 100:.1f}% (line {job['acked_lines']}/"
             f"{job['total_lines']}, sub-part {_or_dash(job.get('subpart'))}, layer "
             f"{_or_dash(job.get('layer'))})"]
    if est.get("time_s") is not None:
        lines.append(f"  estimate: {float(est.get('filament_mm') or 0):.1f} mm of filament, "
                     f"{_hms(float(est['time_s']))}")
    summary = summary_text(info.get("summary"))
    if summary:
        lines.append(f"  {summary}")
    lines.append("  history:")
    for h in job.get("history") or []:
        lines.append(f"    {_when(h.get('at'))}  {h.get('old') or 'new'} -> {h['new']}"
                     + (f"  ({printable(h['reason'])})" if h.get("reason") else ""))
    return lines


def _when(at: Any) -> str:
    """A Unix time as local ``YYYY-MM-DD HH:MM:SS``."""
    return "-" if at is None else time.strftime("%Y-%m-%d %H:%M:%S",
                                                time.localtime(float(at)))


def _show_job(job: dict[str, Any], as_json: bool) -> None:
    if as_json:
        _emit_json(job)
    else:
        print(f"job {job['id']} {job['state']}" + (f": {job['reason']}" if job.get("reason")
                                                  else ""))


def cmd_job_verb(args: argparse.Namespace) -> int:
    with _client(args, timeout=600.0) as c:
        job = c.call(args.method, timeout=600.0, id=args.id)
    _show_job(job, args.json)
    return EXIT_OK


def cmd_resume(args: argparse.Namespace) -> int:
    with _client(args) as c:
        job = c.call("job.resume", id=args.id, **{"from": args.scope})
    _show_job(job, args.json)
    return EXIT_OK


PARAMETER = re.compile(r"[A-FH-LO-SU-Z]([-+]?(\d+\.?\d*|\.\d+))?", re.IGNORECASE)
"""A word that is a command's parameter (``S200``, ``X``), not a command: any letter but
G, M, T (a tool change) and N (a line number), and a number or none."""
TOOL = re.compile(r"T\d+", re.IGNORECASE)
"""A tool change, or the tool parameter of an M-code (``M104 T0 S200``)."""
NOT_GCODE = "is not a G-code command"
"""How the daemon refuses a line that does not start with a command."""


def cmd_send(args: argparse.Namespace) -> int:
    try:
        with _client(args, timeout=600.0) as c:
            res = c.call("printer.gcode", timeout=600.0, script="\n".join(args.gcode))
    except RpcFailure as exc:
        hint = _quoting_hint(args.gcode) if NOT_GCODE in str(exc) else None
        if hint is None:
            raise
        raise CliError(f"{exc}; {hint}", exc.code) from None
    if args.json:
        _emit_json(res)
    else:
        for cmd, reply in zip(res["commands"], res["replies"], strict=False):
            print(f"{cmd}: {json.dumps(reply) if not isinstance(reply, str) else reply}")
    refused = res.get("errors") or []
    if refused:
        first = refused[0]
        more = f" (and {len(refused) - 1} more)" if len(refused) > 1 else ""
        raise CliError(f"the firmware refused {first['command']}: {first['reply']}{more}",
                       EXIT_REFUSED)
    return EXIT_OK


def _quoting_hint(lines: list[str]) -> str | None:
    """``quote a command with its parameters: hostctl send G90 "M104 S200"`` when an
    argument of ``hostctl send`` looks like the parameter of the one before (each argument
    is one line: the words are not joined, a ``T0`` could be either), else None."""
    groups: list[list[str]] = []
    for word in lines:
        if groups and _parameter_of(groups[-1], word):
            groups[-1].append(word)
        else:
            groups.append([word])
    if len(groups) == len(lines):
        return None
    quoted = [_shell_word(" ".join(g)) for g in groups]
    return f"quote a command with its parameters: hostctl send {' '.join(quoted)}"


def _parameter_of(command: list[str], word: str) -> bool:
    """Whether ``word`` reads as a parameter of the ``command`` words (for the hint only):
    a T word is an M-code's tool (``M104 T0``) if it has none yet, else a tool change."""
    if PARAMETER.fullmatch(word):
        return True
    return (bool(TOOL.fullmatch(word)) and command[0][:1].upper() == "M"
            and not any(TOOL.fullmatch(w) for w in command[1:]))


def _shell_word(text: str) -> str:
    """``text`` as one shell word: in double quotes when only its spaces need them."""
    if " " in text and re.fullmatch(r"[\w .+-]+", text):
        return f'"{text}"'
    return shlex.quote(text)


def cmd_delete(args: argparse.Namespace) -> int:
    with _client(args) as c:
        res = c.call("job.delete", id=args.id)
    if args.json:
        _emit_json(res)
    else:
        print(f"job {res['deleted']} deleted")
    return EXIT_OK


def cmd_estop(args: argparse.Namespace) -> int:
    with _client(args) as c:
        res = c.call("printer.estop")
    if args.json:
        _emit_json(res)
    else:
        print("emergency stop sent")
    return EXIT_OK


def cmd_firmware_restart(args: argparse.Namespace) -> int:
    with _client(args, timeout=120.0) as c:
        res = c.call("printer.firmware_restart")
    if args.json:
        _emit_json(res)
    else:
        print(f"firmware restarted: link {res['link']}")
    return EXIT_OK


def cmd_queue(args: argparse.Namespace) -> int:
    method = {"start": "queue.start", "hold": "queue.hold"}.get(args.action, "queue.status")
    with _client(args) as c:
        queue = c.call(method)
    if args.json:
        _emit_json(queue)
        return EXIT_OK
    if queue["held"]:
        print(f"queue held: {queue['reason']}")
    else:
        print("queue runs: the next ready job starts when the printer is free")
    print(f"  {queue['ready']} job(s) ready; daemon.next_job: {queue['next_job']}")
    return EXIT_OK


def cmd_watch(args: argparse.Namespace) -> int:
    with _client(args, timeout=None) as c:
        c.call("events.subscribe")
        for event, data in c.events():
            if args.json:
                _emit_json({"event": event, **data})
            else:
                print(event_text(event, data), flush=True)
    return EXIT_OK
