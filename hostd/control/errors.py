"""THE error table: which JSON-RPC code each exception a handler raises gets.

Nothing else in the daemon picks error codes: the subsystems raise their own errors, and
:func:`hostd.control.rpc.error_for` looks them up here. The domain never imports this
module (``control/`` depends on the domain, not the reverse).
"""

from __future__ import annotations

from hostd.control.codes import (
    INVALID_PARAMS,
    JOB_NOT_FOUND,
    JOB_STATE,
    PRINTER_BUSY,
    PRINTER_ERROR,
    SHUTTING_DOWN,
    UPLOAD_REJECTED,
)
from hostd.errors import PrinterBusy, ShuttingDown
from hostd.events import EventError
from hostd.jobs.spool import SpoolError
from hostd.jobs.states import JobStateError
from hostd.jobs.store import JobNotFound, StoreError
from hostd.link.errors import LinkError
from hostd.printer.errors import PrinterError, ScriptRefused
from hostd.slicing_worker import SliceError

ERROR_CODES: tuple[tuple[type[BaseException], int], ...] = (
    (JobNotFound, JOB_NOT_FOUND),
    (JobStateError, JOB_STATE),
    (StoreError, JOB_STATE),
    (SpoolError, UPLOAD_REJECTED),
    (SliceError, UPLOAD_REJECTED),
    (PrinterBusy, PRINTER_BUSY),
    (ShuttingDown, SHUTTING_DOWN),
    (ScriptRefused, INVALID_PARAMS),  # a bad script param: before PrinterError, its base
    (PrinterError, PRINTER_ERROR),
    (LinkError, PRINTER_ERROR),
    (EventError, INVALID_PARAMS),
)
"""Exception classes → codes, most specific first (an :class:`~hostd.control.codes.RpcError`
carries its own code)."""

