"""Options several hostctl verbs share: the decomposition's ``--parts``/``--seed`` (as the
config keys ``decompose.parts``/``decompose.seed``) and ``--allow-overhang``."""

from __future__ import annotations

import argparse
from typing import Any

from hostd.cli.errors import CliError
from hostd.config.schema import SCHEMA


def add_decompose_options(p: argparse.ArgumentParser) -> None:
    """Add ``--parts`` and ``--seed`` (default: the config's)."""
    p.add_argument("--parts", type=int, default=None,
                   help="coarse part count K of the decomposition (default: config "
                        "decompose.parts; 0 automatic)")
    p.add_argument("--seed", type=int, default=None,
                   help="seed of the decomposition (default: config decompose.seed)")


def add_allow_overhang(p: argparse.ArgumentParser, what: str) -> None:
    """Add ``--allow-overhang``: ``what`` says what it lets through."""
    p.add_argument("--allow-overhang", action="store_true",
                   help=f"{what} even when its replay finds unsupported wall layers "
                        "(walls over air); default: refuse it")


def bounded(key: str, value: int) -> int:
    """``--parts``/``--seed`` within the bounds of their config keys (``decompose.*``)."""
    field = SCHEMA["decompose"][key]
    lo, hi = getattr(field, "lo", None), getattr(field, "hi", None)
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        raise CliError(f"--{key} {value}: must lie in [{lo:.0f}, {hi:.0f}] (as decompose.{key})")
    return value


def decompose_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """``{"parts": K, "seed": S}`` for the options given (checked), nothing for the others."""
    return {key: bounded(key, getattr(args, key)) for key in ("parts", "seed")
            if getattr(args, key) is not None}
