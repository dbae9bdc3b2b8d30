"""Field types of the configuration schema: each parses one YAML node or says why not.

A field never warns: a value it cannot accept raises :class:`FieldError` with a short reason,
which the loader turns into ``file:line: key: reason``.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import yaml


class FieldError(ValueError):
    """A value that does not fit its field; the message is the reason, without the key.

    ``node`` is the YAML node at fault when it is more precise than the whole value (an item
    of a list), so the loader can name its line.
    """

    def __init__(self, message: str, node: yaml.Node | None = None) -> None:
        super().__init__(message)
        self.node = node


def _scalar(node: yaml.Node) -> Any:
    if not isinstance(node, yaml.ScalarNode):
        raise FieldError(f"expected a single value, got a {_kind(node)}")
    return yaml.safe_load(yaml.serialize(node))


def _kind(node: yaml.Node) -> str:
    if isinstance(node, yaml.MappingNode):
        return "mapping"
    if isinstance(node, yaml.SequenceNode):
        return "list"
    return "value"


def _fmt(x: float) -> str:
    """A bound or value as written: whole numbers in full (``2147483647``, not
    ``2.14748e+09``), others as short as they go."""
    if float(x).is_integer() and abs(x) < 1e15:
        return str(int(x))
    return f"{x:g}"


def _number(value: Any, integer: bool) -> float | int:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise FieldError(f"{value!r} is not {'an integer' if integer else 'a number'}")
    if integer and not isinstance(value, int):
        raise FieldError(f"{value!r} is not an integer")
    if not math.isfinite(value):
        raise FieldError(f"{value!r} is not a finite number")
    return value if integer else float(value)


def _bounded(x: float, lo: float | None, hi: float | None) -> None:
    if lo is not None and x < lo:
        raise FieldError(f"{_fmt(x)} is below {_fmt(lo)}")
    if hi is not None and x > hi:
        raise FieldError(f"{_fmt(x)} is above {_fmt(hi)}")


@dataclass(frozen=True)
class Field:
    """Base of every field: its documentation, default and whether null is accepted."""

    doc: str
    default: Any = None
    nullable: bool = False

    def parse(self, node: yaml.Node) -> Any:
        if isinstance(node, yaml.ScalarNode) and node.tag.endswith(":null"):
            if self.nullable:
                return None
            raise FieldError("must not be empty")
        return self.convert(node)

    def convert(self, node: yaml.Node) -> Any:  # pragma: no cover - abstract
        raise NotImplementedError

    def describe(self) -> str:
        return "any"


@dataclass(frozen=True)
class Number(Field):
    lo: float | None = None
    hi: float | None = None
    integer: bool = False

    def convert(self, node: yaml.Node) -> float | int:
        x = _number(_scalar(node), self.integer)
        _bounded(x, self.lo, self.hi)
        return x

    def describe(self) -> str:
        kind = "integer" if self.integer else "number"
        lo = "-inf" if self.lo is None else _fmt(self.lo)
        hi = "inf" if self.hi is None else _fmt(self.hi)
        return f"{kind} in [{lo}, {hi}]"


@dataclass(frozen=True)
class Flag(Field):
    def convert(self, node: yaml.Node) -> bool:
        value = _scalar(node)
        if not isinstance(value, bool):
            raise FieldError(f"{value!r} is not true or false")
        return value

    def describe(self) -> str:
        return "true | false"


@dataclass(frozen=True)
class Text(Field):
    """A string; ``path`` asks for a non-blank one of at most ``max_bytes`` (UTF-8)."""

    choices: Sequence[str] = ()
    multiline: bool = False
    path: bool = False
    max_bytes: int | None = None

    def convert(self, node: yaml.Node) -> str:
        value = _scalar(node)
        if not isinstance(value, str):
            raise FieldError(f"{value!r} is not a string")
        if self.choices and value not in self.choices:
            raise FieldError(f"{value!r} is not one of {', '.join(self.choices)}")
        if not self.multiline and "\n" in value.strip():
            raise FieldError("must be a single line")
        if self.path:
            _check_path(value, self.max_bytes)
        return value

    def describe(self) -> str:
        if self.choices:
            return " | ".join(self.choices)
        if self.path:
            return "path" + (f" of at most {self.max_bytes} bytes" if self.max_bytes else "")
        return "string"


def _check_path(value: str, max_bytes: int | None) -> None:
    if not value.strip():
        raise FieldError("must not be empty (a path)")
    size = len(value.encode("utf-8", "surrogateescape"))
    if max_bytes is not None and size > max_bytes:
        raise FieldError(f"{value!r} is {size} bytes long, more than the {max_bytes} a "
                         "Unix socket path may have")


@dataclass(frozen=True)
class Vector(Field):
    """A fixed-length list of numbers, each within [lo, hi]; ``ordered`` asks for ascending."""

    length: int = 3
    lo: float | None = None
    hi: float | None = None
    ordered: bool = False

    def convert(self, node: yaml.Node) -> tuple[float, ...]:
        if not isinstance(node, yaml.SequenceNode):
            raise FieldError(f"expected a list of {self.length} numbers, got a {_kind(node)}")
        if len(node.value) != self.length:
            raise FieldError(f"expected {self.length} numbers, got {len(node.value)}")
        xs = tuple(float(_number(_scalar(n), False)) for n in node.value)
        for x in xs:
            _bounded(x, self.lo, self.hi)
        if self.ordered and any(b < a for a, b in itertools.pairwise(xs)):
            raise FieldError(f"{list(xs)} must be in ascending order")
        return xs

    def describe(self) -> str:
        lo = "-inf" if self.lo is None else _fmt(self.lo)
        hi = "inf" if self.hi is None else _fmt(self.hi)
        order = ", ascending" if self.ordered else ""
        return f"list of {self.length} numbers in [{lo}, {hi}]{order}"


@dataclass(frozen=True)
class Records(Field):
    """A list of mappings with fixed numeric keys (e.g. printhead segments)."""

    keys: tuple[str, ...] = ()
    lo: float | None = 0.0
    hi: float | None = None
    min_items: int = 1
    item_fields: dict[str, Number] = field(default_factory=dict)

    def convert(self, node: yaml.Node) -> tuple[dict[str, float], ...]:
        if not isinstance(node, yaml.SequenceNode):
            raise FieldError(f"expected a list of mappings, got a {_kind(node)}")
        if len(node.value) < self.min_items:
            raise FieldError(f"needs at least {self.min_items} item(s)")
        return tuple(self._item(i, n) for i, n in enumerate(node.value))

    def _item(self, i: int, node: yaml.Node) -> dict[str, float]:
        if not isinstance(node, yaml.MappingNode):
            raise FieldError(f"item {i}: expected a mapping with {', '.join(self.keys)}", node)
        got = {_scalar(k): v for k, v in node.value}
        missing = [k for k in self.keys if k not in got]
        extra = [str(k) for k in got if k not in self.keys]
        if missing or extra:
            what = f"missing {', '.join(missing)}" if missing else f"unknown {', '.join(extra)}"
            raise FieldError(f"item {i}: {what} (keys: {', '.join(self.keys)})", node)
        out = {}
        for k in self.keys:
            try:
                out[k] = float(_number(_scalar(got[k]), False))
                _bounded(out[k], self.lo, self.hi)
            except FieldError as exc:
                raise FieldError(f"item {i}: {k}: {exc}", got[k]) from None
        return out

    def describe(self) -> str:
        return f"list of {{{', '.join(self.keys)}}}"
