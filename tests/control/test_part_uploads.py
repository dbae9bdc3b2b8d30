"""Uploads in parts, one per connection: assembled in order, dropped on any error or when
too many are open."""

from __future__ import annotations

import asyncio
import base64

import pytest

from hostd.control.codes import RpcError
from hostd.control.upload import MAX_OPEN, PartUploads
from hostd.jobs.spool import Spool, SpoolError


def b64(data: bytes) -> str:
    return base64.b64encode(data).decode()


def staged_files(spool: Spool) -> list[str]:
    return sorted(p.name for p in spool.root.iterdir() if p.name.endswith(".tmp"))


@pytest.mark.timeout(30)
def test_parts_assemble_per_connection_and_errors_drop_the_upload(tmp_path):
    spool = Spool(tmp_path / "spool", max_bytes=100)
    uploads = PartUploads(spool.stage)

    async def main() -> None:
        assert await uploads.append(1, b64(b"G28\n"), 0) == 4
        assert await uploads.append(2, b64(b"M105\n"), 0) == 5  # another connection's own
        assert await uploads.append(1, b64(b"G1 X1\n"), 4) == 10
        with pytest.raises(RpcError, match="offset 4: 5 bytes received"):
            await uploads.append(2, b64(b"G1\n"), 4)
        with pytest.raises(RpcError, match="no upload in progress"):
            await uploads.append(2, b64(b"G1\n"), 5)  # it was dropped
        staged = uploads.take(1)
        staged.finish()
        assert staged.path.read_bytes() == b"G28\nG1 X1\n"
        staged.discard()
        with pytest.raises(RpcError, match="no upload in parts"):
            uploads.take(1)
        await uploads.append(3, b64(b"x" * 60), 0)
        with pytest.raises(SpoolError, match="exceeds the limit of 100 bytes"):  # → -32003
            await uploads.append(3, b64(b"x" * 60), 60)
        assert uploads.open == {}

    asyncio.run(main())
    assert staged_files(spool) == []


@pytest.mark.timeout(30)
def test_at_most_max_open_uploads_at_once(tmp_path):
    spool = Spool(tmp_path / "spool", max_bytes=100)
    uploads = PartUploads(spool.stage)

    async def main() -> None:
        for conn in range(MAX_OPEN):
            await uploads.append(conn, b64(b"G28\n"), 0)
        with pytest.raises(RpcError, match=f"{MAX_OPEN} uploads in parts are in progress"):
            await uploads.append(MAX_OPEN, b64(b"G28\n"), 0)
        await uploads.append(0, b64(b"M105\n"), 0)  # a connection may start its own afresh
        uploads.drop(1)
        await uploads.append(MAX_OPEN, b64(b"G28\n"), 0)  # room again

    asyncio.run(main())
    assert len(staged_files(spool)) == MAX_OPEN
