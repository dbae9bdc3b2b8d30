from __future__ import annotations

import json
import re
from pathlib import Path

from hostd.metrics.specs import SPECS

ROOT = Path(__file__).resolve().parents[2]


def _exported_names() -> set[str]:
    names: set[str] = set()
    for s in SPECS:
        if s.kind == "histogram":
            names |= {f"{s.name}_bucket", f"{s.name}_sum", f"{s.name}_count"}
        elif s.kind == "info":
            names.add(f"{s.name}_info")
        else:
            names.add(s.name)
    return names


def test_dashboard_queries_only_metrics_we_export() -> None:
    dash = json.loads((ROOT / "docs" / "grafana-dashboard.json").read_text())
    exported = _exported_names()
    used = set()
    for panel in dash["panels"]:
        for target in panel["targets"]:
            used |= set(re.findall(r"\bhostd_[a-z_]+", target["expr"]))
    assert used, "the dashboard queries nothing"
    assert used <= exported, used - exported
    titles = " ".join(p["title"].lower() for p in dash["panels"])
    for topic in ("progress", "temperature", "link", "a / c"):
        assert topic in titles
