"""An upload's base64 decoded in slices: the same bytes and the same errors as one strict
decode, with the event loop's other callbacks run between the slices."""

from __future__ import annotations

import asyncio
import base64
import binascii

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hostd.control.upload import base64_pieces, write_base64
from hostd.jobs.spool import Spool

SLICES = st.integers(1, 6).map(lambda n: 4 * n)
ALPHABET = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/"


def strict(data: str) -> bytes | None:
    """One strict decode of ``data``: its bytes, or None when it is refused."""
    try:
        return binascii.a2b_base64(data, strict_mode=True)
    except ValueError:
        return None


def sliced(data: str, slice_chars: int) -> bytes | None:
    try:
        return b"".join(base64_pieces(data, slice_chars))
    except ValueError:
        return None


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=200), SLICES)
def test_sliced_decoding_gives_the_uploaded_bytes(raw: bytes, slice_chars: int):
    assert sliced(base64.b64encode(raw).decode(), slice_chars) == raw


MIXES = [ALPHABET + "==\n -é", "AQgw09+/=", "AQ==", "A=", "Aw=\n"]  # (padding-heavy too)


@settings(max_examples=1000, deadline=None)
@given(st.sampled_from(MIXES).flatmap(lambda chars: st.text(chars, max_size=40)), SLICES)
def test_sliced_decoding_refuses_what_a_strict_decode_refuses(data: str, slice_chars: int):
    """Equal on every input: the bytes when one strict decode accepts it, else a refusal."""
    assert sliced(data, slice_chars) == strict(data)


@settings(max_examples=200, deadline=None)
@given(st.binary(min_size=1, max_size=60),
       st.sampled_from(["=", "==", "A=", "QQ==", "QUI=", "\n", "é"]), SLICES)
def test_a_damaged_upload_is_refused(raw: bytes, damage: str, slice_chars: int):
    """Padding (alone, or ending a whole group) or a stray character before the end: refused,
    however the slices fall."""
    good = base64.b64encode(raw).decode()
    for cut in range(0, len(good), 4):
        bad = good[:cut] + damage + good[cut:]
        assert strict(bad) is None
        assert sliced(bad, slice_chars) is None


@pytest.mark.timeout(30)
def test_the_loop_runs_other_callbacks_between_slices(tmp_path):
    raw = bytes(range(256)) * 12  # 4096 characters of base64: 32 slices of 128
    ticks: list[int] = []
    staged = Spool(tmp_path / "spool", max_bytes=1 << 20).stage()

    async def main() -> None:
        async def tick() -> None:
            while True:
                ticks.append(1)
                await asyncio.sleep(0)

        ticker = asyncio.create_task(tick())
        await asyncio.sleep(0)  # the ticker starts
        ticks.clear()
        try:
            await write_base64(staged, base64.b64encode(raw).decode(), 128)
        finally:
            ticker.cancel()

    asyncio.run(main())
    staged.finish()
    assert staged.path.read_bytes() == raw
    assert len(ticks) >= 31  # a turn of the ticker between each two slices


@pytest.mark.parametrize("slice_chars", [0, -4, 6])
def test_a_slice_that_is_not_whole_groups_is_a_programming_error(slice_chars: int):
    with pytest.raises(ValueError, match="multiple of 4"):
        list(base64_pieces("QUJD", slice_chars))
