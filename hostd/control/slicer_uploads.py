"""Send to printer from slicers: the upload requests of OctoPrint and Moonraker clients.

- ``POST /api/files/local`` (OctoPrint's, as PrusaSlicer, SuperSlicer, OrcaSlicer and Cura's
  OctoPrint plugin send it): a multipart form with ``file``, and optionally ``print``,
  ``select`` and ``path`` (a folder, ignored: jobs are named by the file); the key in
  ``X-Api-Key``. 201 with OctoPrint's answer (``files.local``, ``done``,
  ``effectivePrint``) and hostd's job.
- ``POST /server/files/upload`` (Moonraker's, as Mainsail, Fluidd and Moonraker's other
  clients send it): ``file``, ``root`` (``gcodes`` only), ``path``, ``print``, and
  ``checksum`` (the file's sha256, checked: 422 when it differs). 201 with Moonraker's
  ``{"result": {"item", "print_started", "print_queued", "action"}}``.

An STL, 3MF, OBJ or G-code sent so becomes a job, checked and stored as ``job.submit``
stores one. Every job in hostd prints in its turn: one sent without ``print`` is queued
with the queue held (``queue.start``, or the web page's Start, lets it print), as a slicer's
plain "Upload" means "keep it, do not start it".
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from aiohttp import web

from hostd.control.http_api import UploadError, json_response

if TYPE_CHECKING:
    from hostd.control.http_api import HttpApi, Upload

TRUE = frozenset({"true", "1", "yes", "on"})


def add_routes(app: web.Application, api: HttpApi) -> None:
    uploads = SlicerUploads(api)
    app.router.add_post("/api/files/local", uploads.octoprint)
    app.router.add_post("/server/files/upload", uploads.moonraker)


def _flag(fields: dict[str, str], name: str) -> bool:
    return fields.get(name, "").strip().lower() in TRUE


class SlicerUploads:
    """The two upload endpoints over one :class:`~hostd.control.http_api.HttpApi`."""

    def __init__(self, api: HttpApi) -> None:
        self.api = api

    async def _job(self, up: Upload, start: bool) -> dict[str, Any] | web.Response:
        """The upload queued as a job; without ``start`` the queue is held for it."""
        job = await self.api.submit(up, up.name, None)
        if isinstance(job, web.Response) or start:
            return job
        self.api.host.jobs.queue_hold(f"uploaded without print (job {job['id']} "
                                      f"{job['name']!r}): hostctl queue start prints it")
        return job

    async def octoprint(self, request: web.Request) -> web.Response:
        try:
            up = await self.api.read_upload(request)
        except UploadError as exc:
            return json_response({"error": str(exc)}, exc.status)
        start = _flag(up.fields, "print")
        job = await self._job(up, start)
        if isinstance(job, web.Response):
            return job
        name = str(job["name"])
        return json_response({
            "files": {"local": {"name": name, "path": name, "origin": "local",
                                "refs": {"resource": f"{request.url.origin()}/api/files/"
                                                     f"local/{name}"}}},
            "done": True, "effectivePrint": start,
            "effectiveSelect": start or _flag(up.fields, "select"), "job": job}, 201)

    async def moonraker(self, request: web.Request) -> web.Response:
        try:
            up = await self.api.read_upload(request)
        except UploadError as exc:
            return _moonraker_error(str(exc), exc.status)
        refused = _moonraker_refusal(up)
        if refused is not None:
            up.staged.discard()
            return refused
        start = _flag(up.fields, "print")
        job = await self._job(up, start)
        if isinstance(job, web.Response):
            return job
        return json_response({"result": {
            "item": {"path": str(job["name"]), "root": "gcodes", "size": up.staged.size},
            "print_started": start and job["state"] == "printing", "print_queued": start,
            "action": "create_file", "job": job}}, 201)


def _moonraker_refusal(up: Upload) -> web.Response | None:
    """Moonraker's refusals of a form hostd reads: another root, a checksum that differs."""
    root = up.fields.get("root", "gcodes") or "gcodes"
    if root != "gcodes":
        return _moonraker_error(f"root {root!r}: hostd takes files to print only (gcodes)",
                                400)
    want = up.fields.get("checksum", "").strip().lower()
    if want and want != up.staged.digest():
        return _moonraker_error(f"file {up.name!r}: checksum mismatch: the upload's sha256 is "
                                f"{up.staged.digest()}, the request said {want}", 422)
    return None


def _moonraker_error(message: str, status: int) -> web.Response:
    return json_response({"error": {"code": status, "message": message}}, status)
