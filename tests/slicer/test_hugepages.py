"""The slice's small-pages switch: off inside the block, the caller's setting after it."""

from __future__ import annotations

import pytest

from slicer import hugepages
from slicer.hugepages import ENV, small_pages

switch = hugepages._switch()
pytestmark = pytest.mark.skipif(switch is None, reason="this numpy has no hugepage switch")


def _current() -> bool:
    assert switch is not None
    state = switch(True)
    switch(state)
    return state


@pytest.mark.parametrize("before", [True, False])
def test_huge_pages_are_off_inside_and_restored_after(before: bool, monkeypatch) -> None:
    monkeypatch.delenv(ENV, raising=False)
    assert switch is not None
    old = switch(before)
    try:
        with small_pages():
            assert _current() is False
        assert _current() is before
    finally:
        switch(old)


def test_the_setting_is_restored_when_the_slice_fails(monkeypatch) -> None:
    monkeypatch.delenv(ENV, raising=False)
    assert switch is not None
    old = switch(True)
    try:
        with pytest.raises(RuntimeError), small_pages():
            raise RuntimeError("slice failed")
        assert _current() is True
    finally:
        switch(old)


def test_an_explicit_numpy_setting_decides(monkeypatch) -> None:
    monkeypatch.setenv(ENV, "1")
    assert switch is not None
    old = switch(True)
    try:
        with small_pages():
            assert _current() is True
    finally:
        switch(old)


def test_overlapping_blocks_restore_after_the_last(monkeypatch) -> None:
    """Two slices at once (two threads): off until both end, then the first one's setting."""
    monkeypatch.delenv(ENV, raising=False)
    assert switch is not None
    old = switch(True)
    first, second = small_pages(), small_pages()
    try:
        first.__enter__()
        second.__enter__()
        first.__exit__(None, None, None)
        assert _current() is False  # the second slice is still running
        second.__exit__(None, None, None)
        assert _current() is True
    finally:
        switch(old)
