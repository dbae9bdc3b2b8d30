"""hostctl watch: operator text of every event (no Python reprs); --json as sent."""

from __future__ import annotations

import argparse
import json
from collections.abc import Iterator
from typing import Any

import pytest

from hostd.cli import cmd_control

EVENTS: list[dict[str, Any]] = [
    {"event": "printer.temperatures",
     "heaters": {"T": {"actual": 44.88, "target": 0.0, "power": 0.0},
                 "B": {"actual": 23.0, "target": 60.0}}},
    {"event": "subpart_started", "job_id": 1, "subpart": 1, "parent": 0, "a": -48.491,
     "c": -85.90364, "line": 1234,
     "pose": {"X": 255.472, "Y": 282.172, "Z": 133.364, "A": -48.491, "C": -85.90364}},
    {"event": "job.state", "job_id": 2, "name": "a\nb.gcode", "old": "queued",
     "new": "ready", "reason": ""},
    {"event": "queue.state", "held": False, "reason": None},
    {"event": "job.progress", "job_id": 2, "progress": 0.4231234, "eta_s": None,
     "subpart": None, "layer": 3, "elapsed_s": 12.5},
]


class EventClient:
    """Subscribes, then yields :data:`EVENTS` as the daemon would push them."""

    def __enter__(self) -> EventClient:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def call(self, method: str, **params: object) -> dict[str, Any]:
        assert method == "events.subscribe"
        return {"subscribed": "all"}

    def events(self) -> Iterator[tuple[str, dict[str, Any]]]:
        for data in EVENTS:
            yield str(data["event"]), data


def watch(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
          as_json: bool) -> list[str]:
    monkeypatch.setattr(cmd_control, "_client", lambda args, timeout=None: EventClient())
    assert cmd_control.cmd_watch(argparse.Namespace(json=as_json)) == 0
    return capsys.readouterr().out.splitlines()


def test_watch_prints_operator_text(monkeypatch, capsys) -> None:
    assert watch(monkeypatch, capsys, as_json=False) == [
        "printer.temperatures T 44.9/0.0 B 23.0/60.0",
        "subpart_started job_id=1 subpart=1 parent=0 a=-48.491 c=-85.904 line=1234 "
        "pose=(X 255.472 Y 282.172 Z 133.364 A -48.491 C -85.904)",
        "job.state job_id=2 name=a\\nb.gcode old=queued new=ready",
        "queue.state held=no",
        "job.progress job_id=2 progress=0.423 layer=3 elapsed_s=12.5",
    ]


def test_watch_json_prints_the_events_as_sent(monkeypatch, capsys) -> None:
    lines = watch(monkeypatch, capsys, as_json=True)
    assert [json.loads(line) for line in lines] == EVENTS
