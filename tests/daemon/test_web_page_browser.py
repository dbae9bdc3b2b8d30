"""The web page in a real browser (issue 36, item 3): headless Chromium (Debian's package)
driven by Playwright, against a hostd subprocess on sim://. It uploads an STL from the page,
watches it slice and print to completion through the WebSocket's events, and finds the job's
summary, sub-part and layer figures and its pictures on the page. A screenshot is kept in
``$HOSTD_TEST_OUTPUT`` (default ``.test-output/`` in the source tree: CI keeps it).

Skipped where /usr/bin/chromium or Playwright is missing (``.ci/run`` installs both)."""

from __future__ import annotations

import asyncio
import os
import shutil
from pathlib import Path

import pytest
from hostd_harness import ROOT, DaemonProc, free_port

from slicer.mesh.samples import cylinder

CHROMIUM = "/usr/bin/chromium"
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]
playwright = pytest.importorskip("playwright.async_api")
pytestmark = [pytest.mark.asyncio, pytest.mark.skipif(not Path(CHROMIUM).exists(),
                                                       reason="Debian's chromium is missing")]


def output_dir() -> Path:
    out = Path(os.environ.get("HOSTD_TEST_OUTPUT") or ROOT / ".test-output")
    out.mkdir(parents=True, exist_ok=True)
    return out


async def test_the_page_uploads_an_stl_and_shows_it_print_to_completion(tmp_path):
    from hostd import api_keys

    keys = tmp_path / "api-keys"
    key = api_keys.new(keys, "browser").key
    port = free_port()
    d = DaemonProc(tmp_path, http__enabled=True, http__port=port, http__api_key_file=str(keys),
                   sim__throttle=True)
    part = tmp_path / "peg.stl"
    cylinder(radius=6.0, height=3.0).export(part, file_type="stl")
    async with asyncio.timeout(240):
        await d.start()
        try:
            async with playwright.async_playwright() as pw:
                browser = await pw.chromium.launch_persistent_context(
                    str(tmp_path / "profile"), executable_path=CHROMIUM, headless=True,
                    args=FLAGS, viewport={"width": 1200, "height": 1400})
                try:
                    seen = await drive(browser.pages[0] if browser.pages
                                       else await browser.new_page(), port, key, part)
                finally:
                    await browser.close()
        finally:
            await d.stop()
    assert seen["address"] == f"http://127.0.0.1:{port}/"  # the key left the address bar
    assert seen["link"] == "ready"
    assert seen["upload"].startswith("job 1 ") and seen["upload"].endswith("peg.stl")
    assert seen["state"].startswith("completed")
    assert seen["summary"].startswith("summary: ") and "mm of filament" in seen["summary"]
    assert seen["subpart"].startswith("sub-part ") and " of " in seen["subpart"]
    assert seen["layer"].startswith("layer ") and " of " in seen["layer"]
    assert seen["pictures"] == {"decomposition": True, "toolpaths": True}
    assert not d.loop_errors()


async def drive(page: object, port: int, key: str, part: Path) -> dict[str, object]:
    """What a person does and sees: open the page, upload, watch the job to its end."""
    seen: dict[str, object] = {}
    await page.goto(f"http://127.0.0.1:{port}/?apikey={key}")
    await page.wait_for_function(
        "document.getElementById('link-state').textContent === 'ready'")
    seen["address"], seen["link"] = page.url, await page.text_content("#link-state")
    await page.set_input_files("#file", str(part))
    await page.click("#upload button")
    await page.wait_for_function(
        "document.getElementById('upload-status').textContent.startsWith('job ')")
    seen["upload"] = await page.text_content("#upload-status")
    await page.wait_for_function(
        "document.getElementById('job-state').textContent.startsWith('completed')",
        timeout=180_000)
    await page.wait_for_function(
        "document.getElementById('summary').textContent.startsWith('summary: ')")
    for key_ in ("state", "summary", "subpart", "layer"):
        seen[key_] = await page.text_content(f"#job-{key_}" if key_ != "summary"
                                             else "#summary")
    await page.wait_for_function(
        "['decomposition', 'toolpaths'].every(n => { const i = document.getElementById("
        "'picture-' + n); return i && i.complete && i.naturalWidth > 0; })")
    seen["pictures"] = {n: await page.evaluate(
        f"document.getElementById('picture-{n}').naturalWidth > 100")
        for n in ("decomposition", "toolpaths")}
    shot = output_dir() / "web_page.png"
    await page.screenshot(path=str(shot), full_page=True)
    shutil.copy(shot, part.parent / "web_page.png")
    return seen
