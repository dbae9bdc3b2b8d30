"""The web page's server side (issue 36, item 3) without a browser: the page behind the key,
the pictures of a job (404 where there are none), and the figures the page shows of a job
on the printer (sub-part k of n, layer l of m within it) in the job.progress events."""

from __future__ import annotations

import asyncio

import aiohttp
import pytest
from hostd_harness import DaemonProc, free_port, make_gcode

pytestmark = pytest.mark.asyncio


async def test_the_page_and_pictures_need_the_key_and_a_gcode_job_has_no_pictures(tmp_path):
    from hostd import api_keys

    keys = tmp_path / "api-keys"
    key = api_keys.new(keys, "page").key
    port = free_port()
    d = DaemonProc(tmp_path, http__enabled=True, http__port=port, http__api_key_file=str(keys))
    url = f"http://127.0.0.1:{port}"
    async with asyncio.timeout(90):
        await d.start()
        try:
            c = await d.rpc()
            await c.call("events.subscribe", events=["job.progress", "job.state"])
            job = await c.submit_text("two.gcode", make_gcode(subparts=2, layers=3))
            progress = await c.until(lambda e: e["event"] == "job.progress"
                                     and e["subpart"] == 1)
            await c.until_state(job["id"], "completed")
            await c.close()
            async with aiohttp.ClientSession() as http:
                async with http.get(f"{url}/") as r:
                    assert r.status == 401
                async with http.get(f"{url}/?apikey={key}") as r:
                    assert r.status == 200 and r.content_type == "text/html"
                    page = await r.text()
                pics = f"{url}/api/jobs/{job['id']}/pictures/toolpaths.png?apikey={key}"
                async with http.get(pics) as r:
                    assert r.status == 404
                    assert (await r.json())["error"] == (f"job {job['id']} has no toolpaths "
                                                         "picture")
                async with http.get(f"{url}/api/jobs/99/pictures/toolpaths.png?apikey={key}"
                                    ) as r:
                    assert r.status == 404 and (await r.json())["code"] == -32001
        finally:
            await d.stop()
    assert "<title>hostd</title>" in page and "/websocket" in page
    assert progress["subparts_total"] == 2 and progress["subpart_layers"] == 3
