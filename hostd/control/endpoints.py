"""Every JSON-RPC method of the control socket, registered in one table.

Handlers are thin: they validate nothing themselves (the registry checks params), call the job
manager or the printer, and return plain JSON. Errors are exceptions, mapped to codes by
:func:`hostd.control.rpc.error_for`.
"""

from __future__ import annotations

import asyncio
from typing import TYPE_CHECKING, Any

from hostd import __version__
from hostd.control.codes import INVALID_PARAMS, UPLOAD_REJECTED, RpcError
from hostd.control.rpc import Param, Registry
from hostd.control.server import Client
from hostd.control.upload import PartUploads, write_base64
from hostd.errors import PrinterBusy
from hostd.jobs.spool import Staged
from hostd.jobs.states import JobState, JobStateError, parse_state
from hostd.link.replies import Echo, ErrorReply, Ok, Position, Temperatures
from hostd.printer.errors import ProgramError
from hostd.printer.program import parse_program

if TYPE_CHECKING:
    from hostd.daemon import Daemon

SAFE_WHILE_PRINTING = frozenset({"M105", "M114", "M115", "M117", "M118", "M119", "M220",
                                 "M221", "M106", "M107", "M104", "M140", "M155"})
"""Raw commands accepted while a job prints: queries, messages, fan, overrides, set points."""
RAW_MAX_LINES = 100
LIST_LIMIT = 100
"""Jobs ``job.list`` returns unless asked: the newest (a long history would hold the loop)."""


def build_registry(d: Daemon) -> Registry:
    """The whole API of the daemon ``d``."""
    reg = Registry()
    uploads = PartUploads(lambda: d.jobs.spool.stage())
    jid = Param("id", "int", required=False, doc="job id (default: the current job)")
    wait = Param("wait", "bool", required=False, default=True)

    async def server_info(ctx: Client) -> dict[str, Any]:
        return {"name": "hostd", "version": __version__, "api": 1,
                "machine": d.config["machine.name"],
                "max_upload_bytes": d.config["daemon.max_upload_bytes"],
                "emulator": d.is_sim, "methods": sorted(reg.endpoints)}

    async def printer_status(ctx: Client) -> dict[str, Any]:
        return d.snapshot()

    async def printer_gcode(ctx: Client, script: str) -> dict[str, Any]:
        try:  # the checks of a file: no control characters, only finite numbers, the heaters'
            program = parse_program(script)  # limits, the travel of absolute moves (a relative
            if d.jobs.checker.envelope is not None:  # one, from a place unknown, is not known)
                d.jobs.checker.envelope.check(program)
        except ProgramError as exc:
            raise RpcError(INVALID_PARAMS, f"script: {exc}") from None
        commands = program.commands
        if not commands:
            raise RpcError(INVALID_PARAMS, "script: no G-code commands")
        if len(commands) > RAW_MAX_LINES:
            raise RpcError(INVALID_PARAMS, f"script: more than {RAW_MAX_LINES} commands")
        act = d.jobs.active
        if act is not None and act.streamer.state != "paused":
            unsafe = [c for c in commands if c.split()[0] not in SAFE_WHILE_PRINTING]
            if unsafe:
                raise PrinterBusy(f"refused while printing: {unsafe[0]} (allowed: "
                                  f"{' '.join(sorted(SAFE_WHILE_PRINTING))})")
        elif act is not None:  # paused: anything goes, and the resume puts it back
            act.streamer.note_raw(commands)
        raw = [await d.link.query(c) for c in commands]
        return {"commands": commands, "replies": [_reply(r) for r in raw],
                "errors": [{"command": c, "reply": str(getattr(r, "text", r))}
                           for c, r in zip(commands, raw, strict=True) if _refused(r)]}

    async def printer_firmware_restart(ctx: Client) -> dict[str, Any]:
        return await d.firmware_restart()

    async def queue_status(ctx: Client) -> dict[str, Any]:
        return d.jobs.queue_status()

    async def queue_start(ctx: Client) -> dict[str, Any]:
        return d.jobs.queue_start()

    async def queue_hold(ctx: Client) -> dict[str, Any]:
        return d.jobs.queue_hold()

    async def printer_estop(ctx: Client) -> dict[str, Any]:
        await d.emergency_stop()
        return {"stopped": True}

    async def job_submit(ctx: Client, name: str, data: str | None, kind: str | None,
                         encoding: str) -> dict[str, Any]:
        staged = uploads.take(ctx.id) if data is None else await _staged(data, encoding)
        return d.jobs.job_dict(await d.jobs.submit_staged(name, staged, kind))

    async def _staged(data: str, encoding: str) -> Staged:
        limit = d.config["daemon.max_upload_bytes"]
        if encoding == "base64" and len(data) > (limit + 2) // 3 * 4 + 4:
            raise RpcError(UPLOAD_REJECTED, f"upload exceeds the limit of {limit} bytes")
        staged = d.jobs.spool.stage()
        try:
            if encoding == "base64":
                await write_base64(staged, data)
            else:
                await asyncio.to_thread(staged.write, data.encode("utf-8"))
        except BaseException:
            staged.discard()
            raise
        return staged

    async def job_upload(ctx: Client, data: str, offset: int) -> dict[str, Any]:
        ctx.on_close["upload"] = lambda: uploads.drop(ctx.id)
        return {"bytes": await uploads.append(ctx.id, data, offset)}

    async def job_list(ctx: Client, states: list[Any] | None, limit: int) -> dict[str, Any]:
        try:
            wanted = None if states is None else [parse_state(str(s)) for s in states]
        except JobStateError as exc:  # a bad parameter, not a job in the wrong state
            raise RpcError(INVALID_PARAMS, f"states: {exc}") from None
        if limit < 0:
            raise RpcError(INVALID_PARAMS, f"limit: {limit} is negative (0 lists every job)")
        store = d.jobs.store
        return {"jobs": [d.jobs.job_dict(j) for j in store.list(wanted, limit, newest=True)],
                "total": store.count(wanted)}

    async def job_get(ctx: Client, id: int | None) -> dict[str, Any]:
        job = d.jobs.store.get(_current(d, id))
        out = d.jobs.job_dict(job)
        out["history"] = d.jobs.store.history(job.id)
        out["checkpoints"] = [c.to_dict() for c in d.jobs.store.checkpoints(job.id)]
        return out

    async def job_pause(ctx: Client, id: int | None, wait: bool) -> dict[str, Any]:
        return d.jobs.job_dict(await d.jobs.pause(_current(d, id), wait))

    async def job_resume(ctx: Client, id: int | None, scope: str | None) -> dict[str, Any]:
        target = id if id is not None else _resumable(d)
        return d.jobs.job_dict(await d.jobs.resume(target, scope))

    async def job_cancel(ctx: Client, id: int | None, wait: bool) -> dict[str, Any]:
        return d.jobs.job_dict(await d.jobs.cancel(_current(d, id), wait))

    async def job_delete(ctx: Client, id: int) -> dict[str, Any]:
        job = await d.jobs.delete(id)
        return {"deleted": job.id}

    async def job_wait(ctx: Client, id: int) -> dict[str, Any]:
        return d.jobs.job_dict(await d.jobs.wait_finished(id))

    async def events_subscribe(ctx: Client, events: list[Any] | None) -> dict[str, Any]:
        names = None if not events else [str(e) for e in events]
        if names:
            d.bus.subscribe(lambda n, data: None, names)()  # validates the names
        ctx.subscribe(names)
        return {"subscribed": names or "all"}

    async def events_unsubscribe(ctx: Client) -> dict[str, Any]:
        ctx.subscribed = None
        return {"subscribed": None}

    async def sim_log(ctx: Client, since: int) -> dict[str, Any]:
        log = d.emulator_log()
        return {"total": len(log), "commands": [[n, c] for n, c in log[since:]]}

    reg.add("server.info", server_info, doc="daemon identity and the method list")
    reg.add("printer.status", printer_status, doc="status() snapshots of every component")
    reg.add("printer.gcode", printer_gcode, Param("script", "str"),
            doc="run raw G-code lines (only a safe set while printing)")
    reg.add("printer.estop", printer_estop, doc="M112 now; the current job fails")
    reg.add("printer.firmware_restart", printer_firmware_restart,
            doc="reset the firmware (port reopened) and reconnect; refused with a job on it")
    reg.add("queue.status", queue_status, doc="whether new jobs may start, and why not")
    reg.add("queue.start", queue_start,
            doc="the platform is clear: lift the hold, the next ready job starts")
    reg.add("queue.hold", queue_hold, doc="start no new job until queue.start")
    reg.add("job.submit", job_submit, Param("name", "str", line=True),
            Param("data", "str", required=False, doc="the file (else the job.upload parts)"),
            Param("kind", "str", required=False, choices=("stl", "gcode")),
            Param("encoding", "str", required=False, default="base64",
                  choices=("base64", "text")),
            doc="queue an STL or G-code upload (content in the request)")
    reg.add("job.upload", job_upload, Param("data", "str", doc="a part of the file, base64"),
            Param("offset", "int", doc="its byte offset in the file (0 starts one)"),
            doc="send a file in parts, then job.submit without data")
    reg.add("job.list", job_list, Param("states", "list", required=False),
            Param("limit", "int", required=False, default=LIST_LIMIT),
            doc="the newest jobs (limit 0: all), oldest first, and how many there are")
    reg.add("job.get", job_get, jid, doc="one job with history and checkpoints")
    reg.add("job.pause", job_pause, jid, wait, doc="pause after the acknowledged line")
    reg.add("job.resume", job_resume, jid,
            Param("from", "str", required=False, default=None,
                  choices=("layer", "subpart", "checkpoint"),
                  doc="interrupted jobs only (default layer)"),
            doc="resume a paused job (once it prints again), or an interrupted one from the "
                "start of its layer (default), sub-part or last checkpoint")
    reg.add("job.cancel", job_cancel, jid, wait, doc="stop and run the end script")
    reg.add("job.delete", job_delete, Param("id", "int"), doc="forget a finished job")
    reg.add("job.wait", job_wait, Param("id", "int"),
            doc="return when the job is finished or interrupted")
    reg.add("events.subscribe", events_subscribe, Param("events", "list", required=False),
            doc="push notify_* notifications (all events or the named ones)")
    reg.add("events.unsubscribe", events_unsubscribe, doc="stop pushed notifications")
    if d.is_sim:
        reg.add("sim.log", sim_log, Param("since", "int", required=False, default=0),
                doc="the emulator's execution log (emulator only)")
    _rename_from(reg)
    return reg


def _rename_from(reg: Registry) -> None:
    """``job.resume``'s ``from`` is a Python keyword: bind it to ``scope``."""
    ep = reg.endpoints["job.resume"]
    handler = ep.handler

    async def resume(ctx: Client, **kw: Any) -> Any:
        return await handler(ctx, kw["id"], kw["from"])

    reg.endpoints["job.resume"] = type(ep)(ep.method, resume, ep.params, ep.doc)


def _current(d: Daemon, job_id: int | None) -> int:
    if job_id is not None:
        return job_id
    if d.jobs.active is None:
        raise JobStateError("no job is printing; give an id")
    return d.jobs.active.job.id


def _resumable(d: Daemon) -> int:
    if d.jobs.active is not None:
        return d.jobs.active.job.id
    jobs = d.jobs.store.list([JobState.INTERRUPTED, JobState.PAUSED])
    if not jobs:
        raise JobStateError("no paused or interrupted job; give an id")
    return jobs[-1].id


REFUSALS = ("unknown command",)
"""How an ``echo:`` reply of Marlin's starts when it did not run the command."""


def _refused(reply: Any) -> bool:
    """Whether the firmware answered a raw command with an error: an ``Error:`` line, or an
    ``echo:Unknown command``."""
    if isinstance(reply, ErrorReply):
        return True
    return isinstance(reply, Echo) and reply.text.lower().startswith(REFUSALS)


def _reply(reply: Any) -> Any:
    if isinstance(reply, Position):
        return {"position": dict(reply.axes)}
    if isinstance(reply, Temperatures):
        return {"temperatures": {k: {"actual": h.actual, "target": h.target}
                                 for k, h in reply.heaters.items()}}
    if isinstance(reply, Ok):
        return "ok"
    return str(getattr(reply, "text", reply))
