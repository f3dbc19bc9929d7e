"""Every command line the README's shell blocks and the ``--help`` epilogs show runs, as written,
on the bundled fixtures (paths relative to the repository, as the README says), and writes what
it names: documentation that a user copies must work."""

from __future__ import annotations

import argparse
import functools
import re
import shlex
import urllib.request
from pathlib import Path

import pytest

from scan2terrain.cli import build_parser, main
from scan2terrain.commands.view import Viewer
from tests.fixtures import ROOT


def shell_lines(text: str) -> list[str]:
    """``scan2terrain ...`` lines of ``text``, continuation lines joined, comments dropped."""
    out: list[str] = []
    pending = ""
    for raw in text.splitlines():
        line = raw.strip()
        if pending:
            line = pending + " " + line
            pending = ""
        if line.endswith("\\"):
            pending = line[:-1].strip()
            continue
        line = re.sub(r"\s+#.*$", "", line)
        if line.startswith("scan2terrain "):
            out.append(line)
    return out


def readme_commands() -> list[str]:
    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"^```(?:bash|sh)\n(.*?)^```", text, flags=re.M | re.S)
    return [c for block in blocks for c in shell_lines(block)]


def help_commands() -> list[str]:
    parser = build_parser()
    epilogs = [parser.epilog or ""]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            epilogs += [sub.epilog or "" for sub in action.choices.values()]
    return [c for e in epilogs for c in shell_lines(e)]


def test_the_documents_show_commands() -> None:
    """Guards the parsers above: both sources name every command at least once."""
    readme, helps = readme_commands(), help_commands()
    commands = {"map2world", "image2world", "dem2world", "octree2world", "bag2world"}
    commands |= {"cloud2world", "convert", "inspect", "fidelity", "view"}
    assert {c.split()[1] for c in readme} == commands
    assert {c.split()[1] for c in helps} == commands
    assert len(readme) >= 15 and len(helps) >= 20


def argv(command: str) -> list[str]:
    """The shell's word splitting and pathname expansion (in the current folder)."""
    words: list[str] = []
    for word in shlex.split(command)[1:]:
        pattern = any(ch in word for ch in "*?[")
        matches = sorted(str(p) for p in Path().glob(word)) if pattern else []
        words += matches or [word]
    return words


def written(words: list[str]) -> Path | None:
    """What the command line says it writes: ``-o OUT``, or convert's target."""
    args = build_parser().parse_args(words)
    target = getattr(args, "out", None) or getattr(args, "target", None)
    return None if target is None else Path(target)


@functools.cache
def _makers() -> dict[str, str]:
    """Each folder or file a documented line writes -> the first such line."""
    makers: dict[str, str] = {}
    for command in sorted(set(readme_commands()) | set(help_commands())):
        target = written(argv(command))
        if target is not None:
            makers.setdefault(target.parts[0], command)
    return makers


def prerequisites(words: list[str]) -> list[str]:
    """The documented command lines that write what ``words`` read (``fidelity tb3_world/...``
    scores the world an earlier line wrote), as a user runs them one after the other."""
    makers = _makers()
    target = written(words)
    return [
        makers[Path(w).parts[0]]
        for w in words[1:]
        if Path(w).parts
        and Path(w).parts[0] in makers
        and not Path(w).exists()
        and (target is None or Path(w).parts[0] != target.parts[0])
    ]


def _fetch_once(viewer: Viewer) -> None:
    with urllib.request.urlopen(viewer.url, timeout=30) as page:
        assert page.status == 200 and b"<html" in page.read()


@pytest.mark.parametrize(
    "command",
    sorted(set(readme_commands()) | set(help_commands())),
    ids=lambda command: command.removeprefix("scan2terrain ")[:90],
)
def test_documented_command_runs(
    command: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    for name in ("fixtures", "configs"):
        (tmp_path / name).symlink_to(ROOT / name, target_is_directory=True)
    monkeypatch.chdir(tmp_path)
    words = argv(command)
    if words[0] == "view":  # serves until Ctrl-C: here, until its page has been fetched once
        monkeypatch.setattr(Viewer, "wait", _fetch_once)
    for before in prerequisites(words):  # what an earlier documented line wrote, made first
        assert main(argv(before)) == 0, before
        capsys.readouterr()
    code = main(words)
    out, err = capsys.readouterr()
    assert code == 0, f"{command}\n{err}"
    assert "internal error" not in err
    target = written(words)
    if target is not None:
        assert target.exists(), f"{command} did not write {target}"
    else:
        assert out.strip(), f"{command} printed nothing"
