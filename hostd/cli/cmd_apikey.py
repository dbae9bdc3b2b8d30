"""``hostctl api-key new|list|revoke``: the HTTP API's keys (``http.api_key_file``).

They edit the key file itself (no daemon needed; hostd reads it again when it changes), so
they run as a user who may write it: ``sudo hostctl api-key new`` for the installed
``/etc/hostd/api-keys``.
"""

from __future__ import annotations

import argparse
import json
from typing import Any

from hostd import api_keys
from hostd.cli.errors import EXIT_FAILED, EXIT_OK, EXIT_USAGE, CliError
from hostd.cli.text import printable
from hostd.config import ConfigError, load
from hostd.config.paths import INSTALLED_CONFIG, offline_config


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "api-key", help="make, list or revoke keys of the HTTP API (http.api_key_file)",
        description="Keys of the HTTP API, one a line in http.api_key_file (run as a user "
                    "who may write it: sudo for the installed file). hostd reads the file "
                    "again when it changes.")
    p.add_argument("action", choices=("new", "list", "revoke"),
                   help="new: make a key and print it; list: the keys' first digits and "
                        "labels; revoke: remove the key that starts with PREFIX")
    p.add_argument("prefix", nargs="?", help="revoke: the key, or its first 4+ characters")
    p.add_argument("--label", default="", help="new: what the key is for (e.g. PrusaSlicer)")
    p.add_argument("--config", default=None, metavar="FILE",
                   help=f"config naming http.api_key_file (default: {INSTALLED_CONFIG} if it "
                        "exists, else the shipped defaults)")
    p.add_argument("--file", default=None, help="the key file (default: http.api_key_file)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=run)


def _key_file(args: argparse.Namespace) -> str:
    if args.file:
        return str(args.file)
    try:
        return str(load(args.config or offline_config())["http.api_key_file"])
    except ConfigError as exc:
        raise CliError(str(exc)) from None


def run(args: argparse.Namespace) -> int:
    path = _key_file(args)
    try:
        if args.action == "new":
            key = api_keys.new(path, args.label)
            _show({"key": key.key, "label": key.label, "file": path}, args.json,
                  f"{key.key}\n(added to {path}: {printable(key.label)})")
        elif args.action == "list":
            keys = api_keys.read(path)
            _show({"file": path, "keys": [{"key": k.shown, "label": k.label} for k in keys]},
                  args.json, "\n".join(f"{k.shown}  {printable(k.label)}" for k in keys)
                  or f"no keys in {path} (hostctl api-key new makes one)")
        else:
            if not args.prefix:
                raise CliError("revoke: give the key or its first characters", EXIT_USAGE)
            gone = api_keys.revoke(path, args.prefix)
            _show({"revoked": gone.shown, "label": gone.label, "file": path}, args.json,
                  f"revoked {gone.shown} ({printable(gone.label)})")
    except api_keys.ApiKeyError as exc:
        raise CliError(str(exc), EXIT_FAILED if args.action != "revoke" else EXIT_USAGE
                       ) from None
    return EXIT_OK


def _show(data: dict[str, Any], as_json: bool, text: str) -> None:
    print(json.dumps(data, sort_keys=True) if as_json else text)
