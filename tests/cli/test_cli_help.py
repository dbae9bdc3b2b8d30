"""hostctl's --help: every verb describes each of its options and positionals."""

from __future__ import annotations

import argparse
import re

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


def test_the_synopsis_in_the_protocol_doc_lists_every_verb_and_option() -> None:
    """docs/control-protocol.md's hostctl synopsis: a line per verb, naming its options."""
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[2] / "docs" / "control-protocol.md").read_text()
    block = doc.split("## hostctl", 1)[1].split("```")[1]
    lines = {line.split()[1]: line for line in block.splitlines() if line.startswith("hostctl ")}
    missing = [f"{verb} {action.dest}" for verb, p in _verbs(build_parser()).items()
               for action in p._actions if action.option_strings
               and not isinstance(action, argparse._HelpAction)
               and not set(action.option_strings) & set(re.findall(r"-[-\w]+",
                                                                   lines.get(verb, "")))]
    assert missing == []
    assert lines["[--socket"].startswith("hostctl [--socket PATH] VERB")
