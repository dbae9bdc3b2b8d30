"""Fixtures of the end-to-end daemon tests (the harness is in hostd_harness.py)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from hostd_harness import DaemonProc


@pytest.fixture
def daemon_factory(tmp_path: Path):
    procs: list[DaemonProc] = []

    def make(**overrides: Any) -> DaemonProc:
        d = DaemonProc(tmp_path, **overrides)
        procs.append(d)
        return d

    yield make
    for d in procs:
        if d.proc is not None and d.proc.returncode is None:
            d.proc.kill()
