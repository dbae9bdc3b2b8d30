"""hostctl's --help: every verb describes each of its options and positionals."""

from __future__ import annotations

import argparse

from hostd.cli.main import build_parser


def _verbs(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(sub.choices)


def test_every_option_and_positional_of_every_verb_has_help() -> None:
    undescribed = [f"{verb} {action.dest}" for verb, p in _verbs(build_parser()).items()
                   for action in p._actions
                   if not isinstance(action, argparse._HelpAction) and not action.help]
    assert undescribed == []


def test_the_json_flag_says_what_stdout_holds() -> None:
    for verb, p in _verbs(build_parser()).items():
        for action in p._actions:
            if "--json" in action.option_strings:
                assert action.help and "JSON" in action.help, verb
