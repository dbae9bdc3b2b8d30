from __future__ import annotations

import asyncio
import time
import urllib.request

import pytest
from prometheus_client import generate_latest
from prometheus_client.parser import text_string_to_metric_families

from hostd.metrics.collector import lookup, make_registry
from hostd.metrics.server import MetricsServer
from hostd.metrics.specs import SPECS
from hostd.stats import Buckets

UNITS = ("_seconds", "_celsius", "_meters", "_degrees", "_bytes", "_ratio", "_total")


def full_snapshot() -> dict:
    rtt = Buckets((0.01, 0.1))
    for x in (0.005, 0.05, 0.5):
        rtt.observe(x)
    return {
        "daemon": {"info": {"version": "0.1.0", "firmware_name": "hostd-sim"}},
        "link": {"connected": True, "capabilities": {"AUTOREPORT_TEMP": True, "EEPROM": False},
                 "lines_sent": 120, "lines_acked": 118, "lines_resent": 3, "reads": 60,
                 "lines_withdrawn": 5,
                 "checksum_errors": 2, "timeouts": 1, "reconnects": 0, "window_bytes": 127,
                 "state": "halted", "resets": 1,
                 "starve_nudges": 4, "resyncs": 2,
                 "ok_rtt": {"histogram": rtt.snapshot()},
                 "temperatures": {"T": {"actual": 209.5, "target": 210.0, "power": 80},
                                  "B": {"actual": 60.1, "target": 60.0, "power": None}}},
        "jobs": {"queue_length": 2, "finished": {"completed": 4, "failed": 1},
                 "counts": {"queued": 1, "slicing": 1, "ready": 0, "completed": 4},
                 "transitions": {"total": 3, "failed": 0},
                 "file_checks": {"checks": 5, "refused": 1, "worker_started": True},
                 "queue": {"held": True, "reason": "job 3 completed"},
                 "waiting_for_printer": False,
                 "storage": {"failing": False, "error": None, "since": None,
                             "heaters_off": False},
                 "latest": {"info": {"id": "j1", "name": "pipe"}, "state": "printing",
                            "progress": 0.25, "subpart": 1, "subparts_total": 3, "layer": 7,
                            "layers_total": 900, "elapsed_s": 12.0, "remaining_s": 36.0,
                            "filament_mm": 2500.0, "axes": {"A": 45.0, "C": -90.0, "X": 1}}},
        "slicer": {"durations": Buckets((1.0, 10.0)).snapshot(), "failures": 2},
        "metrics": {"start_time_s": 1_700_000_000.0,
                    "jobs_finished": {"completed": 2, "failed": 0}},
        "connections": {"open": {"control": 3, "metrics": 1},
                        "refused": {"control": 2, "metrics": 0},
                        "dropped": {"idle": 4, "too_large": 1, "budget": 1,
                                    "slow_reader": 1, "room": 7},
                        "events_dropped": 12},
    }


def parse(snapshot: dict) -> dict:
    text = generate_latest(make_registry(lambda: snapshot)).decode()
    return {f.name: f for f in text_string_to_metric_families(text)}


def test_every_spec_is_exported_with_its_type() -> None:
    families = parse(full_snapshot())
    for spec in SPECS:
        # The text format (0.0.4) renders info and stateset families as gauges.
        name = {"counter": spec.name.removesuffix("_total"),
                "info": f"{spec.name}_info"}.get(spec.kind, spec.name)
        assert name in families, spec.name
        expected = "gauge" if spec.kind in ("info", "stateset") else spec.kind
        assert families[name].type == expected, spec.name


def test_names_follow_conventions() -> None:
    for spec in SPECS:
        assert spec.name.startswith("hostd")
        assert (spec.kind == "counter") == spec.name.endswith("_total"), spec.name
        assert spec.label != "job", "job ids only in the info metric"
    unit_names = [s.name for s in SPECS if s.kind in ("gauge", "histogram") and s.label is None]
    assert any(n.endswith(UNITS) for n in unit_names)


def test_values_come_from_the_snapshot() -> None:
    snap = full_snapshot()
    fam = parse(snap)
    assert fam["hostd_serial_lines_sent"].samples[0].value == 120
    assert fam["hostd_job_filament_used_meters"].samples[0].value == pytest.approx(2.5)
    temps = {s.labels["heater"]: s.value for s in fam["hostd_temperature_celsius"].samples}
    assert temps == {"T": 209.5, "B": 60.1}
    targets = {s.labels["heater"]: s.value
               for s in fam["hostd_temperature_target_celsius"].samples}
    assert targets == {"T": 210.0, "B": 60.0}
    axes = {s.labels["axis"]: s.value for s in fam["hostd_axis_position_degrees"].samples}
    assert axes == {"A": 45.0, "C": -90.0}
    state = {s.labels["state"]: s.value for s in fam["hostd_job_state"].samples}
    assert state["printing"] == 1 and sum(state.values()) == 1
    link = {s.labels["state"]: s.value for s in fam["hostd_serial_link_state"].samples}
    assert link == {"disconnected": 0, "handshake": 0, "ready": 0, "halted": 1}
    jobs = {s.labels["state"]: s.value for s in fam["hostd_jobs"].samples}
    assert jobs["slicing"] == 1 and jobs["completed"] == 4
    assert fam["hostd_serial_firmware_resets"].samples[0].value == 1
    assert fam["hostd_slicing_failures"].samples[0].value == 2
    rtt = {s.labels.get("le"): s.value for s in fam["hostd_serial_ok_roundtrip_seconds"].samples
           if s.name.endswith("_bucket")}
    assert rtt == {"0.01": 1, "0.1": 2, "+Inf": 3}


def test_state_gauges_are_labelled_state_as_documented() -> None:
    """One gauge per state with the label ``state`` (the README's), 1 for the current one;
    nothing yet is the first state (idle), a state not listed sets none."""
    from hostd.metrics.docs import render_markdown

    rows = {line.split("|")[1].strip(" `"): line for line in render_markdown().splitlines()}
    for name in ("hostd_job_state", "hostd_serial_link_state"):
        assert "| state |" in rows[name]
        fam = parse({"jobs": {"latest": None}, "link": {"state": "handshake"}})[name]
        assert {s.name for s in fam.samples} == {name}
        assert {tuple(s.labels) for s in fam.samples} == {("state",)}
    job = {s.labels["state"]: s.value for s in parse({})["hostd_job_state"].samples}
    assert job["idle"] == 1 and sum(job.values()) == 1
    assert not {"queued", "slicing", "ready"} & set(job), "a job on the printer never is"
    odd = parse({"link": {"state": "rebooting"}})["hostd_serial_link_state"]
    assert sum(s.value for s in odd.samples) == 0


def test_units_are_declared_in_openmetrics() -> None:
    from prometheus_client.openmetrics.exposition import generate_latest as om_latest
    from prometheus_client.openmetrics.parser import text_string_to_metric_families as om_parse

    text = om_latest(make_registry(full_snapshot)).decode()
    units = {f.name: f.unit for f in om_parse(text)}
    assert units["hostd_job_elapsed_seconds"] == "seconds"
    assert units["hostd_temperature_celsius"] == "celsius"
    assert units["hostd_job_progress_ratio"] == "ratio"
    assert units["hostd_serial_lines_sent"] == ""


def test_missing_values_are_left_out_not_invented() -> None:
    fam = parse({"link": {"connected": False}})
    assert fam["hostd_serial_link_up"].samples[0].value == 0
    assert "hostd_serial_lines_sent" not in fam
    assert "hostd_job_progress_ratio" not in fam


def test_lookup_walks_dotted_paths() -> None:
    assert lookup({"a": {"b": {"c": 3}}}, "a.b.c") == 3
    assert lookup({"a": {"b": 1}}, "a.b.c") is None
    assert lookup({}, "x") is None


@pytest.mark.asyncio
async def test_http_endpoint_reads_snapshot_on_the_loop() -> None:
    calls: list[int] = []

    def snapshot() -> dict:
        calls.append(1)
        return full_snapshot()

    server = MetricsServer("127.0.0.1", 0, snapshot)
    server.start()
    try:
        url = f"http://127.0.0.1:{server.port}/metrics"
        async with asyncio.timeout(20):
            body = await asyncio.to_thread(lambda: urllib.request.urlopen(url, timeout=10).read())
        names = {f.name for f in text_string_to_metric_families(body.decode())}
        assert "hostd_job_progress_ratio" in names
        assert calls and server.status()["scrapes"] == len(calls) - 1  # and one at start
    finally:
        server.stop()


async def scrape_families(server: MetricsServer) -> dict:
    url = f"http://127.0.0.1:{server.port}/metrics"
    async with asyncio.timeout(20):
        body = await asyncio.to_thread(lambda: urllib.request.urlopen(url, timeout=10).read())
    return {f.name: f for f in text_string_to_metric_families(body.decode())}


def finished(fams: dict) -> dict[str, float]:
    return {s.labels["outcome"]: s.value for s in fams["hostd_jobs_finished"].samples
            if s.name == "hostd_jobs_finished_total"}


@pytest.mark.asyncio
async def test_jobs_finished_counts_this_run_only_and_never_goes_down() -> None:
    """The job manager's figures start from the database's rows; the counter starts at 0
    and only grows, even when the source drops (a job deleted, then hostd restarted)."""
    source = {"completed": 4, "failed": 1, "cancelled": 0, "interrupted": 2}
    snap = {"daemon": {"uptime_s": 12.5}, "jobs": {"finished": source}}
    server = MetricsServer("127.0.0.1", 0, lambda: snap)
    server.start()
    try:
        fams = await scrape_families(server)
        assert finished(fams) == {"completed": 0, "failed": 0, "cancelled": 0,
                                  "interrupted": 0}
        started = fams["hostd_start_time_seconds"].samples[0].value
        assert abs(started - (time.time() - 12.5)) < 60
        source["completed"] = 5
        assert finished(await scrape_families(server))["completed"] == 1
        source["completed"] = 1  # rows deleted: the source went down
        assert finished(await scrape_families(server))["completed"] == 1
        source["completed"] = 2
        fams = await scrape_families(server)
        assert finished(fams)["completed"] == 2
        assert fams["hostd_start_time_seconds"].samples[0].value == started
        assert server.status()["jobs_finished"]["completed"] == 2
    finally:
        server.stop()
