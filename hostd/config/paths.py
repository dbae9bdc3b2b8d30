"""Where configurations live: the shipped defaults (inside the package, linked to config/) and
the installed one, which the systemd unit names and ``hostd`` reads without ``--config``."""

from __future__ import annotations

from pathlib import Path

DEFAULT_CONFIG = Path(__file__).resolve().parent.parent / "default_config" / "hostd.yaml"
INSTALLED_CONFIG = Path("/etc/hostd/hostd.yaml")


def offline_config() -> Path:
    """The configuration ``hostctl slice``/``decompose`` use without ``--config``: the
    printer's installed one when there is one (slice for this machine), else the shipped
    defaults (a computer that only slices)."""
    return INSTALLED_CONFIG if INSTALLED_CONFIG.exists() else DEFAULT_CONFIG
