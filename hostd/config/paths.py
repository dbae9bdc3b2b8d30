"""Where the shipped default configuration lives (inside the package, linked to config/)."""

from __future__ import annotations

from pathlib import Path

DEFAULT_CONFIG = Path(__file__).resolve().parent.parent / "default_config" / "hostd.yaml"
