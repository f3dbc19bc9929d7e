"""Each shared option is declared once (cli/options.py) and attached to every command that
takes it: the same flag means the same thing, with the same help, everywhere; the commands the
parser offers are exactly the dispatch table's."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from scan2terrain.cli import main
from scan2terrain.cli.dispatch import COMMANDS
from scan2terrain.cli.parser import Parser, build_parser
from tests.fixtures import SICK_ROS1_DIR

SHARED = ("-v", "-q", "--config", "--overwrite", "--max-range", "--las-classes", "--simulator")


def _options(parser: Parser) -> dict[str, tuple[str, str, str]]:
    """Flag -> (dest, help without its default, choices) of one command."""
    out = {}
    for a in parser._actions:
        for flag in a.option_strings:
            text = re.sub(r" \(default: [^)]*\)$", "", a.help or "")
            out[flag] = (a.dest, text, " ".join(map(str, a.choices or ())))
    return out


def test_the_parser_offers_exactly_the_dispatch_table_s_commands() -> None:
    parser = build_parser()
    assert isinstance(parser, Parser)
    assert list(parser.commands) == list(COMMANDS)


def test_every_flag_means_one_thing_in_every_command() -> None:
    parser = build_parser()
    assert isinstance(parser, Parser)
    # (flag, dest, choices) -> help -> commands: one flag may set another command's own key
    # (--resolution), or offer fewer choices where a command takes fewer (and its help says
    # only what it offers: test_cli_messages)
    seen: dict[tuple[str, str, str], dict[str, list[str]]] = {}
    for name, (sub, _) in parser.commands.items():
        for flag, (dest, text, choices) in _options(sub).items():
            seen.setdefault((flag, dest, choices), {}).setdefault(text, []).append(name)
    differ = {f: v for f, v in seen.items() if len(v) > 1}
    assert not differ, differ
    for flag in SHARED:  # each declared once, and taken by more than one command
        taking = [v.values() for (f, _, _), v in seen.items() if f == flag]
        commands = [c for texts in taking for cs in texts for c in cs]
        assert len(commands) > 1, (flag, commands)


def test_the_shared_run_options_reach_every_command() -> None:
    parser = build_parser()
    assert isinstance(parser, Parser)
    for name, (sub, _) in parser.commands.items():
        flags = _options(sub)
        # view serves a folder as it was written: no config value changes what it shows
        shared = {"-v", "-q"} if name == "view" else {"-v", "-q", "--config"}
        assert shared <= set(flags), name


@pytest.mark.parametrize("command", ["inspect", "convert"])
def test_quiet_prints_nothing_in_every_command(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str
) -> None:
    bag = SICK_ROS1_DIR
    argv = [command, str(bag), "-q", "--topic", "/sick_lms_1xx/scan", "--pose", *"000000"]
    if command == "convert":
        argv.insert(2, str(tmp_path / "o.xyz"))
    assert main(argv) == 0
    assert capsys.readouterr().out == ""
    assert main([a for a in argv if a != "-q"] + (["--overwrite"] * (command == "convert"))) == 0
    assert capsys.readouterr().out.strip()
