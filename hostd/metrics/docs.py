"""Render the metrics table of the README from :data:`hostd.metrics.specs.SPECS`."""

from __future__ import annotations

from hostd.metrics.specs import SPECS

_EXPOSED = {"info": "info (`{name}_info`)", "stateset": "gauge (one per state, 1: the current one)"}


def render_markdown() -> str:
    rows = ["| metric | type | unit | labels | meaning |", "|---|---|---|---|---|"]
    for s in SPECS:
        kind = _EXPOSED.get(s.kind, s.kind).format(name=s.name)
        labels = s.label or ""
        rows.append(f"| `{s.name}` | {kind} | {s.unit} | {labels} | {s.doc} |")
    return "\n".join(rows) + "\n"
