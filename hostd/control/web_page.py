"""The web page (``GET /``, one file: ``hostd/web/index.html``) and the pictures of a sliced
job (``GET /api/jobs/{id}/pictures/{decomposition|toolpaths}.png``).

The page needs no build step and no library: it speaks JSON-RPC over ``/websocket`` and
uploads with ``POST /api/jobs``, as any client of the API does. Like every request but
``GET /api/version``, these need the API key (``/?apikey=KEY`` the first time: the page keeps
it for the tab and takes it out of the address).
"""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import TYPE_CHECKING

from aiohttp import web

from hostd.control.http_api import json_response, refusal

if TYPE_CHECKING:
    from hostd.control.http_api import HttpApi

PAGE = Path(__file__).resolve().parents[1] / "web" / "index.html"


def add_routes(app: web.Application, api: HttpApi) -> None:
    page = WebPage(api)
    app.router.add_get("/", page.index)
    app.router.add_get("/api/jobs/{id:[0-9]+}/pictures/{which:[a-z]+}.png", page.picture)


class WebPage:
    def __init__(self, api: HttpApi) -> None:
        self.api = api
        self._html: bytes | None = None

    async def index(self, request: web.Request) -> web.Response:
        if self._html is None:
            self._html = await asyncio.to_thread(PAGE.read_bytes)
        return web.Response(body=self._html, content_type="text/html", charset="utf-8",
                            headers={"Cache-Control": "no-store",
                                     "Referrer-Policy": "no-referrer",
                                     "X-Content-Type-Options": "nosniff"})

    async def picture(self, request: web.Request) -> web.StreamResponse:
        job_id, which = int(request.match_info["id"]), request.match_info["which"]
        try:
            path = await asyncio.to_thread(self.api.host.jobs.picture, job_id, which)
        except Exception as exc:  # no such job: the socket's error, as JSON
            return refusal(exc)
        if path is None:
            return json_response({"error": f"job {job_id} has no {which} picture"}, 404)
        return web.FileResponse(path, headers={"Cache-Control": "private, max-age=3600"})
