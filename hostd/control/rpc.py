"""JSON-RPC 2.0: message framing and the declarative endpoint registry.

Every exception a handler raises is turned into a JSON-RPC error by :func:`error_for`, using
the single table :data:`hostd.control.errors.ERROR_CODES`; nothing else in the daemon picks
error codes (the numbers themselves are :mod:`hostd.control.codes`).
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any

from hostd.control.codes import (
    INTERNAL_ERROR,
    INVALID_PARAMS,
    INVALID_REQUEST,
    METHOD_NOT_FOUND,
    PARSE_ERROR,
    RpcError,
)
from hostd.control.errors import ERROR_CODES
from hostd.control.text import control_character

log = logging.getLogger(__name__)


def error_for(exc: BaseException) -> dict[str, Any]:
    """The JSON-RPC ``error`` object for ``exc``; unknown exceptions become internal errors."""
    if isinstance(exc, RpcError):
        err: dict[str, Any] = {"code": exc.code, "message": exc.message}
        if exc.data is not None:
            err["data"] = exc.data
        return err
    for cls, code in ERROR_CODES:
        if isinstance(exc, cls):
            return {"code": code, "message": str(exc) or cls.__name__}
    log.error("internal error", exc_info=exc)
    return {"code": INTERNAL_ERROR, "message": f"internal error: {type(exc).__name__}"}


# -- the registry ----------------------------------------------------------------------------

INT_LIMIT = 1 << 63
"""Integer params are 64-bit, as the job database stores them."""

_TYPES: dict[str, tuple[type, ...]] = {
    "int": (int,), "number": (int, float), "str": (str,), "bool": (bool,),
    "list": (list,), "dict": (dict,),
}


@dataclass(frozen=True)
class Param:
    """One named parameter: JSON type (``int``, ``number``, ``str``, ``bool``, ``list``,
    ``dict``), whether it is required, its default, and allowed values."""

    name: str
    type: str
    required: bool = True
    default: Any = None
    choices: tuple[Any, ...] | None = None
    doc: str = ""
    line: bool = False
    """A string shown as one line of text (a job name): no control characters."""
    arg: str | None = None
    """The handler's keyword for it, where the name cannot be one (``from``)."""

    def check(self, value: Any) -> Any:
        types = _TYPES[self.type]
        if isinstance(value, bool) and bool not in types:
            raise RpcError(INVALID_PARAMS, f"{self.name}: expected {self.type}, got bool")
        if value is None and not self.required:
            return self.default
        if not isinstance(value, types):
            raise RpcError(INVALID_PARAMS,
                           f"{self.name}: expected {self.type}, got {type(value).__name__}")
        if isinstance(value, str) and not value.isascii():
            _check_text(self.name, value)
        if isinstance(value, str) and self.line:
            _check_line(self.name, value)
        if isinstance(value, int) and not -INT_LIMIT <= value < INT_LIMIT:
            raise RpcError(INVALID_PARAMS, f"{self.name}: {value} is out of range")
        if self.choices is not None and value not in self.choices:
            raise RpcError(INVALID_PARAMS, f"{self.name}: must be one of "
                           f"{', '.join(map(str, self.choices))}")
        return value


def _check_text(name: str, value: str) -> None:
    """Refuse a string UTF-8 cannot carry: a lone surrogate, which JSON's ``\\u`` escapes
    can smuggle in (it would fail later, writing a file, the database or the serial port)."""
    try:
        value.encode("utf-8")
    except UnicodeEncodeError as exc:
        raise RpcError(INVALID_PARAMS, f"{name}: not Unicode text (a lone surrogate at "
                       f"character {exc.start})") from None


def _check_line(name: str, value: str) -> None:
    at = control_character(value)
    if at is not None:
        raise RpcError(INVALID_PARAMS, f"{name}: control character {value[at]!r} at "
                       f"character {at} (it must be one line of printable text)")


Handler = Callable[..., Awaitable[Any]]


@dataclass(frozen=True)
class Endpoint:
    method: str
    handler: Handler
    params: tuple[Param, ...] = ()
    doc: str = ""

    def bind(self, params: Any) -> dict[str, Any]:
        """Validate ``params`` (object or array) into keyword arguments."""
        if params is None:
            params = {}
        if isinstance(params, list):
            if len(params) > len(self.params):
                raise RpcError(INVALID_PARAMS, f"{self.method} takes at most "
                               f"{len(self.params)} parameters")
            params = {p.name: v for p, v in zip(self.params, params, strict=False)}
        if not isinstance(params, dict):
            raise RpcError(INVALID_PARAMS, "params must be an object or an array")
        known = {p.name for p in self.params}
        extra = sorted(set(params) - known)
        if extra:
            raise RpcError(INVALID_PARAMS, f"unknown parameter(s): {', '.join(extra)}")
        out = {}
        for p in self.params:
            if p.name in params:
                out[p.arg or p.name] = p.check(params[p.name])
            elif p.required:
                raise RpcError(INVALID_PARAMS, f"missing parameter: {p.name}")
            else:
                out[p.arg or p.name] = p.default
        return out


@dataclass
class Registry:
    """Method name → :class:`Endpoint`; handlers are ``async def h(ctx, **params)``."""

    endpoints: dict[str, Endpoint] = field(default_factory=dict)

    def add(self, method: str, handler: Handler, *params: Param, doc: str = "") -> None:
        if method in self.endpoints:
            raise ValueError(f"{method} registered twice")
        self.endpoints[method] = Endpoint(method, handler, tuple(params), doc)

    def describe(self) -> list[dict[str, Any]]:
        return [{"method": e.method, "doc": e.doc,
                 "params": [{"name": p.name, "type": p.type, "required": p.required}
                            for p in e.params]}
                for e in self.endpoints.values()]

    async def dispatch(self, raw: str | bytes, ctx: Any) -> str | None:
        """One line in, one response line out (``None`` when nothing is to be answered)."""
        try:
            message = json.loads(raw)
        except (ValueError, UnicodeDecodeError) as exc:
            return encode(response(None, error={"code": PARSE_ERROR,
                                                "message": f"parse error: {exc}"}))
        except RecursionError:  # json's decoder recurses once per nested array or object
            return encode(response(None, error={"code": PARSE_ERROR,
                                                "message": "parse error: nested too deeply"}))
        if isinstance(message, list):
            if not message:
                return encode(response(None, error={"code": INVALID_REQUEST,
                                                    "message": "empty batch"}))
            replies = [r for r in [await self._one(m, ctx) for m in message] if r is not None]
            return _encode_safe(replies) if replies else None
        reply = await self._one(message, ctx)
        return None if reply is None else _encode_safe(reply)

    async def _one(self, message: Any, ctx: Any) -> dict[str, Any] | None:
        req_id = message.get("id") if isinstance(message, dict) else None
        if not _valid_id(req_id):
            req_id = None
        try:
            method, params, notify = _validate(message)
            endpoint = self.endpoints.get(method)
            if endpoint is None:
                raise RpcError(METHOD_NOT_FOUND, f"method not found: {method}")
            result = await endpoint.handler(ctx, **endpoint.bind(params))
        except Exception as exc:  # every handler failure becomes a JSON-RPC error
            error = error_for(exc)  # (an internal error is logged there)
            if isinstance(message, dict) and "id" not in message and _is_request(message):
                return None  # a notification: nobody to answer
            return response(req_id, error=error)
        return None if notify else response(req_id, result=result)


def _finite(obj: Any) -> Any:
    """``obj`` with non-finite floats as JSON-friendly values (``"+Inf"``, ``None``)."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return None if math.isnan(obj) else ("+Inf" if obj > 0 else "-Inf")
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    return obj


class Encoded(str):
    """A result already encoded as JSON text (a handler's cached answer): put in its reply
    as it is, not encoded again."""


def encoded(result: Any) -> Encoded:
    """``result`` as :class:`Encoded` JSON (non-finite numbers as :func:`_finite` has them)."""
    try:
        return Encoded(json.dumps(result, separators=(",", ":"), allow_nan=False))
    except ValueError:
        return Encoded(json.dumps(_finite(result), separators=(",", ":"), allow_nan=False))


def _spliced(message: Any) -> str | None:
    """``message`` as one line when it, or a batch of replies, holds :class:`Encoded`
    results; ``None`` when none does."""
    replies = message if isinstance(message, list) else [message]
    if not any(isinstance(r, dict) and isinstance(r.get("result"), Encoded) for r in replies):
        return None
    parts = [_splice(r) for r in replies]
    return (f"[{','.join(parts)}]" if isinstance(message, list) else parts[0]) + "\n"


def _splice(reply: Any) -> str:
    result = reply.get("result") if isinstance(reply, dict) else None
    if not isinstance(result, Encoded):
        return encode(reply)[:-1]
    return f'{{"jsonrpc":"2.0","id":{json.dumps(reply["id"])},"result":{result}}}'


def _encode_safe(message: Any) -> str:
    try:
        return _spliced(message) or encode(message)
    except (ValueError, RecursionError):
        pass
    try:
        return encode(_finite(message))
    except (TypeError, ValueError, RecursionError) as exc:  # NaN, bytes, too deep ...
        log.error("unencodable result: %s", exc)
        req_id = message.get("id") if isinstance(message, dict) else None
        return encode(response(req_id, error={"code": INTERNAL_ERROR,
                                              "message": "internal error: unencodable result"}))


def _valid_id(value: Any) -> bool:
    return value is None or (isinstance(value, (str, int)) and not isinstance(value, bool))


def _is_request(m: dict[str, Any]) -> bool:
    return m.get("jsonrpc") == "2.0" and isinstance(m.get("method"), str)


def _validate(message: Any) -> tuple[str, Any, bool]:
    if not isinstance(message, dict) or message.get("jsonrpc") != "2.0":
        raise RpcError(INVALID_REQUEST, "invalid request: not a JSON-RPC 2.0 object")
    method = message.get("method")
    if not isinstance(method, str):
        raise RpcError(INVALID_REQUEST, "invalid request: method must be a string")
    if "id" in message and not _valid_id(message["id"]):
        raise RpcError(INVALID_REQUEST, "invalid request: id must be a string, number or null")
    return method, message.get("params"), "id" not in message


def response(req_id: Any, result: Any = None, error: dict[str, Any] | None = None
             ) -> dict[str, Any]:
    if error is not None:
        return {"jsonrpc": "2.0", "id": req_id, "error": error}
    return {"jsonrpc": "2.0", "id": req_id, "result": result}


def notification(method: str, params: Any) -> dict[str, Any]:
    return {"jsonrpc": "2.0", "method": method, "params": params}


def encode(message: Any) -> str:
    """One message as one line (``\\n``-terminated, no raw newlines inside)."""
    return json.dumps(message, separators=(",", ":"), allow_nan=False) + "\n"
