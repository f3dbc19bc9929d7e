"""Issue 25 item 12: the messages a user reads first. A usage mistake is one error line first,
then a short usage; a typo gets a "did you mean"; errors name the flag a user types; printed
numbers and command lines are the ones a user would type back."""

from __future__ import annotations

import shlex
from pathlib import Path

import numpy as np
import pytest

from scan2terrain.cli import main
from tests.conftest import write_map
from tests.fixtures import MAPS, SFBAY, SIMPLE_LAS

TB3 = str(MAPS["tb3"])


def usage_error(argv: list[str], capsys: pytest.CaptureFixture[str]) -> list[str]:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    return captured.err.splitlines()


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["map2world", TB3, "-o", "x", "--heigth", "2"], ["--heigth", "did you mean --height?"]),
        (["map2world", TB3, "--heigth", "2"], ["--heigth", "did you mean --height?"]),
        (["map2world", TB3, "-o", "x", "--upsampel", "2"], ["did you mean --upsample?"]),
        (["map2world", TB3], ["the following arguments are required: -o/--out"]),
        (
            ["map2world", TB3, "-o", "x", "--geometry", "box"],
            ["invalid choice: 'box'", "did you mean 'boxes'?"],
        ),
        (["map2wrld", TB3, "-o", "x"], ["invalid choice: 'map2wrld'", "did you mean 'map2world'?"]),
        (["bag2world", "b.bag", "-o", "x", "--topik", "/scan"], ["did you mean --topic?"]),
    ],
)
def test_usage_mistakes_are_one_error_line_then_a_short_usage(
    argv: list[str], words: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    lines = usage_error(argv, capsys)
    assert lines[0].startswith("scan2terrain") and ": error: " in lines[0], lines
    for w in words:
        assert w in lines[0], lines
    assert len(lines) <= 3, lines  # the error, a one-line usage, where the help is
    assert lines[1].startswith("usage: scan2terrain"), lines
    assert "--help" in lines[-1]


def test_help_offers_only_what_the_command_takes(capsys: pytest.CaptureFixture[str]) -> None:
    """map2world refuses voxels and has no use for --max-memory; dem2world ignores --height and
    --invert: none of them is offered, and giving one is a usage error naming it."""
    for command, absent in [
        ("map2world", ["voxels", "--max-memory"]),
        ("image2world", ["voxels", "--max-memory"]),
        ("dem2world", ["--height ", "--invert", "--max-memory"]),
    ]:
        with pytest.raises(SystemExit):
            main([command, "--help"])
        text = capsys.readouterr().out
        for word in absent:
            assert word not in text, (command, word)
    for command, src, bad in [
        ("map2world", TB3, ["--geometry", "voxels"]),
        ("map2world", TB3, ["--max-memory", "100"]),
        ("dem2world", "d.tif", ["--height", "3"]),
    ]:
        lines = usage_error([command, src, "-o", "x", *bad], capsys)
        assert bad[-1 if bad[0] == "--geometry" else 0] in lines[0], lines
    for command in ("octree2world", "bag2world", "cloud2world"):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        text = capsys.readouterr().out
        assert "voxels" in text and "--max-memory" in text


def test_config_errors_name_the_flag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A value refused by the config's checks names the flag a user types, and the config key
    that a YAML file would set."""
    out = str(tmp_path / "w")
    assert main(["map2world", TB3, "-o", out, "--filter-size", "4"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--filter-size" in err and "filter.size" in err, err
    cfg = tmp_path / "c.yaml"
    cfg.write_text("world:\n  geometry: voxels\n")
    assert main(["map2world", TB3, "-o", out, "--config", str(cfg)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--geometry voxels" in err and "world.geometry" in err, err
    cloud = str(SIMPLE_LAS)
    assert main(["cloud2world", cloud, "-o", out, "--insert", "raycast", "--stream"]) == 2
    err = capsys.readouterr().err
    assert "--insert raycast" in err, err


def test_printed_numbers_are_rounded_and_paths_quoted(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Offsets print as a user would type them (no 28.950000000000003), and every printed
    command line can be pasted into a shell when paths hold spaces."""
    good = write_map(
        tmp_path / "my maps", np.full((21, 31), 254, np.uint8), origin="[-1.15, -0.35, 0.0]"
    )
    good.with_name("m.png")
    out = tmp_path / "my worlds" / "w 1"
    (tmp_path / "my worlds").mkdir()
    assert main(["map2world", str(good), "-o", str(out), "--geometry", "heightmap"]) == 0
    text = capsys.readouterr().out
    assert "0000000" not in text and "9999999" not in text, text
    commands = [ln.strip() for ln in text.splitlines() if ln.strip().startswith(("GZ_", "GAZEBO"))]
    assert commands, text
    for line in commands:
        words = shlex.split(line)
        assert any(w.endswith(("world_gz.sdf", "world_classic.world")) for w in words), line
        for w in words:
            if w.endswith((".sdf", ".world")):
                assert Path(w).exists(), (line, w)


def test_gz_only_runs_print_no_classic_lines(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    for geometry in ("mesh", "heightmap"):
        out = str(tmp_path / geometry)
        argv = ["map2world", TB3, "-o", out, "--simulator", "gz", "--geometry", geometry]
        assert main(argv) == 0
        text = capsys.readouterr().out
        assert "Classic" not in text and "classic" not in text, text
        assert "gz sim" in text
    dem = str(SFBAY)
    assert main(["dem2world", dem, "-o", str(tmp_path / "dem")]) == 0  # gz-only by default
    text = capsys.readouterr().out
    assert "Classic" not in text and "gz sim" in text, text
