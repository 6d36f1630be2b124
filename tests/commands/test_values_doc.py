"""docs/values.md is generated from the rules (inceptiongs/io/values.py) and the parsers, and
every numeric flag of every command is checked by a rule of the table."""

from __future__ import annotations

import argparse
import importlib.util
from pathlib import Path

from inceptiongs.cli import build_parser
from inceptiongs.io.values import RULES, FlagValue

ROOT = Path(__file__).resolve().parents[2]
GENERATOR = ROOT / "scripts" / "gen_values.py"


def _generator():
    spec = importlib.util.spec_from_file_location("gen_values", GENERATOR)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_values_page_is_current():
    text = (ROOT / "docs" / "values.md").read_text(encoding="utf-8")
    assert text == _generator().render_values_doc(), "run python3 scripts/gen_values.py"


def test_every_numeric_option_of_every_command_follows_a_rule_of_the_table():
    parser = build_parser()
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    loose = []
    for command, command_parser in sub.choices.items():
        for action in command_parser._actions:
            if action.type in (int, float):
                loose.append(f"{command} {action.option_strings}: bare {action.type.__name__}")
            elif isinstance(action.type, FlagValue):
                assert action.type.flag_name in action.option_strings, action.type.flag_name
                if action.type.rule not in RULES.values():
                    loose.append(f"{command} {action.option_strings}: a rule not in the table")
    assert not loose, loose
