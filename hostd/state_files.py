"""Directories of the state directory that are the daemon's alone: the upload spool and the
slice cache (mode 0700, their files 0600).

The control socket lets every member of the ``hostd`` group queue and print; the files it
prints from must not be theirs to change. A directory open to the group (0770) let any of
them swap a checked file for another before it printed.
"""

from __future__ import annotations

from pathlib import Path

PRIVATE_DIR = 0o700
PRIVATE_FILE = 0o600


def private_dir(root: Path) -> None:
    """Make ``root`` (if missing) the daemon's alone: mode 0700, each file in it 0600, also
    those an older hostd left open to its group."""
    root.mkdir(parents=True, exist_ok=True, mode=PRIVATE_DIR)
    root.chmod(PRIVATE_DIR)
    for entry in root.iterdir():
        if entry.is_file() and not entry.is_symlink():
            entry.chmod(PRIVATE_FILE)
