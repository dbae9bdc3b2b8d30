"""JSON-RPC 2.0 error codes of the control socket, and the error that carries one.

The numbers are the protocol's (``hostctl`` reads them to pick its exit code): this module
imports nothing of the daemon, so the client stays light. Which exception gets which code is
:data:`hostd.control.errors.ERROR_CODES`.
"""

from __future__ import annotations

from typing import Any

PARSE_ERROR = -32700
INVALID_REQUEST = -32600
METHOD_NOT_FOUND = -32601
INVALID_PARAMS = -32602
INTERNAL_ERROR = -32603
# application errors (-32000 .. -32099 are reserved for implementations)
JOB_NOT_FOUND = -32001
JOB_STATE = -32002
UPLOAD_REJECTED = -32003
PRINTER_BUSY = -32004
PRINTER_ERROR = -32005
SLICE_FAILED = -32006
MESSAGE_TOO_LARGE = -32007
SHUTTING_DOWN = -32008
CONNECTION_LIMIT = -32009
"""A connection refused or closed by a limit (too many open, idle too long, ...)."""


class RpcError(Exception):
    """An error with an explicit JSON-RPC code (bad params, unknown method, ...)."""

    def __init__(self, code: int, message: str, data: Any = None) -> None:
        super().__init__(message)
        self.code = code
        self.message = message
        self.data = data
