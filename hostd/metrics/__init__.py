"""Prometheus metrics: declared in ``specs``, rendered by ``collector``, served by ``server``."""

from __future__ import annotations
