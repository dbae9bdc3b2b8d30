"""hostctl: the operator's command line. One ``cmd_*.py`` module per verb (or verb group)."""

from __future__ import annotations
