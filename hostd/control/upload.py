"""Uploads into the spool: base64 decoded in slices, and files sent in parts.

A large upload must never hold the event loop long.

Decoding 17 MB of base64 in one call took 46–111 ms on the project's test VM
(``bench/upload_lag.py --costs``): that long, the serial stream of the job printing meanwhile
would wait. In slices of :data:`SLICE_CHARS` characters, with the loop's other callbacks run
between them, no wait is much over a millisecond. The bytes, and every refusal, are those of
one strict decode (RFC 4648: the base64 alphabet only, no padding before the end). The
pieces are written to the spool's staging file on a thread, as they are decoded.

One JSON message holding a whole file still costs one ``json.loads`` of all of it on the loop
(17–23 ms for 17 MB on the same VM). So a client may send a file in parts instead
(``job.upload``, each part a message of its own), then ``job.submit`` without ``data``:
:class:`PartUploads` keeps one such upload per connection.
"""

from __future__ import annotations

import asyncio
import binascii
from collections.abc import Callable, Iterator

from hostd.control.codes import INVALID_PARAMS, UPLOAD_REJECTED, RpcError
from hostd.jobs.spool import Staged

SLICE_CHARS = 1 << 18
"""Characters decoded per slice (a multiple of 4, so slices end on whole groups)."""
MAX_OPEN = 8
"""Uploads in parts open at once, across connections: each holds a staging file of up to
``daemon.max_upload_bytes`` on the spool's disk."""


def base64_pieces(data: str, slice_chars: int = SLICE_CHARS) -> Iterator[bytes]:
    """``data`` decoded a slice at a time (the caller yields to the loop between them);
    :class:`binascii.Error` (a ``ValueError``) when it is not strict base64, ``ValueError``
    for characters outside ASCII."""
    if slice_chars <= 0 or slice_chars % 4:
        raise ValueError(f"slice_chars must be a positive multiple of 4, not {slice_chars}")
    start = 0
    body = _unpadded_length(data, slice_chars)  # the last slice takes the final padding whole
    while body - start > slice_chars:
        piece = data[start:start + slice_chars]
        if piece.endswith("="):  # padding that more data follows
            raise binascii.Error("Excess data after padding")
        yield binascii.a2b_base64(piece, strict_mode=True)
        start += slice_chars
    # the last slice is decoded after the group before it (3 bytes, dropped again), so that
    # its padding is judged as in one decode: padding is refused at the very start only
    lead = min(start, 4)
    yield binascii.a2b_base64(data[start - lead:], strict_mode=True)[lead // 4 * 3:]


def _unpadded_length(data: str, window: int) -> int:
    """``len(data.rstrip("="))``, without copying a long ``data``."""
    end = len(data)
    while end:
        tail = data[max(0, end - window):end]
        kept = len(tail.rstrip("="))
        end -= len(tail) - kept
        if kept:
            break
    return end


async def write_base64(staged: Staged, data: str, slice_chars: int = SLICE_CHARS) -> None:
    """Decode ``data`` into ``staged``, a slice at a time, each written on a thread (the
    loop's other callbacks run meanwhile); :class:`RpcError` for data that is not base64."""
    try:
        for piece in base64_pieces(data, slice_chars):
            await asyncio.to_thread(staged.write, piece)
    except ValueError:  # binascii.Error included
        raise RpcError(INVALID_PARAMS, "data: invalid base64") from None


class PartUploads:
    """Files sent in parts: at most one per connection, discarded when it ends unsubmitted.

    Parameters
    ----------
    stage
        Starts an upload in the spool (:meth:`hostd.jobs.spool.Spool.stage`).
    """

    def __init__(self, stage: Callable[[], Staged]) -> None:
        self.stage = stage
        self.open: dict[int, Staged] = {}  # connection id → its upload

    async def append(self, conn: int, data: str, offset: int) -> int:
        """Add a part (base64 ``data``) at byte ``offset``: 0 starts a new upload (dropping
        one left unsubmitted), any other must be the bytes received so far. Returns that
        count. On any error the connection's upload is dropped."""
        if offset == 0:
            self.drop(conn)
            if len(self.open) >= MAX_OPEN:
                raise RpcError(UPLOAD_REJECTED, f"{MAX_OPEN} uploads in parts are in progress "
                               "on other connections; submit or close one first")
            self.open[conn] = self.stage()
        staged = self.open.get(conn)
        if staged is None or staged.size != offset:
            self.drop(conn)
            have = "no upload in progress" if staged is None else f"{staged.size} bytes received"
            raise RpcError(INVALID_PARAMS, f"offset {offset}: {have}; start again at offset 0")
        try:
            await write_base64(staged, data)
        except BaseException:
            self.drop(conn)
            raise
        return staged.size

    def take(self, conn: int) -> Staged:
        """The connection's upload, now the caller's to submit."""
        staged = self.open.pop(conn, None)
        if staged is None:
            raise RpcError(INVALID_PARAMS, "data: missing, and no upload in parts on this "
                           "connection (job.upload)")
        return staged

    def drop(self, conn: int) -> None:
        staged = self.open.pop(conn, None)
        if staged is not None:
            staged.discard()
