"""The HTTP API's key file: what hostctl api-key writes, what the daemon takes, read again
when the file changes."""

from __future__ import annotations

import os
import stat

import pytest

from hostd import api_keys
from hostd.api_keys import ApiKeyError, KeyRing


def test_new_keys_are_random_labelled_lines_of_a_group_readable_file(tmp_path):
    path = tmp_path / "etc" / "api-keys"
    first = api_keys.new(path, "PrusaSlicer")
    second = api_keys.new(path, "  Fluidd\n on the laptop ")
    assert first.key != second.key and len(first.key) == 32
    assert path.read_text() == (f"{first.key} PrusaSlicer\n"
                                f"{second.key} Fluidd on the laptop\n")
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o640
    assert api_keys.read(path) == [first, second]


def test_comments_and_blank_lines_are_no_keys():
    assert api_keys.parse("# keys\n\nabc123 for me\n  def456\n") == [
        api_keys.ApiKey("abc123", "for me"), api_keys.ApiKey("def456")]


def test_revoke_takes_one_key_by_its_first_characters(tmp_path):
    path = tmp_path / "keys"
    path.write_text("aaaa1111 one\naaaa2222 two\nbbbb3333 three\n")
    with pytest.raises(ApiKeyError, match="2 keys start so"):
        api_keys.revoke(path, "aaaa")
    with pytest.raises(ApiKeyError, match="at least the first 4"):
        api_keys.revoke(path, "bbb")
    assert api_keys.revoke(path, "aaaa2").label == "two"
    assert [k.key for k in api_keys.read(path)] == ["aaaa1111", "bbbb3333"]


def test_the_daemons_ring_reads_the_file_again_when_it_changes(tmp_path):
    path = tmp_path / "keys"
    ring = KeyRing(path)
    assert not ring.valid("x") and ring.count() == 0  # no file: no key
    key = api_keys.new(path).key
    assert ring.valid(key) and not ring.valid(key[:-1]) and not ring.valid(None)
    api_keys.revoke(path, key)
    assert not ring.valid(key)


def test_an_unreadable_key_file_is_said_and_lets_nobody_in(tmp_path):
    path = tmp_path / "keys"
    path.write_bytes(b"\xff\xfe not text")
    ring = KeyRing(path)
    assert not ring.valid("anything")
    assert ring.error is not None and ring.error.startswith(f"{path}: cannot read")
