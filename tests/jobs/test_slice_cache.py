"""The slice cache: an entry is whole or a miss, whatever a crash left on disk."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hostd.slice_cache import SIZE_KEY, SliceCache

GCODE = b"G90\nG1 X1 Y1 Z0.2\n" * 50
KEY = "abc-123"


def stored(tmp_path: Path) -> SliceCache:
    cache = SliceCache(tmp_path / "cache")
    cache.gcode_path(KEY).write_bytes(GCODE)  # as the worker leaves it (renamed into place)
    info = cache.store(KEY, {"subparts": 2, "layers": 40})
    assert info[SIZE_KEY] == len(GCODE)
    return cache


def test_a_whole_entry_is_found_with_its_figures(tmp_path: Path):
    cache = stored(tmp_path)
    assert cache.lookup(KEY) == {"subparts": 2, "layers": 40, SIZE_KEY: len(GCODE)}
    assert sorted(p.name for p in cache.root.iterdir()) == [f"{KEY}.gcode", f"{KEY}.json"]


def test_no_figures_is_a_miss_even_with_the_gcode(tmp_path: Path):
    cache = SliceCache(tmp_path / "cache")
    cache.gcode_path(KEY).write_bytes(GCODE)  # the worker wrote it, the daemon died
    assert cache.lookup(KEY) is None


@pytest.mark.parametrize("damage", ["torn figures", "empty figures", "not an object",
                                    "short gcode", "empty gcode", "no gcode"])
def test_a_torn_entry_is_a_miss_and_is_removed(tmp_path: Path, damage: str):
    cache = stored(tmp_path)
    meta = cache.root / f"{KEY}.json"
    gcode = cache.gcode_path(KEY)
    if damage == "torn figures":
        meta.write_bytes(meta.read_bytes()[:10])
    elif damage == "empty figures":
        meta.write_bytes(b"")
    elif damage == "not an object":
        meta.write_text(json.dumps([1, 2]))
    elif damage == "short gcode":
        gcode.write_bytes(GCODE[:-7])
    elif damage == "empty gcode":
        gcode.write_bytes(b"")
    else:
        gcode.unlink()
    assert cache.lookup(KEY) is None
    assert list(cache.root.iterdir()) == []


def test_no_temporary_file_is_left_behind(tmp_path: Path):
    cache = stored(tmp_path)
    cache.store(KEY, {"subparts": 3})
    assert cache.lookup(KEY) == {"subparts": 3, SIZE_KEY: len(GCODE)}
    assert not [p for p in cache.root.iterdir() if p.suffix == ".tmp"]


def test_the_key_changes_with_the_profile_and_with_the_slicer_code(tmp_path: Path):
    """A cached file from an older slicer (say, one with a G-code bug since fixed) must not
    be served after an upgrade: the slicer's source is part of the key."""
    from hostd.slicing_worker import cache_key, code_digest

    profile = {"process.layer_height": 0.2}
    key = cache_key("f" * 64, profile)
    assert key == cache_key("f" * 64, dict(profile))  # stable
    assert key == cache_key("f" * 64, profile, code_digest())
    assert key != cache_key("f" * 64, {"process.layer_height": 0.3})
    assert key != cache_key("f" * 64, profile, code="0" * 64)  # another slicer
    assert key.startswith("f" * 64 + "-")
    assert len(code_digest()) == 64 and code_digest() == code_digest()


def test_the_ready_reason_says_why_the_part_was_turned():
    from hostd.slicing_worker import sliced_reason

    note = "turned to stand on its 804 mm² face (normal +Z in the file), 180° from ..."
    assert sliced_reason({"merged_shells": 0, "base_note": None}) == "sliced"
    assert sliced_reason({"merged_shells": 0, "base_note": note}) == f"sliced; {note}"
    assert sliced_reason({"merged_shells": 2, "base_note": note}) == (
        f"sliced; merged 2 overlapping shells of the file into one solid; {note}")
    assert sliced_reason({"merged_shells": 2}) == (
        "sliced; merged 2 overlapping shells of the file into one solid")


def test_a_refusal_is_kept_whole_and_removed_with_its_entry(tmp_path: Path):
    cache = SliceCache(tmp_path / "cache")
    assert cache.refusal(KEY) is None
    cache.store_refusal(KEY, "tee.stl: replay found 3 unsupported wall layers", "tee.stl")
    assert cache.refusal(KEY) == ("tee.stl: replay found 3 unsupported wall layers", "tee.stl")
    assert [p.name for p in cache.root.iterdir()] == [f"{KEY}.refused.json"]
    cache.remove(KEY)
    assert list(cache.root.iterdir()) == []


@pytest.mark.parametrize("damage", [b"", b'{"refused": "x"', b"[1, 2]",
                                    b'{"refused": 3, "name": null}', b'{"name": "a.stl"}'])
def test_an_unreadable_refusal_is_a_miss_and_is_removed(tmp_path: Path, damage: bytes):
    cache = SliceCache(tmp_path / "cache")
    (cache.root / f"{KEY}.refused.json").write_bytes(damage)
    assert cache.refusal(KEY) is None
    assert list(cache.root.iterdir()) == []
