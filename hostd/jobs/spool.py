"""Content-addressed upload storage: every upload is kept once, named by its sha256.

The daemon only ever reads files it stored here itself; a client never names a path. The
directory is the daemon's alone (0700, its files 0600: a member of the hostd group who may
use the control socket may not reach in), and a file read back is checked against its
digest (:meth:`Spool.read`): a file changed on disk after its checks is never printed.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import re
import tempfile
import unicodedata
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

from hostd.state_files import private_dir

_SHA = re.compile(r"^[0-9a-f]{64}$")


class SpoolError(Exception):
    """An upload that cannot be stored (too large, empty) or a digest that is not stored."""


@contextlib.contextmanager
def _storing() -> Iterator[None]:
    """An operating system's refusal to store (disk full, permissions) as a :class:`SpoolError`
    for the operator, not an internal error."""
    try:
        yield
    except OSError as exc:
        raise SpoolError(f"cannot store the upload: {exc.strerror or exc}") from None


def _close(fh: BinaryIO) -> None:
    """Close ``fh``; what it still buffered is lost when the disk refuses it (full): the
    upload is refused or discarded then, and the close must not fail a second time."""
    with contextlib.suppress(OSError):  # (the descriptor is closed all the same)
        fh.close()


class Staged:
    """An upload on its way into the spool: a temporary file there, hashed as it is written.

    Its methods block (call them on a thread), and one writer at a time. :meth:`Spool.commit`
    moves it to its place; :meth:`discard` (a no-op once committed) deletes it.
    """

    def __init__(self, path: Path, fh: BinaryIO, max_bytes: int) -> None:
        self.path = path
        self.size = 0
        self.committed = False
        self._fh: BinaryIO | None = fh
        self._sha = hashlib.sha256()
        self._max = max_bytes

    @classmethod
    def written(cls, path: Path, max_bytes: int) -> Staged:
        """The file another process wrote at ``path``, hashed now (blocking)."""
        with _storing():
            os.chmod(path, 0o600)  # the spool's files are the daemon's alone
            staged = cls(path, open(path, "ab"), max_bytes)  # closed by finish or discard
            with open(path, "rb") as fh:
                while chunk := fh.read(1 << 20):
                    staged._sha.update(chunk)
                    staged.size += len(chunk)
        return staged

    def write(self, data: bytes) -> None:
        """Append ``data``; :class:`SpoolError` past the spool's size limit."""
        if self._fh is None:
            raise SpoolError("the upload is already finished")
        if self.size + len(data) > self._max:
            raise SpoolError(f"upload of {self.size + len(data)} bytes exceeds the limit of "
                             f"{self._max} bytes")
        with _storing():
            self._fh.write(data)
        self._sha.update(data)
        self.size += len(data)

    def digest(self) -> str:
        """The sha256 hex digest of what was written so far."""
        return self._sha.hexdigest()

    def finish(self) -> str:
        """Flush the file to disk and close it; the sha256 hex digest of what was written."""
        if self._fh is not None:
            fh, self._fh = self._fh, None
            with _storing():
                try:
                    fh.flush()
                    os.fsync(fh.fileno())
                finally:
                    _close(fh)
        return self._sha.hexdigest()

    def discard(self) -> None:
        if self._fh is not None:
            _close(self._fh)
            self._fh = None
        if not self.committed:
            self.path.unlink(missing_ok=True)


class Spool:
    """A directory of files named ``<sha256>`` plus an extension.

    Parameters
    ----------
    root
        The spool directory (created if missing).
    max_bytes
        The largest accepted upload.
    """

    def __init__(self, root: str | Path, max_bytes: int) -> None:
        self.root = Path(root)
        self.max_bytes = int(max_bytes)
        private_dir(self.root)
        for stale in self.root.glob(".*.tmp"):  # uploads a stopped daemon left half-written
            stale.unlink(missing_ok=True)

    def check_size(self, size: int, name: str = "") -> None:
        """Raise :class:`SpoolError` for an empty or oversized upload (named ``name``)."""
        where = f"{name}: " if name else ""
        if size <= 0:
            raise SpoolError(f"{where}empty upload")
        if size > self.max_bytes:
            raise SpoolError(f"{where}upload of {size} bytes exceeds the limit of "
                             f"{self.max_bytes} bytes")

    def stage(self) -> Staged:
        """A new upload, to :meth:`Staged.write` and then :meth:`commit` or discard."""
        with _storing():
            fd, name = tempfile.mkstemp(prefix=".upload-", suffix=".tmp", dir=self.root)
        return Staged(Path(name), os.fdopen(fd, "wb"), self.max_bytes)

    def commit(self, staged: Staged, suffix: str) -> str:
        """Store a staged upload under its digest (once; blocking) and return the digest."""
        self.check_size(staged.size)
        digest = staged.finish()
        path = self.path(digest, suffix, must_exist=False)
        with _storing():
            if path.exists():
                staged.path.unlink(missing_ok=True)
            else:
                os.replace(staged.path, path)
        staged.committed = True
        return digest

    def adopt(self, path: Path, suffix: str) -> str:
        """Store the file at ``path`` (written in the spool's directory by another process)
        under its digest, moving it (blocking); the digest."""
        staged = Staged.written(path, self.max_bytes)
        try:
            return self.commit(staged, suffix)
        finally:
            staged.discard()

    def put(self, data: bytes, suffix: str) -> str:
        """Store ``data`` (atomically, once) and return its sha256 hex digest."""
        self.check_size(len(data))
        staged = self.stage()
        try:
            staged.write(data)
            return self.commit(staged, suffix)
        finally:
            staged.discard()

    def path(self, digest: str, suffix: str, must_exist: bool = True) -> Path:
        """The file of ``digest``; only well-formed digests map to a path."""
        if not _SHA.match(digest) or not re.match(r"^\.[a-z0-9]{1,8}$", suffix):
            raise SpoolError(f"bad spool name {digest!r}{suffix!r}")
        path = self.root / f"{digest}{suffix}"
        if must_exist and not path.exists():
            raise SpoolError(f"spool file {digest[:12]}{suffix} is missing")
        return path

    def read(self, digest: str, suffix: str) -> bytes:
        """The file of ``digest``, checked against it: :class:`SpoolError` when its content
        changed since it was stored (and checked)."""
        data = self.path(digest, suffix).read_bytes()
        actual = hashlib.sha256(data).hexdigest()
        if actual != digest:
            raise SpoolError(f"spool file {digest[:12]}{suffix} changed after its checks "
                             f"(its digest is now {actual[:12]}): not used")
        return data

    def remove(self, digest: str, suffix: str) -> None:
        """Delete a stored file (no error if it is already gone)."""
        self.path(digest, suffix, must_exist=False).unlink(missing_ok=True)

    def usage(self) -> dict[str, int]:
        files = [p for p in self.root.iterdir() if p.is_file() and not p.name.startswith(".")]
        return {"files": len(files), "bytes": sum(p.stat().st_size for p in files)}


KINDS = {".stl": "stl", ".3mf": "3mf", ".obj": "obj", ".gcode": "gcode", ".gco": "gcode",
         ".g": "gcode", ".nc": "gcode"}
SUFFIX = {"stl": ".stl", "gcode": ".gcode"}
"""The stored kinds: a part to slice is kept as binary STL whatever it was sent as."""
UPLOAD_KINDS = ("stl", "3mf", "obj", "gcode")
MESH_KINDS = frozenset({"stl", "3mf", "obj"})
"""Uploads the slicer reads (stored as ``stl`` jobs)."""


HIDDEN_CATEGORIES = frozenset({"Cc", "Cf", "Cs", "Co", "Zl", "Zp"})
"""Characters a job name may not hold: controls, formatting (the bidirectional overrides and
isolates U+202A..U+202E, U+2066..U+2069, zero-width marks), surrogates, private use and line
or paragraph separators: each changes what ``hostctl jobs`` shows of a name, not only of
itself (``part\u202elts.gcode`` shows as ``partedoc g.stl``)."""


def _hidden(ch: str) -> bool:
    return unicodedata.category(ch) in HIDDEN_CATEGORIES


def check_name(name: str) -> None:
    """Refuse an upload name holding a character of :data:`HIDDEN_CATEGORIES`, naming it
    (the name shown with each such character escaped)."""
    for ch in name:
        if _hidden(ch):
            shown = "".join(f"\\u{ord(c):04x}" if _hidden(c) else c for c in name)
            raise SpoolError(f"job name '{shown}' "
                             f"holds U+{ord(ch):04X} ({unicodedata.name(ch, 'a control')}): it "
                             "would change how the name shows; rename the file")


def upload_kind(name: str, kind: str | None) -> str:
    """``stl``, ``3mf``, ``obj`` or ``gcode``, given explicitly or from the file name's
    extension."""
    if kind is not None:
        if kind not in UPLOAD_KINDS:
            raise SpoolError(f"unknown upload kind {kind!r} ({', '.join(UPLOAD_KINDS)})")
        return kind
    ext = Path(name).suffix.lower()
    if ext not in KINDS:
        raise SpoolError(f"{name or '(no name)'}: cannot tell the kind from the extension "
                         "(.stl, .3mf, .obj or .gcode); give the kind (hostctl print --kind)")
    return KINDS[ext]


def check_gcode(data: bytes, name: str) -> str:
    """The text of a G-code upload; :class:`SpoolError` for binary data."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise SpoolError(f"{name}: G-code is not UTF-8 text") from None
    if "\0" in text:
        raise SpoolError(f"{name}: G-code contains NUL bytes")
    return text
