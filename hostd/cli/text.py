"""Operator text of what the daemon sends: names on one line, events as ``key=value``."""

from __future__ import annotations

import unicodedata
from typing import Any

from hostd.control.text import CONTROL_CATEGORIES, control_character


def printable(text: Any) -> str:
    """``text`` on one line: control characters escaped (``\\n``, ``\\x1b``), as a name
    stored before the daemon refused them would otherwise break the listing."""
    text = str(text)
    if control_character(text) is None:
        return text
    return "".join(ch.encode("unicode_escape").decode("ascii")
                   if unicodedata.category(ch) in CONTROL_CATEGORIES else ch for ch in text)


def event_text(event: str, data: dict[str, Any]) -> str:
    """One line for an event: ``printer.temperatures T 44.9/0.0 B 23.0/60.0``, else
    ``job.state job_id=2 old=queued new=ready`` (fields without a value left out)."""
    if event == "printer.temperatures":
        return f"{event} {value_text(data.get('heaters') or {}, nested=False)}".rstrip()
    fields = [f"{key}={value_text(value)}" for key, value in data.items()
              if key != "event" and value not in (None, "")]
    return " ".join([event, *fields])


def value_text(value: Any, nested: bool = True) -> str:
    """A value as an operator reads it: numbers to 3 decimals, a heater as actual/target,
    a mapping as ``(X 1.5 Y 2)`` (without the parentheses unless ``nested``), a list
    comma-separated, ``yes``/``no``, ``-`` for none."""
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return _number(value)
    if isinstance(value, dict):
        if "actual" in value and "target" in value:
            return f"{_degrees(value['actual'])}/{_degrees(value['target'])}"
        inner = " ".join(f"{printable(k)} {value_text(v)}" for k, v in value.items())
        return f"({inner})" if nested else inner
    if isinstance(value, list | tuple):
        return ",".join(value_text(v) for v in value)
    return printable(value)


def _number(value: float) -> str:
    text = f"{value:.3f}".rstrip("0").rstrip(".")
    return "0" if text == "-0" else text


def _degrees(value: Any) -> str:
    """A temperature to 0.1 °C (``-`` when the board gave none)."""
    return f"{value:.1f}" if isinstance(value, int | float) else "-"
