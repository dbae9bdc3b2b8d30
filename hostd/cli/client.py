"""A small blocking JSON-RPC 2.0 client for hostctl (one message per line, Unix socket)."""

from __future__ import annotations

import itertools
import json
import os
import socket
from collections import deque
from collections.abc import Iterator
from typing import Any

from hostd.cli.errors import EXIT_REFUSED, EXIT_UNREACHABLE, EXIT_USAGE, CliError
from hostd.control.codes import INVALID_PARAMS, UPLOAD_REJECTED

DEFAULT_SOCKET = "/run/hostd/hostd.sock"


def socket_path(arg: str | None) -> str:
    return arg or os.environ.get("HOSTD_SOCKET") or DEFAULT_SOCKET


BAD_INPUT = frozenset({UPLOAD_REJECTED, INVALID_PARAMS})
"""JSON-RPC error codes that mean the input was bad (exit 2), not refused (exit 4)."""


class RpcFailure(CliError):
    """The daemon answered with a JSON-RPC error."""

    def __init__(self, code: int, message: str) -> None:
        # a refused upload or bad params (a raw G-code line the daemon refuses: a heater
        # target over its limit, M112) is bad input (exit 2); the rest are refusals (exit 4)
        super().__init__(message, EXIT_USAGE if code in BAD_INPUT else EXIT_REFUSED)
        self.rpc_code = code


class Client:
    """``call()`` requests; notifications that arrive meanwhile are kept for ``events()``."""

    def __init__(self, path: str, timeout: float | None = 30.0) -> None:
        self.path = path
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.sock.settimeout(timeout)
        try:
            self.sock.connect(path)
        except OSError as exc:
            self.sock.close()
            raise CliError(f"cannot connect to hostd at {path}: {exc.strerror or exc}",
                           EXIT_UNREACHABLE) from None
        self._file = self.sock.makefile("rb")
        self._ids = itertools.count(1)
        self.pending: deque[dict[str, Any]] = deque()

    def close(self) -> None:
        self._file.close()
        self.sock.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def call(self, method: str, timeout: float | None = 30.0, **params: Any) -> Any:
        req_id = next(self._ids)
        msg = {"jsonrpc": "2.0", "id": req_id, "method": method,
               "params": {k: v for k, v in params.items() if v is not None}}
        self.sock.settimeout(timeout)
        try:
            self._send(json.dumps(msg).encode() + b"\n")
            while True:
                reply = self._read()
                if "method" in reply and "id" not in reply:
                    self.pending.append(reply)
                    continue
                if reply.get("id") not in (req_id, None):
                    continue
                if "error" in reply:
                    err = reply["error"]
                    raise RpcFailure(int(err.get("code", 0)), str(err.get("message")))
                return reply.get("result")
        except TimeoutError:
            raise CliError(f"hostd did not answer {method} in time", EXIT_UNREACHABLE) from None
        except OSError as exc:
            raise CliError(f"connection to hostd lost: {exc}", EXIT_UNREACHABLE) from None

    def _send(self, data: bytes) -> None:
        """Send a request; a daemon that closed the connection first may have said why (too
        many connections): that answer is the error, not the broken pipe."""
        try:
            self.sock.sendall(data)
        except OSError:
            try:
                reply = self._read()
            except (CliError, OSError):
                raise
            err = reply.get("error") if reply.get("id") is None else None
            if not isinstance(err, dict):
                raise
            raise RpcFailure(int(err.get("code", 0)), str(err.get("message"))) from None

    def events(self, timeout: float | None = None) -> Iterator[tuple[str, dict[str, Any]]]:
        """Pushed notifications as ``(event, data)``, forever (until the daemon closes)."""
        self.sock.settimeout(timeout)
        while True:
            msg = self.pending.popleft() if self.pending else self._read()
            if "method" in msg and "id" not in msg:
                params = msg.get("params") or {}
                yield str(params.get("event", msg["method"])), params

    def _read(self) -> dict[str, Any]:
        line = self._file.readline()
        if not line:
            raise CliError("hostd closed the connection", EXIT_UNREACHABLE)
        try:
            msg = json.loads(line)
        except ValueError:
            raise CliError("hostd sent malformed JSON", EXIT_UNREACHABLE) from None
        if not isinstance(msg, dict):
            raise CliError("hostd sent an unexpected message", EXIT_UNREACHABLE)
        return msg
