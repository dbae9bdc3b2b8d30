"""A prometheus-client collector that renders :data:`hostd.metrics.specs.SPECS` from a snapshot.

The collector calls ``snapshot()`` once per scrape and yields metric families built with
prometheus-client's own classes; a value missing from the snapshot is simply not exported.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping
from typing import Any

from prometheus_client.core import (
    CounterMetricFamily,
    GaugeMetricFamily,
    HistogramMetricFamily,
    InfoMetricFamily,
    Metric,
)
from prometheus_client.registry import Collector, CollectorRegistry

from hostd.metrics.specs import SPECS, Spec

Snapshot = Mapping[str, Any]


def lookup(snapshot: Snapshot, path: str) -> Any:
    """The value at a dotted path, or ``None`` where any step is missing."""
    node: Any = snapshot
    for part in path.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return None
        node = node[part]
    return node


def _number(value: Any) -> float | None:
    if isinstance(value, bool):
        return float(value)
    if isinstance(value, int | float) and math.isfinite(value):
        return float(value)
    return None


def _family(spec: Spec, value: Any) -> Metric | None:
    builder = _BUILDERS[spec.kind]
    return builder(spec, value)


def _scalar_family(spec: Spec, value: Any) -> Metric | None:
    cls = CounterMetricFamily if spec.kind == "counter" else GaugeMetricFamily
    if spec.label is None:
        x = _number(value)
        return None if x is None else cls(spec.name, spec.doc, value=x * spec.scale,
                                          unit=spec.unit)
    if not isinstance(value, Mapping):
        return None
    fam = cls(spec.name, spec.doc, labels=[spec.label], unit=spec.unit)
    for key, raw in _labelled(spec, value):
        x = _number(raw)
        if x is not None:
            fam.add_metric([key], x * spec.scale)
    return fam


def _labelled(spec: Spec, value: Mapping[str, Any]) -> Iterator[tuple[str, Any]]:
    """(label value, raw number) pairs of a dict-valued path, per ``keys`` and ``field``."""
    keys = spec.keys if spec.keys is not None else sorted(str(k) for k in value)
    for key in keys:
        raw = value.get(key)
        if spec.field is not None:
            raw = raw.get(spec.field) if isinstance(raw, Mapping) else None
        yield key, raw


def _histogram_family(spec: Spec, value: Any) -> Metric | None:
    if not isinstance(value, Mapping) or "buckets" not in value:
        return None
    buckets = [(_le(le), float(n)) for le, n in value["buckets"]]
    return HistogramMetricFamily(spec.name, spec.doc, buckets=buckets,
                                 sum_value=float(value.get("sum", 0.0)), unit=spec.unit)


def _le(bound: float | str) -> str:
    if isinstance(bound, str) or math.isinf(bound):
        return "+Inf"
    return f"{bound:g}"


def _info_family(spec: Spec, value: Any) -> Metric | None:
    if not isinstance(value, Mapping):
        return None
    labels = {str(k): "" if v is None else str(v) for k, v in value.items()}
    return InfoMetricFamily(spec.name, spec.doc, value=labels)


def _stateset_family(spec: Spec, value: Any) -> Metric | None:
    """One gauge per state, labelled ``spec.label`` (``state``), 1 for the current one.

    Exported as a gauge: OpenMetrics' stateset type would name the label after the metric
    (``hostd_job_state="printing"``), not ``state`` as the README documents."""
    states = spec.keys or ()
    current = states[0] if value is None and states else str(value)
    fam = GaugeMetricFamily(spec.name, spec.doc, labels=[spec.label or "state"])
    for state in states:
        fam.add_metric([state], 1.0 if state == current else 0.0)
    return fam


_BUILDERS: dict[str, Callable[[Spec, Any], Metric | None]] = {
    "gauge": _scalar_family,
    "counter": _scalar_family,
    "histogram": _histogram_family,
    "info": _info_family,
    "stateset": _stateset_family,
}


class SnapshotCollector(Collector):
    """Exports :data:`SPECS` from ``snapshot()``, called once per scrape."""

    def __init__(self, snapshot: Callable[[], Snapshot]) -> None:
        self._snapshot = snapshot

    def collect(self) -> Iterator[Metric]:
        snap = self._snapshot()
        for spec in SPECS:
            family = _family(spec, lookup(snap, spec.path))
            if family is not None:
                yield family


def make_registry(snapshot: Callable[[], Snapshot]) -> CollectorRegistry:
    """A registry holding only hostd's collector (no process/platform defaults)."""
    registry = CollectorRegistry(auto_describe=False)
    registry.register(SnapshotCollector(snapshot))
    return registry
