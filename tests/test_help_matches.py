"""``--help`` says what each command really uses: for every option of every command that sets a
config value, the default its help states is that command's effective default (the config's,
after the command's own ``COMMAND_DEFAULTS``), and every choice it offers is accepted by the
config's validation. Help can then not drift from behaviour again (issues 12 and 14)."""

from __future__ import annotations

import argparse
import re
from typing import Any

import pytest

from scan2terrain.cli import COMMAND_DEFAULTS, build_parser
from scan2terrain.config import Config, load_config


def commands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def effective(command: str, dest: str) -> Any:
    cfg: Any = load_config(None, {}, defaults=COMMAND_DEFAULTS.get(command))
    for part in dest.split("."):
        cfg = getattr(cfg, part)
    return cfg


def shown(value: Any) -> set[str]:
    """The ways a help text may write ``value``."""
    if isinstance(value, float):
        return {repr(value), f"{value:g}"}
    if isinstance(value, int) and value >= 1 << 20 and value & (value - 1) == 0:
        return {str(value), f"2^{value.bit_length() - 1}"}
    return {str(value)}


CASES = [
    (command, action)
    for command, sub in commands().items()
    for action in sub._actions
    if action.dest
    and ("." in action.dest or action.dest == "max_pixels")
    and not isinstance(action, argparse._StoreConstAction)
]


@pytest.mark.parametrize(
    ("command", "action"), CASES, ids=[f"{c}-{a.option_strings[0]}" for c, a in CASES]
)
def test_help_default_and_choices_are_the_commands_own(
    command: str, action: argparse.Action
) -> None:
    value = effective(command, action.dest)
    text = action.help or ""
    if value is None:
        # No value to state: the help says in words what happens without the option.
        assert "default" in text, f"{command} {action.option_strings[0]}: {text!r}"
    else:
        stated = re.search(r"\(default: ([^()]*)\)$", text)
        assert stated is not None, f"{command} {action.option_strings[0]}: no default in {text!r}"
        assert stated.group(1) in shown(value), (
            f"{command} {action.option_strings[0]}: help says default {stated.group(1)!r}, "
            f"the command uses {value!r}"
        )
    for choice in action.choices or ():
        load_config(None, {action.dest: choice}, defaults=COMMAND_DEFAULTS.get(command))
        if not isinstance(value, bool) and value is not None:
            assert value in action.choices, f"{action.dest}: default {value!r} not a choice"


def test_cases_cover_every_command() -> None:
    assert {c for c, _ in CASES} == set(commands())
    assert Config().filter.kind == "thin_wall"  # the sweep reads real defaults
