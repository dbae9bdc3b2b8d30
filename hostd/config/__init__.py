"""Configuration: a declarative schema, a strict YAML loader, and the shipped default."""

from __future__ import annotations

from hostd.config.loader import Config, ConfigError, defaults, load, loads

__all__ = ["Config", "ConfigError", "defaults", "load", "loads"]
