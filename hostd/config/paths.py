"""Where configurations live: the shipped defaults (inside the package, linked to config/) and
the installed one, which the systemd unit names and ``hostd`` reads without ``--config``."""

from __future__ import annotations

from pathlib import Path

DEFAULT_CONFIG = Path(__file__).resolve().parent.parent / "default_config" / "hostd.yaml"
INSTALLED_CONFIG = Path("/etc/hostd/hostd.yaml")
