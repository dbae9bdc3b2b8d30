"""Issue 7: the Prometheus endpoint of a live daemon during a print on the emulator.

The endpoint is scraped after every ``job.progress`` event and parsed with prometheus-client's
own parsers: names, types and units as documented, progress rising to 1, serial counters equal
to the link's ``printer.status`` counters, temperatures equal to ``hostctl status --json``.
"""

from __future__ import annotations

import asyncio
import json
import math
import re
import sys
from typing import Any

import pytest
from hostd_harness import ROOT, free_port, make_gcode, scrape
from prometheus_client.metrics_core import Metric
from prometheus_client.openmetrics.parser import text_string_to_metric_families as parse_om
from prometheus_client.parser import text_string_to_metric_families as parse_text

from hostd.metrics.collector import lookup
from hostd.metrics.specs import SPECS, Spec

pytestmark = pytest.mark.asyncio

COUNTERS = {"hostd_serial_lines_sent": "lines_sent",
            "hostd_serial_lines_acknowledged": "lines_acked",
            "hostd_serial_lines_resent": "lines_resent",
            "hostd_serial_checksum_errors": "checksum_errors",
            "hostd_serial_timeouts": "timeouts",
            "hostd_serial_reconnects": "reconnects"}
OPENMETRICS = "application/openmetrics-text; version=1.0.0"
ATTEMPTS = 8  # consistent reads around a scrape (an idle M105 may land in between)


async def families(port: int) -> dict[str, Metric]:
    return {f.name: f for f in parse_text(await scrape(port))}


def exposed_name(spec: Spec) -> str:
    """The family name the 0.0.4 text parser gives a spec."""
    if spec.kind == "counter":
        return spec.name.removesuffix("_total")
    return f"{spec.name}_info" if spec.kind == "info" else spec.name


def exposed_type(spec: Spec) -> str:
    return "gauge" if spec.kind in ("info", "stateset") else spec.kind


def value(fams: dict[str, Metric], name: str, **labels: str) -> float:
    for s in fams[name].samples:
        if s.name in (name, name + "_total") and all(s.labels.get(k) == v
                                                     for k, v in labels.items()):
            return s.value
    raise KeyError((name, labels))


def by_label(fams: dict[str, Metric], name: str, label: str) -> dict[str, float]:
    return {s.labels[label]: s.value for s in fams[name].samples}


def has_source(status: dict[str, Any], spec: Spec) -> bool:
    src = lookup(status, spec.path)
    if spec.kind == "stateset":
        return True  # nothing is the first state ("idle")
    if spec.label is None or src is None:
        return src is not None
    return any(k in src for k in (spec.keys or src))


def readme_table() -> dict[str, tuple[str, str]]:
    """metric → (type, unit) as the README documents them."""
    text = (ROOT / "README.md").read_text()
    table = text.split("<!-- BEGIN metrics-table -->")[1].split("<!-- END metrics-table -->")[0]
    rows = {}
    for m in re.finditer(r"^\| `(\w+)` \| ([^|]+) \| ([^|]*) \|", table, re.M):
        rows[m[1]] = (m[2].strip().split(" ")[0], m[3].strip())
    return rows


async def hostctl_status(sock: str) -> dict[str, Any]:
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "hostd.cli.main", "--socket", sock, "status", "--json",
        stdout=asyncio.subprocess.PIPE, cwd=str(ROOT))
    out, _ = await proc.communicate()
    assert proc.returncode == 0
    return json.loads(out)


async def watch_progress(c: Any, port: int, job_id: int) -> list[float]:
    """Scrape after every progress event until the job completes; the scraped ratios."""
    seen: list[float] = []
    while True:
        ev = await c.events.get()
        if ev["event"] == "job.state" and ev["job_id"] == job_id:
            assert ev["new"] not in ("failed", "cancelled", "interrupted"), ev
            if ev["new"] == "completed":
                return seen
            continue
        if ev["event"] != "job.progress":
            continue
        ratio = value(await families(port), "hostd_job_progress_ratio")
        assert ratio >= ev["progress"] - 1e-12, "a scrape lags behind a published event"
        assert not seen or ratio >= seen[-1], "progress went backwards"
        seen.append(ratio)


async def test_metrics_during_a_print(daemon_factory):
    port = free_port()
    d = daemon_factory(metrics__enabled=True, metrics__host="127.0.0.1", metrics__port=port)
    await d.start()
    async with asyncio.timeout(60):
        c = await d.rpc()
        await c.call("events.subscribe", events=["job.progress", "job.state"])
        idle = await families(port)
        assert value(idle, "hostd_job_state", state="idle") == 1
        assert "hostd_job_progress_ratio" not in idle
        assert value(idle, "hostd_serial_link_up") == 1
        assert value(idle, "hostd_serial_link_state", state="ready") == 1

        job = await c.submit_text("m.gcode", make_gcode(subparts=3, layers=3, per_layer=80))
        seen = await watch_progress(c, port, job["id"])
        assert len(seen) >= 3 and seen[0] < 1.0

        # the finished job stays visible: progress 1, state completed, counted once
        fams = await families(port)
        assert value(fams, "hostd_job_progress_ratio") == 1.0
        assert value(fams, "hostd_job_state", state="completed") == 1
        assert value(fams, "hostd_jobs_finished", outcome="completed") == 1
        assert value(fams, "hostd_jobs", state="completed") == 1
        assert value(fams, "hostd_jobs", state="queued") == 0
        assert value(fams, "hostd_transitions") == 2
        assert value(fams, "hostd_job_subparts") == 3
        assert by_label(fams, "hostd_axis_position_degrees", "axis") == {"A": 0.0, "C": 0.0}
        info = fams["hostd_job_info"].samples[0].labels
        assert info == {"id": str(job["id"]), "name": "m.gcode"}

        await check_every_spec(c, port)
        await check_counters(c, port, job["total_lines"])
        await check_temperatures(d, port)
        await c.close()
    assert await d.stop() == 0


async def check_every_spec(c: Any, port: int) -> None:
    status = await c.call("printer.status")
    fams = await families(port)
    om = {f.name: f for f in parse_om(await scrape(port, OPENMETRICS))}
    documented = readme_table()
    missing = []
    for spec in SPECS:
        if not has_source(status, spec):
            missing.append(spec.name)
            continue
        name = exposed_name(spec)
        assert name in fams, spec.name
        assert fams[name].type == exposed_type(spec), spec.name
        kind = exposed_type(spec) if spec.kind == "stateset" else spec.kind
        assert documented[spec.name] == (kind, spec.unit), spec.name
        om_name = name if spec.kind != "info" else spec.name
        assert om[om_name].type == kind and om[om_name].unit == spec.unit, spec.name
    assert not missing, missing


async def consistent(read: Any, scrape_once: Any) -> tuple[Any, Any]:
    """(value read before and after the scrape, the scrape), once both reads agree."""
    for _ in range(ATTEMPTS):
        before = await read()
        fams = await scrape_once()
        if await read() == before:
            return before, fams
    raise AssertionError("the daemon's state never stood still around a scrape")


async def check_counters(c: Any, port: int, job_lines: int) -> None:
    async def counters() -> dict[str, int]:
        link = (await c.call("printer.status"))["link"]
        return {**{k: link[k] for k in COUNTERS.values()}, "rtt": link["ok_rtt"]["count"]}

    link, fams = await consistent(counters, lambda: families(port))
    assert {name: value(fams, name) for name in COUNTERS} == {
        name: link[key] for name, key in COUNTERS.items()}
    assert link["lines_acked"] >= job_lines
    rtt = {s.name: s.value for s in fams["hostd_serial_ok_roundtrip_seconds"].samples}
    assert rtt["hostd_serial_ok_roundtrip_seconds_count"] == link["rtt"] > 0
    assert fams["hostd_serial_lines_sent"].type == "counter"


async def check_temperatures(d: Any, port: int) -> None:
    async def scraped() -> tuple[dict[str, float], dict[str, float]]:
        fams = await families(port)
        return (by_label(fams, "hostd_temperature_celsius", "heater"),
                by_label(fams, "hostd_temperature_target_celsius", "heater"))

    (actual, target), status = await consistent(scraped, lambda: hostctl_status(str(d.socket)))
    temps = status["link"]["temperatures"]
    assert {"T", "B"} <= set(temps)
    assert actual == {k: t["actual"] for k, t in temps.items()}
    assert target == {k: t["target"] for k, t in temps.items()}
    assert all(math.isfinite(x) for x in actual.values())
