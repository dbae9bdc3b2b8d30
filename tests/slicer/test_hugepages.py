"""The slice's small-pages switch: off inside the block, the caller's setting after it."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest

from slicer import hugepages
from slicer.hugepages import ENV, small_pages

pytestmark = pytest.mark.skipif(hugepages._switch() is None,
                                reason="this numpy has no hugepage switch")


@pytest.fixture
def switch(monkeypatch) -> Iterator[Callable[[bool], bool]]:
    """numpy's setter, with ``NUMPY_MADVISE_HUGEPAGE`` unset and huge pages on; the
    process's own setting is put back after the test."""
    setter = hugepages._switch()
    assert setter is not None
    monkeypatch.delenv(ENV, raising=False)
    old = setter(True)
    yield setter
    setter(old)


def _current(switch: Callable[[bool], bool]) -> bool:
    state = switch(True)
    switch(state)
    return state


@pytest.mark.parametrize("before", [True, False])
def test_huge_pages_are_off_inside_and_restored_after(before: bool, switch) -> None:
    switch(before)
    with small_pages():
        assert _current(switch) is False
    assert _current(switch) is before


def test_the_setting_is_restored_when_the_slice_fails(switch) -> None:
    with pytest.raises(RuntimeError), small_pages():
        raise RuntimeError("slice failed")
    assert _current(switch) is True


def test_an_explicit_numpy_setting_decides(switch, monkeypatch) -> None:
    monkeypatch.setenv(ENV, "1")
    with small_pages():
        assert _current(switch) is True


def test_overlapping_blocks_restore_after_the_last(switch) -> None:
    """Two slices at once (two threads): off until both end, then the first one's setting."""
    first, second = small_pages(), small_pages()
    first.__enter__()
    second.__enter__()
    first.__exit__(None, None, None)
    assert _current(switch) is False  # the second slice is still running
    second.__exit__(None, None, None)
    assert _current(switch) is True
