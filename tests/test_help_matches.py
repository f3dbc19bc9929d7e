"""``--help`` says what each command really uses (issues 12, 14 and 29).

For every option of every command that sets a config value (``max_memory`` and ``max_pixels``
included), the default its help states is the value the command is run with when the option is
not given: :func:`scan2terrain.cli.main` is run with only the command's required arguments and
the config it hands the command's run function is read (the run function replaced by one that
keeps it). The help's text is computed when the parser is built and the config when the command
runs, so a help that states a wrong default, or a command that sets a default its help does not
know, fails here. A short table of literal defaults (as README.md documents them) checks both
against numbers written by hand. Every choice an option offers is accepted by the config's
validation.
"""

from __future__ import annotations

import argparse
import dataclasses
import re
from pathlib import Path
from typing import Any

import pytest

from scan2terrain.cli import COMMAND_DEFAULTS, build_parser, dispatch, main
from scan2terrain.config import Config, load_config


def commands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def sets_config(action: argparse.Action) -> bool:
    """An option whose value goes into the config: a section's key, or a top-level one."""
    return (
        bool(action.option_strings)
        and ("." in action.dest or action.dest in ("max_memory", "max_pixels"))
        and not isinstance(action, argparse._StoreConstAction)
    )


CASES = [
    (command, action)
    for command, sub in commands().items()
    for action in sub._actions
    if sets_config(action)
]


def required_argv(command: str, tmp: Path) -> list[str]:
    """The command with its positional arguments and required options only."""
    argv = [command]
    for action in commands()[command]._actions:
        if not action.option_strings:
            argv.append(str(tmp / f"in_{action.dest}"))
        elif action.required:
            argv += [action.option_strings[0], str(tmp / "out")]
    return argv


def run_config(command: str, tmp: Path, monkeypatch: pytest.MonkeyPatch) -> Config:
    """The config ``scan2terrain COMMAND ...`` hands its run function when no option is given."""
    seen: list[Config] = []

    def keep(args: argparse.Namespace, cfg: Config, *_: object) -> str:
        seen.append(cfg)
        return ""

    row = dataclasses.replace(dispatch.COMMANDS[command], run=keep, numba=False)
    monkeypatch.setitem(dispatch.COMMANDS, command, row)
    assert main([*required_argv(command, tmp), "-q"]) == 0
    (cfg,) = seen
    return cfg


def value_at(cfg: Config, dest: str) -> Any:
    value: Any = cfg
    for part in dest.split("."):
        value = getattr(value, part)
    return value


def stated_default(action: argparse.Action) -> str | None:
    """What ``(default: X)`` at the end of the help says, or None when it says none."""
    m = re.search(r"\(default: ([^()]*)\)$", action.help or "")
    return None if m is None else m.group(1)


def read_stated(text: str, like: Any) -> Any:
    """The help's words for a default as a value of the type of ``like``."""
    if isinstance(like, bool):
        return {"True": True, "False": False}[text]
    if isinstance(like, int):
        power = re.fullmatch(r"2\^(\d+)", text)
        return 1 << int(power.group(1)) if power else int(text)
    if isinstance(like, float):
        return float(text)
    return text


@pytest.fixture(scope="module")
def used(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Config]:
    """Each command's config as it runs without options."""
    tmp = tmp_path_factory.mktemp("help")
    with pytest.MonkeyPatch.context() as monkeypatch:
        return {name: run_config(name, tmp, monkeypatch) for name in commands()}


@pytest.mark.parametrize(
    ("command", "action"), CASES, ids=[f"{c}-{a.option_strings[-1]}" for c, a in CASES]
)
def test_help_default_is_what_the_command_runs_with(
    command: str, action: argparse.Action, used: dict[str, Config]
) -> None:
    value = value_at(used[command], action.dest)
    flag = action.option_strings[-1]
    stated = stated_default(action)
    if value is None:
        # No value to state: the help says in words what happens without the option, and
        # names no number the command does not use.
        assert "default" in (action.help or ""), f"{command} {flag}: {action.help!r}"
        assert stated is None or not re.fullmatch(r"[-+0-9.e^]+|True|False", stated), (
            f"{command} {flag}: help says default {stated!r}, the command runs with None"
        )
        return
    assert stated is not None, f"{command} {flag}: no default in {action.help!r}"
    assert read_stated(stated, value) == value, (
        f"{command} {flag}: help says default {stated!r}, the command runs with {value!r}"
    )


@pytest.mark.parametrize(
    ("command", "action"), CASES, ids=[f"{c}-{a.option_strings[-1]}" for c, a in CASES]
)
def test_every_choice_is_accepted(command: str, action: argparse.Action) -> None:
    value = value_at(load_config(None, {}, defaults=COMMAND_DEFAULTS.get(command)), action.dest)
    for choice in action.choices or ():
        load_config(None, {action.dest: choice}, defaults=COMMAND_DEFAULTS.get(command))
    if action.choices and not isinstance(value, bool) and value is not None:
        assert value in action.choices, f"{action.dest}: default {value!r} not a choice"


#: (command, flag) -> the default README.md and the command's help state, written by hand.
LITERAL = {
    ("map2world", "--height"): "2.0",
    ("map2world", "--simulator"): "both",
    ("map2world", "--filter"): "thin_wall",
    ("map2world", "--bit-depth"): "8",
    ("image2world", "--max-pixels"): "2^28",
    ("octree2world", "--max-memory"): "8192",
    ("octree2world", "--resolution"): "0.05",
    ("bag2world", "--max-memory"): "8192",
    ("cloud2world", "--max-memory"): "8192",
    ("dem2world", "--simulator"): "gz",
    ("dem2world", "--bit-depth"): "16",
    ("dem2world", "--filter"): "none",
    ("fidelity", "--simulator"): "gz",
}


@pytest.mark.parametrize(
    ("command", "flag"), sorted(LITERAL), ids=[f"{c}{f}" for c, f in sorted(LITERAL)]
)
def test_help_states_the_documented_default(
    command: str, flag: str, used: dict[str, Config]
) -> None:
    (action,) = [a for a in commands()[command]._actions if flag in a.option_strings]
    assert stated_default(action) == LITERAL[command, flag]
    value = value_at(used[command], action.dest)
    assert read_stated(LITERAL[command, flag], value) == value


def test_cases_cover_every_command_and_the_limits() -> None:
    # view sets no config value: it serves a folder (its --host and --port state their defaults
    # in their help, checked by test_view)
    assert {c for c, _ in CASES} == set(commands()) - {"view"}
    flags = {(c, a.option_strings[-1]) for c, a in CASES}
    for command in ("octree2world", "bag2world", "cloud2world"):
        assert (command, "--max-memory") in flags
    assert ("map2world", "--max-pixels") in flags
    assert len(CASES) > 150
