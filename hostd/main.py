"""Entry point of the ``hostd`` daemon."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from hostd import __version__
from hostd.config import ConfigError, load
from hostd.config.paths import DEFAULT_CONFIG, INSTALLED_CONFIG

EXIT_CONFIG = 2


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="hostd", description="Five-axis printer host daemon.")
    p.add_argument("--version", action="version", version=f"hostd {__version__}")
    p.add_argument("--config", metavar="FILE", default=None,
                   help=f"configuration YAML file (default: {INSTALLED_CONFIG})")
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


def config_path(arg: str | None) -> Path:
    """The configuration to run on: ``--config``, else :data:`INSTALLED_CONFIG`.

    Without either hostd refuses (:class:`ConfigError`) rather than run on the built-in
    defaults, whose ``serial.port`` is the emulator: a daemon started without its config on
    the printer's computer would drive a fake printer. An installed file that is there but
    cannot be read (no permission) is returned, for :func:`load` to say why.
    """
    if arg is not None:
        return Path(arg)
    try:
        INSTALLED_CONFIG.stat()
    except FileNotFoundError:
        raise ConfigError(f"no configuration: {INSTALLED_CONFIG} does not exist; pass --config "
                          f"FILE (--config {DEFAULT_CONFIG} runs on the built-in defaults: the "
                          "emulator, serial.port sim://)") from None
    except OSError:
        pass  # there, but not for this user: load() names the file and the error
    return INSTALLED_CONFIG


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.check_config is not None:
        return check_config(args.check_config)
    try:
        config = load(config_path(args.config))
    except ConfigError as exc:
        print(f"hostd: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    from hostd.daemon import run_daemon  # imported late: --check-config stays light

    return run_daemon(config)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
