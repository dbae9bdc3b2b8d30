"""Load and validate the YAML configuration against :data:`hostd.config.schema.SCHEMA`.

Every problem is fatal and reported as one line, ``FILE:LINE: KEY: REASON``. Keys left out take
their schema default, so a config file only states what differs from the default machine.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from hostd.config.fields import FieldError
from hostd.config.placeholders import SCRIPT_KEYS, filled, script_problem
from hostd.config.schema import SCHEMA
from slicer.settings import MAX_BEAD_SHARE


class ConfigError(Exception):
    """A configuration file that cannot be used; ``str()`` is the one-line report."""


@dataclass(frozen=True)
class Config(Mapping[str, Any]):
    """Validated configuration: dotted keys (``machine.a_limits``) to typed values."""

    data: Mapping[str, Any]  # (named as UserDict's: a field "values" hid Mapping.values())
    source: str = "<defaults>"

    def __getitem__(self, key: str) -> Any:
        return self.data[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self.data)

    def __len__(self) -> int:
        return len(self.data)

    def section(self, name: str) -> dict[str, Any]:
        """All keys of one section, without the section prefix."""
        if name not in SCHEMA:
            raise KeyError(name)
        return {k: self.data[f"{name}.{k}"] for k in SCHEMA[name]}

    def replace(self, **dotted: Any) -> Config:
        """A copy with some values replaced (keys given with ``__`` for the dot)."""
        new = dict(self.data)
        for k, v in dotted.items():
            key = k.replace("__", ".")
            if key not in new:
                raise KeyError(key)
            new[key] = v
        return Config(new, self.source)


def defaults() -> Config:
    """The configuration every omitted key falls back to."""
    return Config({f"{s}.{k}": f.default for s, fs in SCHEMA.items() for k, f in fs.items()})


def load(path: str | Path) -> Config:
    """Read and validate ``path``; raise :class:`ConfigError` naming file, line and key."""
    name = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{name}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{name}: cannot read: {exc}") from None
    return loads(text, name)


def loads(text: str, name: str = "<string>") -> Config:
    """Validate YAML ``text``; ``name`` is the file name used in error messages."""
    root = _compose(text, name)
    values = dict(defaults().data)
    if root is None:
        return Config(values, name)
    if not isinstance(root, yaml.MappingNode):
        raise ConfigError(f"{name}:{_line(root)}: the top level must be a mapping of sections")
    for sec_key, sec_node in _pairs(root, name, ""):
        if sec_key not in SCHEMA:
            known = ", ".join(SCHEMA)
            raise ConfigError(f"{name}:{_line(sec_key)}: {sec_key}: unknown section "
                              f"(known: {known})")
        values.update(_section(name, str(sec_key), sec_node))
    config = Config(values, name)
    _cross_checks(config, name, root)
    return config


class _Key(str):
    """A mapping key that remembers its line."""

    line: int


def _line(node: yaml.Node | _Key) -> int:
    if isinstance(node, _Key):
        return node.line
    return node.start_mark.line + 1


def _compose(text: str, name: str) -> yaml.Node | None:
    try:
        return yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = mark.line + 1 if mark else 0
        raise ConfigError(f"{name}:{line}: invalid YAML: {exc.problem or exc}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{name}: invalid YAML: {exc}") from None


def _pairs(node: yaml.MappingNode, name: str, prefix: str) -> Iterator[tuple[_Key, yaml.Node]]:
    seen: set[str] = set()
    for k, v in node.value:
        if not isinstance(k, yaml.ScalarNode):
            raise ConfigError(f"{name}:{_line(k)}: {prefix}keys must be plain names")
        key = _Key(k.value)
        key.line = _line(k)
        if key in seen:
            raise ConfigError(f"{name}:{key.line}: {prefix}{key}: duplicate key")
        seen.add(key)
        yield key, v


def _section(name: str, section: str, node: yaml.Node) -> dict[str, Any]:
    if isinstance(node, yaml.ScalarNode) and node.tag.endswith(":null"):
        return {}
    if not isinstance(node, yaml.MappingNode):
        raise ConfigError(f"{name}:{_line(node)}: {section}: expected a mapping of keys")
    fields = SCHEMA[section]
    out: dict[str, Any] = {}
    for key, value in _pairs(node, name, f"{section}."):
        dotted = f"{section}.{key}"
        if key not in fields:
            raise ConfigError(f"{name}:{key.line}: {dotted}: unknown key "
                              f"(known in {section}: {', '.join(fields)})")
        try:
            out[dotted] = fields[key].parse(value)
        except FieldError as exc:
            at = exc.node if exc.node is not None else value
            raise ConfigError(f"{name}:{_line(at)}: {dotted}: {exc}") from None
    return out


def _key_line(root: yaml.MappingNode, dotted: str) -> int:
    """Line of ``dotted`` in the file, or 0 when it was left at its default."""
    section, _, key = dotted.partition(".")
    for k, v in root.value:
        if k.value == section and isinstance(v, yaml.MappingNode):
            for kk, vv in v.value:
                if kk.value == key:
                    return _line(vv)
    return 0


def _cross_checks(config: Config, name: str, root: yaml.MappingNode) -> None:
    for dotted, reason in _problems(config):
        line = _key_line(root, dotted)  # 0: the key keeps its default (the other one is set)
        raise ConfigError(f"{name}:{line}: {dotted}: {reason}" if line
                          else f"{name}: {dotted}: {reason}")


def _script_gcode(c: Config, key: str) -> str | None:
    """What the firmware or hostd would refuse in a start/end script, filled (one line)."""
    from hostd.printer.envelope import envelope_from_config
    from hostd.printer.errors import ProgramError
    from hostd.printer.program import parse_program

    try:
        program = parse_program(filled(c, c[key]))
        envelope_from_config(c.data).check_temperatures(program)
    except ProgramError as exc:
        return f"script {exc}"
    except ValueError as exc:  # a format spec that does not suit its value
        return str(exc)
    return None


def _problems(c: Config) -> Iterator[tuple[str, str]]:
    if c["daemon.max_request_bytes"] > c["daemon.max_buffered_bytes"]:
        yield "daemon.max_buffered_bytes", (f"{c['daemon.max_buffered_bytes']} is below "
                                            "daemon.max_request_bytes "
                                            f"({c['daemon.max_request_bytes']})")
    if c["serial.reconnect_min"] > c["serial.reconnect_max"]:
        yield "serial.reconnect_min", (f"{c['serial.reconnect_min']:g} is above "
                                       f"serial.reconnect_max ({c['serial.reconnect_max']:g})")
    segs = c["printhead.segments"]
    for i, s in enumerate(segs):
        if s["end"] <= s["start"]:
            yield "printhead.segments", f"item {i}: end {s['end']:g} is not above start"
        if i and s["start"] != segs[i - 1]["end"]:
            yield "printhead.segments", f"item {i}: start {s['start']:g} leaves a gap"
    if segs and segs[0]["start"] != 0:
        yield "printhead.segments", "the first segment must start at the nozzle tip (0)"
    if c["sim.silence_at_line"] and not c["sim.silence_lines"]:
        yield "sim.silence_at_line", ("silences nothing with sim.silence_lines 0 (the lines to "
                                      "swallow without answer)")
    for process, machine in (("process.nozzle_temperature", "machine.max_hotend_temp"),
                             ("process.bed_temperature", "machine.max_bed_temp")):
        if c[process] > c[machine]:
            yield process, f"{c[process]:g} is above {machine} ({c[machine]:g})"
    for key in SCRIPT_KEYS:
        if (problem := script_problem(c[key]) or _script_gcode(c, key)) is not None:
            yield key, problem
    bound = c["machine.nozzle_diameter"] * MAX_BEAD_SHARE
    if c["process.line_width"] < bound:
        yield "process.line_width", (f"{c['process.line_width']:g} is narrower than 0.8 × "
                                     f"machine.nozzle_diameter ({bound:g})")
    if c["process.layer_height"] > bound:
        yield "process.layer_height", (f"{c['process.layer_height']:g} is above 0.8 × "
                                       f"machine.nozzle_diameter ({bound:g})")
