"""hostctl's submission of a file: whole, or in parts at their offsets, reassembling it."""

from __future__ import annotations

import base64
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hostd.cli import cmd_control
from hostd.cli.cmd_control import SUBMIT_TIMEOUT, _submit


class Recorder:
    """A client that answers every call and keeps them."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, float | None, dict[str, Any]]] = []

    def call(self, method: str, timeout: float | None = 30.0, **params: Any) -> Any:
        self.calls.append((method, timeout, params))
        return {"id": 1, "state": "ready", "name": params.get("name")}


@settings(max_examples=60, deadline=None)
@given(st.binary(max_size=200), st.integers(1, 40))
def test_parts_reassemble_the_file_at_their_offsets(data: bytes, part: int):
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(cmd_control, "PART_BYTES", part)
        c, seen = Recorder(), []
        _submit(c, "f.gcode", data, lambda sent, total: seen.append((sent, total)))
    *uploads, (method, timeout, params) = c.calls
    assert method == "job.submit" and timeout == SUBMIT_TIMEOUT  # the check takes its time
    if len(data) <= part:
        assert uploads == [] and base64.b64decode(params["data"]) == data and seen == []
        return
    assert "data" not in params and all(m == "job.upload" for m, _, _ in uploads)
    offsets = [p["offset"] for _, _, p in uploads]
    assert offsets == list(range(0, len(data), part))
    assert b"".join(base64.b64decode(p["data"]) for _, _, p in uploads) == data
    assert [s for s, _ in seen] == [min(o + part, len(data)) for o in offsets]
    assert {t for _, t in seen} == {len(data)}
