"""The HTTP API's keys (``http.api_key_file``): one key a line, a label after it if wanted.

``hostctl api-key new/list/revoke`` write the file (as root: it lives beside the config,
readable by the ``hostd`` group); the daemon reads it again whenever it changes, so a key
made or revoked counts from the next request, without a restart. Lines that are blank or
start with ``#`` are comments. Keys are compared in constant time.
"""

from __future__ import annotations

import contextlib
import grp
import hmac
import os
import secrets
import time
from dataclasses import dataclass
from pathlib import Path

KEY_BYTES = 16
"""Random bytes of a new key (32 hex digits, as OctoPrint's keys)."""
FILE_MODE = 0o640
GROUP = "hostd"
"""The group that may read the key file (the daemon's)."""


class ApiKeyError(Exception):
    """The key file cannot be read or written, or a key to revoke is not in it."""


@dataclass(frozen=True)
class ApiKey:
    key: str
    label: str = ""

    @property
    def shown(self) -> str:
        """The key as listed: its first 8 digits."""
        return f"{self.key[:8]}…"


def parse(text: str) -> list[ApiKey]:
    keys = []
    for line in text.splitlines():
        words = line.strip().split(None, 1)
        if words and not words[0].startswith("#"):
            keys.append(ApiKey(words[0], words[1] if len(words) > 1 else ""))
    return keys


def read(path: str | Path) -> list[ApiKey]:
    """The keys of ``path`` (none when it does not exist)."""
    try:
        return parse(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        return []
    except (OSError, UnicodeDecodeError) as exc:
        raise ApiKeyError(f"{path}: cannot read: {getattr(exc, 'strerror', None) or exc}"
                          ) from None


def _write(path: Path, keys: list[ApiKey]) -> None:
    """Replace the file whole (a temporary file renamed), readable by the daemon's group."""
    text = "".join(f"{k.key} {k.label}".rstrip() + "\n" for k in keys)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, FILE_MODE)
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        with contextlib.suppress(KeyError, PermissionError):  # no such group, or not root
            os.chown(tmp, -1, grp.getgrnam(GROUP).gr_gid)
        os.replace(tmp, path)
    except OSError as exc:
        raise ApiKeyError(f"{path}: cannot write: {exc.strerror or exc}") from None
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink()


def new(path: str | Path, label: str = "") -> ApiKey:
    """A new random key, added to ``path``."""
    label = " ".join(label.split()) or time.strftime("made %Y-%m-%d %H:%M")
    key = ApiKey(secrets.token_hex(KEY_BYTES), label)
    _write(Path(path), [*read(path), key])
    return key


def revoke(path: str | Path, prefix: str) -> ApiKey:
    """Remove the one key that starts with ``prefix`` (at least 4 characters)."""
    keys = read(path)
    if len(prefix) < 4:
        raise ApiKeyError(f"{prefix!r}: give at least the first 4 characters of the key")
    found = [k for k in keys if k.key.startswith(prefix)]
    if len(found) != 1:
        raise ApiKeyError(f"{prefix!r}: " + ("no such key in " if not found else
                                              f"{len(found)} keys start so in ") + str(path))
    _write(Path(path), [k for k in keys if k is not found[0]])
    return found[0]


class KeyRing:
    """The daemon's view of the key file: read again when its modification time or size
    changes (a ``stat`` a request)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._seen: tuple[int, int] | None = None
        self._keys: tuple[bytes, ...] = ()
        self.error: str | None = None

    def _refresh(self) -> None:
        try:
            st = self.path.stat()
            seen: tuple[int, int] | None = (st.st_mtime_ns, st.st_size)
        except OSError:
            seen = None
        if seen == self._seen and self.error is None:
            return
        self._seen = seen
        try:
            self._keys = tuple(k.key.encode() for k in read(self.path))
            self.error = None
        except ApiKeyError as exc:
            self._keys = ()
            self.error = str(exc)

    def count(self) -> int:
        self._refresh()
        return len(self._keys)

    def valid(self, given: str | None) -> bool:
        """Whether ``given`` is one of the keys (every key compared, in constant time)."""
        self._refresh()
        if not given:
            return False
        raw = given.encode("utf-8", "replace")
        ok = False
        for key in self._keys:
            ok |= hmac.compare_digest(raw, key)
        return ok
