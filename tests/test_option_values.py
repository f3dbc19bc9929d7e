"""Every numeric option of every command, given absurd values (NaN, infinities, zero, negative,
tiny, huge, a 400-digit integer): exit 0 with a world, or exit 2 with one line; never exit 1,
never a MemoryError (issues 12 and 13: values that make sense, checked before any work).

The inputs are tiny, so the runs that are accepted finish in a blink.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest

from scan2terrain.cli import build_parser, main
from scan2terrain.commands.view import Viewer
from tests.bagmaker import synthetic_room
from tests.conftest import write_map
from tests.fixtures import MOON

FLOATS = ["nan", "inf", "-inf", "1e300", "-1e300", "0", "-1", "1e-300", "123456"]
INTS = ["-1", "0", "3", "1099511627776", "9" * 400]


@pytest.fixture(scope="module")
def inputs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, list[str]]:
    root = tmp_path_factory.mktemp("inputs")
    pixels = np.full((12, 16), 254, dtype=np.uint8)
    pixels[3:9, 4] = 0
    pixels[0, :] = 205
    yaml_path = write_map(root / "map", pixels)
    (root / "scan.dat").write_text("NODE 0 0 0 0 0 0\n1 0 0\n0 1 0.5\n-1 -1 1\n")
    (root / "cloud.xyz").write_text("0 0 0\n1 0 0.2\n0 1 0.4\n1 1 0.1\n")
    from PIL import Image

    Image.fromarray((np.indices((9, 9)).sum(axis=0) * 14).astype(np.uint8)).save(root / "i.png")
    bag = synthetic_room("tf", n_scans=6).write(root / "room.bag", "ros1")
    world = root / "world"
    assert main(["map2world", str(yaml_path), "-o", str(world), "-q"]) == 0
    return {
        "fidelity": [str(world / "world_gz.sdf"), str(root / "scan.dat")],
        "map2world": [str(yaml_path)],
        "image2world": [str(root / "i.png")],
        "octree2world": [str(root / "scan.dat")],
        "cloud2world": [str(root / "cloud.xyz")],
        "bag2world": [str(bag)],
        "convert": [str(root / "cloud.xyz"), "OUT.ply"],
        "inspect": [str(bag)],
        "dem2world": [str(MOON)],
        "view": [str(world)],
    }


def numeric_options() -> list[tuple[str, str, str]]:
    """(command, option, value) for every int/float option of every command."""
    cases = []
    parser = build_parser()
    for action in parser._actions:
        if not isinstance(action, argparse._SubParsersAction):
            continue
        for command, sub in action.choices.items():
            for opt in sub._actions:
                if not opt.option_strings or opt.type not in (int, float):
                    continue
                values = FLOATS if opt.type is float else INTS
                if opt.option_strings[0] == "--workers":  # no Dask cluster for a sweep
                    values = [v for v in values if v != "3"]
                cases += [(command, opt.option_strings[0], v) for v in values]
    return cases


def test_every_command_has_numeric_options() -> None:
    assert {c for c, _, _ in numeric_options()} == {
        "map2world",
        "image2world",
        "octree2world",
        "bag2world",
        "cloud2world",
        "convert",
        "inspect",
        "dem2world",
        "fidelity",
        "view",
    }


def argv_for(
    command: str, option: str, value: str, inputs: dict[str, list[str]], out: Path
) -> list[str]:
    args = [command]
    files = inputs[command]
    if command == "convert":
        args += [files[0], str(out.with_suffix(".ply"))]
    else:
        args += files
    if command not in ("convert", "inspect", "view"):
        args += ["-o", str(out)]
    if command == "view":
        args += ["--no-browser"]
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    opt = next(o for o in sub.choices[command]._actions if option in o.option_strings)
    n = opt.nargs if isinstance(opt.nargs, int) else 1
    if option == "--origin":  # [x, y] or [x, y, yaw]
        n = 2
    # --opt=VALUE: argparse would take a lone "-inf" for an option name
    args += [f"{option}={value}"] if n == 1 else [option, *([value] * n)]
    if command in ("octree2world", "cloud2world", "bag2world") and option != "--resolution":
        args += ["--resolution", "0.25"]
    if command == "cloud2world" and option in ("--workers", "--chunk-points", "--tile-cells"):
        args += ["--stream"]
    return args


@pytest.mark.parametrize(("command", "option", "value"), numeric_options())
def test_absurd_values_are_refused_or_work(
    *,
    command: str,
    option: str,
    value: str,
    inputs: dict[str, list[str]],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    out = tmp_path / "out"
    argv = argv_for(command, option, value, inputs, out)
    if command == "view":  # a port that serves: stop at once instead of waiting for Ctrl-C
        monkeypatch.setattr(Viewer, "wait", lambda viewer: None)
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse: not a number, not a choice (usage line + error)
        err = capsys.readouterr().err.strip().splitlines()
        assert exc.code == 2 and err[0].startswith(f"scan2terrain {command}: error:"), err
        return
    err = capsys.readouterr().err.strip().splitlines()
    assert code in (0, 2), (argv, err)
    if code == 2:
        assert len(err) == 1 and err[0].startswith("scan2terrain: error:"), err
        assert not out.exists()
        assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []
