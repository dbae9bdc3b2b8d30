"""The ``{placeholders}`` of the start and end scripts (``process.start_gcode`` /
``end_gcode``), checked when the config is loaded.

The slicer fills both scripts from the process settings and ``{safe_z}``; the daemon fills the
end script the same way when a job is cancelled. A placeholder neither knows would otherwise
fail only then: at slicing time, or halfway through a print at its cancel. No numpy here:
the daemon and ``--check-config`` import this.
"""

from __future__ import annotations

import string
from dataclasses import fields
from typing import TYPE_CHECKING, Any

from slicer.settings import ProcessSettings

if TYPE_CHECKING:
    from hostd.config.loader import Config

SCRIPT_KEYS = ("process.start_gcode", "process.end_gcode")
MACHINE_PROCESS_KEYS = ("nozzle_diameter", "filament_diameter", "max_velocity", "max_accel",
                        "max_rotary_velocity", "max_rotary_accel", "linearize_tolerance")
"""ProcessSettings fields set from ``machine.*`` rather than ``process.*``."""


def known_names() -> frozenset[str]:
    """Every placeholder a script may use: the process settings' fields (the scripts
    themselves aside) and ``safe_z``."""
    scripts = {key.split(".", 1)[1] for key in SCRIPT_KEYS}
    return frozenset(f.name for f in fields(ProcessSettings)) - scripts | {"safe_z"}


def process_values(cfg: Config) -> dict[str, Any]:
    """The ProcessSettings field values of a config (``process.*`` and the extrusion and
    motion keys of ``machine.*``), as plain values."""
    names = {f.name for f in fields(ProcessSettings)}
    values = {k: v for k, v in cfg.section("process").items() if k in names}
    values.update({k: cfg[f"machine.{k}"] for k in MACHINE_PROCESS_KEYS})
    return values


def script_problem(template: str) -> str | None:
    """What is wrong with ``template``'s placeholders (one line), or ``None``."""
    known = known_names()
    try:
        parsed = list(string.Formatter().parse(template))
    except ValueError as exc:  # a lone { or }
        return f"{exc} (write {{{{ and }}}} for literal braces)"
    for _, field, _, _ in parsed:
        if field is None:
            continue
        if field not in known:
            return (f"unknown placeholder {{{field}}} (a bare name of: "
                    f"{', '.join(sorted(known))})")
    return None


def filled(cfg: Config, template: str) -> str:
    """``template`` with its placeholders filled as a print would (``{safe_z}`` 0.0, a
    float as the slicer and the daemon's cancel give it); raises :class:`ValueError` naming
    the placeholder when its format spec does not suit its value (``{safe_z:x}``)."""
    values = {**process_values(cfg), "safe_z": 0.0}
    for _, field, spec, conversion in string.Formatter().parse(template):
        if field is None:
            continue
        try:
            ("{0" + (f"!{conversion}" if conversion else "") + f":{spec}}}").format(
                values[field])
        except (ValueError, TypeError) as exc:
            raise ValueError(f"placeholder {{{field}:{spec}}}: {exc}") from None
        except (KeyError, IndexError):  # {safe_z:{width}}
            raise ValueError(f"placeholder {{{field}:{spec}}}: a format spec cannot hold a "
                             "placeholder") from None
    return template.format_map(values)
