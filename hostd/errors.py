"""Errors of a request that more than one subsystem refuses alike (the jobs, the printer,
the daemon): each is mapped to its JSON-RPC code in :mod:`hostd.control.errors`.

A subsystem's own failures have their own classes (:mod:`hostd.link.errors`,
:mod:`hostd.printer.errors`, :mod:`hostd.jobs.states` ...); these two say only that the
request came at the wrong time.
"""

from __future__ import annotations


class PrinterBusy(Exception):
    """A request that conflicts with the print in progress (e.g. raw G-code while printing)."""


class ShuttingDown(Exception):
    """The daemon is stopping and takes no new work."""
