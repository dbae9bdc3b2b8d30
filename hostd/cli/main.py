"""Entry point of ``hostctl``: discovers the verbs in ``hostd/cli/cmd_*.py`` and runs one.

Each verb module defines ``register(subparsers) -> None``, adding its parser(s) with
``set_defaults(func=...)``; the function takes the parsed arguments and returns an exit code.
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import sys
from collections.abc import Sequence

import hostd.cli
from hostd import __version__
from hostd.cli.client import DEFAULT_SOCKET
from hostd.cli.errors import EXIT_INTERRUPTED, EXIT_PIPE, EXIT_USAGE, CliError


def _socket_arg(text: str) -> str:
    """An argparse type: a non-empty path (an empty one would quietly mean the default)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("empty path")
    return text


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="hostctl", description="Control hostd and run the five-axis slicer offline.")
    parser.add_argument("--version", action="version", version=f"hostctl {__version__}")
    parser.add_argument("--socket", default=None, type=_socket_arg,
                        help=f"hostd control socket (default: $HOSTD_SOCKET or {DEFAULT_SOCKET})")
    subparsers = parser.add_subparsers(dest="verb", metavar="VERB")
    subparsers.required = True
    for info in sorted(pkgutil.iter_modules(hostd.cli.__path__), key=lambda m: m.name):
        if info.name.startswith("cmd_"):
            importlib.import_module(f"hostd.cli.{info.name}").register(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        code = int(args.func(args) or 0)
        sys.stdout.flush()  # here, where a reader gone is caught, not at the exit
        return code
    except CliError as exc:
        print(f"hostctl: {exc}", file=sys.stderr)
        return exc.code
    except KeyboardInterrupt:
        print("hostctl: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        return _reader_gone()


def _reader_gone() -> int:
    """stdout's reader went away (``hostctl watch | head -1``): exit quietly, as a command
    killed by SIGPIPE would. stdout now points at /dev/null, so the flush at exit of what
    is still buffered does not fail a second time."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, sys.stdout.fileno())
    finally:
        os.close(devnull)
    return EXIT_PIPE


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

__all__ = ["EXIT_USAGE", "main"]
