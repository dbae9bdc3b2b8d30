"""The slicing worker's result cache: sliced G-code and its figures, named by cache key; and
the slicer's refusals, which the same STL, profile and code meet again.

An entry is two files, ``<key>.gcode`` and ``<key>.json``; each is written to a temporary
name, flushed to disk and renamed, the figures last, and they record the G-code's size. So
after a power cut an entry is whole or absent: figures that do not parse, or a G-code of
another size than they record, make the entry a miss (it is removed and sliced again), never
an error and never a shortened print. A refusal is one file, ``<key>.refused.json``: its line
and the upload's name in it, written the same way; one that does not parse is a miss.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Any

from hostd.state_files import PRIVATE_FILE, private_dir

log = logging.getLogger(__name__)

SIZE_KEY = "gcode_bytes"
"""The figures' record of the G-code's size."""


def write_durably(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` whole or not at all (a temporary file, fsync, rename),
    readable by the daemon alone (0600)."""
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    try:
        with open(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, PRIVATE_FILE), "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def sync_file(path: Path) -> int:
    """Flush ``path`` to disk; its size in bytes."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
        return os.fstat(fd).st_size
    finally:
        os.close(fd)


class SliceCache:
    """Entries in ``root`` (created if missing). Its methods block: call them on a thread."""

    def __init__(self, root: Path) -> None:
        self.root = root
        private_dir(root)  # 0700, files 0600: the hostd group may not swap a sliced file

    def gcode_path(self, key: str) -> Path:
        return self.root / f"{key}.gcode"

    def _meta_path(self, key: str) -> Path:
        return self.root / f"{key}.json"

    def lookup(self, key: str) -> dict[str, Any] | None:
        """The figures of a whole entry, or None (a torn entry is removed)."""
        gcode, meta = self.gcode_path(key), self._meta_path(key)
        if not meta.exists():
            return None
        try:
            info = json.loads(meta.read_bytes())
            whole = isinstance(info, dict) and info.get(SIZE_KEY) == gcode.stat().st_size
        except (OSError, ValueError):
            whole = False
        if whole:
            return info
        log.warning("slice cache: entry %s is incomplete (a crash while it was written?);"
                    " slicing again", key)
        self.remove(key)
        return None

    def store(self, key: str, info: dict[str, Any]) -> dict[str, Any]:
        """Record the figures of the G-code the worker wrote (and renamed) to
        :meth:`gcode_path`, after flushing it to disk; the figures as stored."""
        self.gcode_path(key).chmod(PRIVATE_FILE)
        info = {**info, SIZE_KEY: sync_file(self.gcode_path(key))}
        write_durably(self._meta_path(key), json.dumps(info).encode())
        return info

    def _refusal_path(self, key: str) -> Path:
        return self.root / f"{key}.refused.json"

    def refusal(self, key: str) -> tuple[str, str | None] | None:
        """The slicer's refusal of ``key`` (its line, the upload's name in it), or None."""
        path = self._refusal_path(key)
        try:
            got = json.loads(path.read_bytes())
            text, name = got["refused"], got["name"]
        except FileNotFoundError:
            return None
        except (OSError, ValueError, TypeError, KeyError):
            log.warning("slice cache: refusal %s is unreadable; slicing again", key)
            path.unlink(missing_ok=True)
            return None
        if not isinstance(text, str) or not isinstance(name, str | None):
            path.unlink(missing_ok=True)
            return None
        return text, name

    def store_refusal(self, key: str, text: str, name: str | None) -> None:
        """Keep the slicer's refusal of ``key``: its line ``text``, naming the upload
        ``name``."""
        write_durably(self._refusal_path(key),
                      json.dumps({"refused": text, "name": name}).encode())

    def remove(self, key: str) -> None:
        for path in (self._meta_path(key), self.gcode_path(key), self._refusal_path(key),
                     *self.root.glob(f"{key}.*.png")):
            path.unlink(missing_ok=True)
