"""Every JSON-RPC method of the control socket, declared in one table (:data:`ENDPOINTS`).

Handlers are module-level functions ``async def h(api, ctx, **params)`` over :class:`Api`:
the daemon's facade (:class:`~hostd.control.host.Host`) and the uploads in parts. They validate
nothing themselves (the registry checks params), call the domain and return plain JSON.
Errors are exceptions, mapped to codes in one place (:mod:`hostd.control.errors`).
"""

from __future__ import annotations

import asyncio
from dataclasses import dataclass
from functools import partial
from typing import Any

from hostd import __version__
from hostd.config.schema import SCHEMA
from hostd.control.codes import INVALID_PARAMS, UPLOAD_REJECTED, RpcError
from hostd.control.host import Host
from hostd.control.rpc import Encoded, Endpoint, Param, Registry
from hostd.control.server import Client
from hostd.control.upload import PartUploads, write_base64
from hostd.events import check_names
from hostd.jobs.spool import UPLOAD_KINDS, Staged
from hostd.jobs.states import JobStateError, parse_state
from hostd.link.replies import Ok, Position, Reply, Temperatures
from hostd.slicing_worker import SliceOptions

LIST_LIMIT = 100
"""Jobs ``job.list`` returns unless asked: the newest (a long history would hold the loop)."""


@dataclass
class Api:
    """What every handler is given."""

    host: Host
    uploads: PartUploads
    methods: tuple[str, ...] = ()
    """The methods served (``server.info``)."""


# -- server and printer ------------------------------------------------------------------------

async def server_info(api: Api, ctx: Client) -> dict[str, Any]:
    host = api.host
    return {"name": "hostd", "version": __version__, "api": 1, "machine": host.machine_name,
            "max_upload_bytes": host.max_upload_bytes, "emulator": host.is_sim,
            "methods": list(api.methods)}


async def printer_status(api: Api, ctx: Client) -> Encoded:
    return api.host.snapshot_json()


async def printer_gcode(api: Api, ctx: Client, script: str) -> dict[str, Any]:
    ran = await api.host.raw_gcode(script)
    return {"commands": ran.commands, "replies": [reply_json(r) for r in ran.replies],
            "errors": [{"command": c, "reply": reply_text(r)} for c, r in ran.refused()]}


async def printer_estop(api: Api, ctx: Client) -> dict[str, Any]:
    await api.host.emergency_stop()
    return {"stopped": True}


async def printer_firmware_restart(api: Api, ctx: Client) -> dict[str, Any]:
    return await api.host.firmware_restart()


# -- the queue ---------------------------------------------------------------------------------

async def queue_status(api: Api, ctx: Client) -> dict[str, Any]:
    return api.host.jobs.queue_status()


async def queue_start(api: Api, ctx: Client) -> dict[str, Any]:
    return api.host.jobs.queue_start()


async def queue_hold(api: Api, ctx: Client) -> dict[str, Any]:
    return api.host.jobs.queue_hold()


# -- jobs --------------------------------------------------------------------------------------

async def job_submit(api: Api, ctx: Client, name: str, data: str | None, kind: str | None,
                     encoding: str, allow_overhang: bool, seed: int | None,
                     parts: int | None) -> dict[str, Any]:
    options = SliceOptions(allow_overhang, {k: _decompose_param(k, v) for k, v in
                                            (("seed", seed), ("parts", parts)) if v is not None})
    staged = api.uploads.take(ctx.id) if data is None else await _staged(api.host, data,
                                                                         encoding)
    jobs = api.host.jobs
    return jobs.job_dict(await jobs.submit_staged(name, staged, kind, options))


def _decompose_param(key: str, value: int) -> int:
    """``seed``/``parts`` within the bounds of ``decompose.<key>``."""
    spec = SCHEMA["decompose"][key]
    lo, hi = getattr(spec, "lo", None), getattr(spec, "hi", None)
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        raise RpcError(INVALID_PARAMS, f"{key}: {value} must lie in [{lo:.0f}, {hi:.0f}] "
                                       f"(as decompose.{key})")
    return value


async def _staged(host: Host, data: str, encoding: str) -> Staged:
    """An upload sent whole in the request, written to the spool's staging."""
    limit = host.max_upload_bytes
    if encoding == "base64" and len(data) > (limit + 2) // 3 * 4 + 4:
        raise RpcError(UPLOAD_REJECTED, f"upload exceeds the limit of {limit} bytes")
    staged = host.jobs.stage()
    try:
        if encoding == "base64":
            await write_base64(staged, data)
        else:
            await asyncio.to_thread(staged.write, data.encode("utf-8"))
    except BaseException:
        staged.discard()
        raise
    return staged


async def job_upload(api: Api, ctx: Client, data: str, offset: int) -> dict[str, Any]:
    ctx.on_close["upload"] = lambda: api.uploads.drop(ctx.id)
    return {"bytes": await api.uploads.append(ctx.id, data, offset)}


async def job_list(api: Api, ctx: Client, states: list[Any] | None, limit: int
                   ) -> dict[str, Any]:
    try:
        wanted = None if states is None else [parse_state(str(s)) for s in states]
    except JobStateError as exc:  # a bad parameter, not a job in the wrong state
        raise RpcError(INVALID_PARAMS, f"states: {exc}") from None
    if limit < 0:
        raise RpcError(INVALID_PARAMS, f"limit: {limit} is negative (0 lists every job)")
    jobs, total = api.host.jobs.list_jobs(wanted, limit)
    return {"jobs": jobs, "total": total}


async def job_get(api: Api, ctx: Client, id: int | None) -> dict[str, Any]:
    jobs = api.host.jobs
    return jobs.job_detail(jobs.current_id(id))


async def job_pause(api: Api, ctx: Client, id: int | None, wait: bool) -> dict[str, Any]:
    jobs = api.host.jobs
    return jobs.job_dict(await jobs.pause(jobs.current_id(id), wait))


async def job_resume(api: Api, ctx: Client, id: int | None, scope: str | None
                     ) -> dict[str, Any]:
    jobs = api.host.jobs
    target = id if id is not None else jobs.resumable_id()
    return jobs.job_dict(await jobs.resume(target, scope))


async def job_cancel(api: Api, ctx: Client, id: int | None, wait: bool) -> dict[str, Any]:
    jobs = api.host.jobs
    return jobs.job_dict(await jobs.cancel(jobs.current_id(id), wait))


async def job_delete(api: Api, ctx: Client, id: int) -> dict[str, Any]:
    job = await api.host.jobs.delete(id)
    return {"deleted": job.id}


async def job_wait(api: Api, ctx: Client, id: int) -> dict[str, Any]:
    jobs = api.host.jobs
    return jobs.job_dict(await jobs.wait_finished(id))


# -- events and the emulator -------------------------------------------------------------------

async def events_subscribe(api: Api, ctx: Client, events: list[Any] | None) -> dict[str, Any]:
    names = None if not events else [str(e) for e in events]
    if names:
        check_names(names)
    ctx.subscribe(names)
    return {"subscribed": names or "all"}


async def events_unsubscribe(api: Api, ctx: Client) -> dict[str, Any]:
    ctx.subscribed = None
    return {"subscribed": None}


async def sim_log(api: Api, ctx: Client, since: int) -> dict[str, Any]:
    log = api.host.emulator_log()
    return {"total": len(log), "commands": [[n, c] for n, c in log[since:]]}


# -- the table ---------------------------------------------------------------------------------

JOB_ID = Param("id", "int", required=False, doc="job id (default: the current job)")
WAIT = Param("wait", "bool", required=False, default=True)

ENDPOINTS: tuple[Endpoint, ...] = (
    Endpoint("server.info", server_info, doc="daemon identity and the method list"),
    Endpoint("printer.status", printer_status, doc="status() snapshots of every component"),
    Endpoint("printer.gcode", printer_gcode, (Param("script", "str"),),
             doc="run raw G-code lines (only a safe set while printing)"),
    Endpoint("printer.estop", printer_estop, doc="M112 now; the current job fails"),
    Endpoint("printer.firmware_restart", printer_firmware_restart,
             doc="reset the firmware (port reopened) and reconnect; refused with a job on it"),
    Endpoint("queue.status", queue_status, doc="whether new jobs may start, and why not"),
    Endpoint("queue.start", queue_start,
             doc="the platform is clear: lift the hold, the next ready job starts"),
    Endpoint("queue.hold", queue_hold, doc="start no new job until queue.start"),
    Endpoint("job.submit", job_submit, (
        Param("name", "str", line=True),
        Param("data", "str", required=False, doc="the file (else the job.upload parts)"),
        Param("kind", "str", required=False, choices=UPLOAD_KINDS),
        Param("encoding", "str", required=False, default="base64",
              choices=("base64", "text")),
        Param("allow_overhang", "bool", required=False, default=False,
              doc="a part: keep a file with unsupported wall layers (else the slice fails)"),
        Param("seed", "int", required=False, doc="a part: decompose.seed for this job"),
        Param("parts", "int", required=False, doc="a part: decompose.parts for this job")),
        doc="queue an STL, 3MF, OBJ or G-code upload (content in the request)"),
    Endpoint("job.upload", job_upload, (
        Param("data", "str", doc="a part of the file, base64"),
        Param("offset", "int", doc="its byte offset in the file (0 starts one)")),
        doc="send a file in parts, then job.submit without data"),
    Endpoint("job.list", job_list, (
        Param("states", "list", required=False),
        Param("limit", "int", required=False, default=LIST_LIMIT)),
        doc="the newest jobs (limit 0: all), oldest first, and how many there are"),
    Endpoint("job.get", job_get, (JOB_ID,), doc="one job with history and checkpoints"),
    Endpoint("job.pause", job_pause, (JOB_ID, WAIT), doc="pause after the acknowledged line"),
    Endpoint("job.resume", job_resume, (
        JOB_ID,
        Param("from", "str", required=False, default=None,
              choices=("layer", "subpart", "checkpoint"),
              doc="interrupted jobs only (default layer)", arg="scope")),
        doc="resume a paused job (once it prints again), or an interrupted one from the "
            "start of its layer (default), sub-part or last checkpoint"),
    Endpoint("job.cancel", job_cancel, (JOB_ID, WAIT), doc="stop and run the end script"),
    Endpoint("job.delete", job_delete, (Param("id", "int"),), doc="forget a finished job"),
    Endpoint("job.wait", job_wait, (Param("id", "int"),),
             doc="return when the job is finished or interrupted"),
    Endpoint("events.subscribe", events_subscribe, (Param("events", "list", required=False),),
             doc="push notify_* notifications (all events or the named ones)"),
    Endpoint("events.unsubscribe", events_unsubscribe, doc="stop pushed notifications"),
)
"""The daemon's API, in the order ``describe()`` lists it."""

EMULATOR_ENDPOINTS: tuple[Endpoint, ...] = (
    Endpoint("sim.log", sim_log, (Param("since", "int", required=False, default=0),),
             doc="the emulator's execution log (emulator only)"),
)
"""Served only on the emulator (``serial.port: sim://``)."""


def build_registry(host: Host) -> Registry:
    """The whole API of the daemon ``host``: each handler bound to one :class:`Api`."""
    api = Api(host, PartUploads(lambda: host.jobs.stage()))
    reg = Registry()
    for ep in ENDPOINTS + (EMULATOR_ENDPOINTS if host.is_sim else ()):
        reg.add(ep.method, partial(ep.handler, api), *ep.params, doc=ep.doc)
    api.methods = tuple(sorted(reg.endpoints))
    return reg


# -- replies as JSON ---------------------------------------------------------------------------

def reply_json(reply: Reply) -> Any:
    """A firmware reply as the client gets it: a position, temperatures, ``ok`` or text."""
    if isinstance(reply, Position):
        return {"position": dict(reply.axes)}
    if isinstance(reply, Temperatures):
        return {"temperatures": {k: {"actual": h.actual, "target": h.target}
                                 for k, h in reply.heaters.items()}}
    if isinstance(reply, Ok):
        return "ok"
    return reply_text(reply)


def reply_text(reply: Reply) -> str:
    return str(getattr(reply, "text", reply))
