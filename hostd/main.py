"""Entry point of the ``hostd`` daemon."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from hostd import __version__
from hostd.config import ConfigError, load
from hostd.config.paths import DEFAULT_CONFIG

EXIT_CONFIG = 2


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="hostd", description="Five-axis printer host daemon.")
    p.add_argument("--version", action="version", version=f"hostd {__version__}")
    p.add_argument("--config", default=str(DEFAULT_CONFIG), help="configuration YAML file")
    p.add_argument("--check-config", metavar="FILE", default=None,
                   help="validate FILE, print 'ok' or the error, and exit")
    return p


def check_config(path: str) -> int:
    try:
        load(path)
    except ConfigError as exc:
        print(exc)
        return EXIT_CONFIG
    print("ok")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.check_config is not None:
        return check_config(args.check_config)
    try:
        config = load(args.config)
    except ConfigError as exc:
        print(f"hostd: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    from hostd.daemon import run_daemon  # imported late: --check-config stays light

    return run_daemon(config)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
