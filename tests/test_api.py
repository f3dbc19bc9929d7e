"""The Python API (``scan2terrain.api``, re-exported as ``scan2terrain.map2world`` etc.): every
command through it writes the same bytes as the command line, a bad argument raises the refusal
the command line prints (same class, same words), and its Result says what was written."""

from __future__ import annotations

import re
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
import yaml

import scan2terrain
from scan2terrain import api
from scan2terrain.cli import main
from scan2terrain.errors import ConfigError, InputError, OutputError, Scan2TerrainError
from tests.fixtures import BOWL, GEB079, HDL_PCD, ROOT, SFBAY, SICK_ROS1_DIR, TB3_MAP

SICK_TOPIC = "/sick_lms_1xx/scan"
POSE = ("0", "0", "0.3", "0", "0", "0")

#: command -> (its command line, the same call through the API), both writing into the
#: current folder: options of every kind (a value, a negative number, a flag without a value,
#: several values, a repeatable flag, a config file).
CASES: dict[str, tuple[list[str], Callable[[], api.Result]]] = {
    "map2world": (
        [
            *("map2world", str(TB3_MAP), "-o", "w", "--height", "2.5", "--geometry", "boxes"),
            *("--no-filter", "--simulator", "gz", "--config", "cfg.yaml"),
        ],
        lambda: api.map2world(
            TB3_MAP,
            "w",
            height=2.5,
            geometry="boxes",
            no_filter=True,
            simulator="gz",
            config=Path("cfg.yaml"),
        ),
    ),
    "image2world": (
        [
            *("image2world", str(BOWL), "-o", "w", "--resolution", "0.1", "--height", "1.5"),
            *("--invert", "--origin", "1", "-2"),
        ],
        lambda: api.image2world(
            str(BOWL), "w", resolution=0.1, height=1.5, invert=True, origin=(1, -2)
        ),
    ),
    "dem2world": (
        ["dem2world", str(SFBAY), "-o", "w", "--offset-x", "-3"],
        lambda: api.dem2world(SFBAY, "w", offset_x=-3),
    ),
    "octree2world": (
        ["octree2world", str(GEB079), "-o", "w", "--z-min", "0.1", "--z-max", "1.8"],
        lambda: api.octree2world(GEB079, "w", z_min=0.1, z_max=1.8),
    ),
    "bag2world": (
        ["bag2world", str(SICK_ROS1_DIR), "-o", "w", "--topic", SICK_TOPIC, "--pose", *POSE],
        lambda: api.bag2world(SICK_ROS1_DIR, "w", topic=[SICK_TOPIC], pose=(0, 0, 0.3, 0, 0, 0)),
    ),
    "cloud2world": (
        ["cloud2world", str(HDL_PCD), "-o", "w", "--z-min", "-1.2", "--z-max", "0.5"],
        lambda: api.cloud2world([HDL_PCD], "w", z_min=-1.2, z_max=0.5),
    ),
    "convert": (
        ["convert", str(HDL_PCD), "w.ply", "--outliers", "2"],
        lambda: api.convert(HDL_PCD, "w.ply", outliers=2),
    ),
    "inspect": (
        ["inspect", str(SICK_ROS1_DIR), "--max-range", "20"],
        lambda: api.inspect(SICK_ROS1_DIR, max_range=20.0),
    ),
    "fidelity": (
        [
            *("fidelity", "world/world_gz.sdf", str(SICK_ROS1_DIR), "-o", "w"),
            *("--topic", SICK_TOPIC, "--pose", *POSE),
        ],
        lambda: api.fidelity(
            "world/world_gz.sdf", [SICK_ROS1_DIR], "w", topic=SICK_TOPIC, pose=[0, 0, 0.3, 0, 0, 0]
        ),
    ),
}


def _prepare(folder: Path, command: str) -> None:
    """What a case reads besides the fixtures: a config file, a world to score."""
    folder.mkdir()
    (folder / "cfg.yaml").write_text("terrain:\n  upsample: 2\n")
    if command == "fidelity":
        world = ["bag2world", str(SICK_ROS1_DIR), "-o", str(folder / "world"), "--no-fidelity"]
        assert main([*world, "--topic", SICK_TOPIC, "--pose", *POSE, "-q"]) == 0


def tree(folder: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }


@pytest.fixture(scope="module", params=sorted(CASES))
def both(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> tuple[str, Path, Path, str, api.Result]:
    """A command run through the CLI in one folder and through the API in another: (command,
    the CLI's folder, the API's folder, what the CLI printed, the API's Result)."""
    command: str = request.param
    argv, call = CASES[command]
    tmp = tmp_path_factory.mktemp(command)
    cli, py = tmp / "cli", tmp / "api"
    with pytest.MonkeyPatch.context() as mp:
        _prepare(cli, command)
        mp.chdir(cli)
        printed = subprocess.run(
            [sys.executable, "-m", "scan2terrain", *argv],
            capture_output=True,
            text=True,
            check=False,
        )
        assert printed.returncode == 0, printed.stderr
        _prepare(py, command)
        mp.chdir(py)
        result = call()
    return command, cli, py, printed.stdout, result


def test_every_command_writes_the_same_bytes_as_the_cli(
    both: tuple[str, Path, Path, str, api.Result],
) -> None:
    command, cli, py, _, _ = both
    written, expected = tree(py), tree(cli)
    assert set(written) == set(expected)
    differ = [name for name in expected if written[name] != expected[name]]
    assert differ == [], f"{command}: {differ}"
    made = [n for n in expected if n != "cfg.yaml" and not n.startswith("world/")]  # not inputs
    assert bool(made) == (command != "inspect"), made


def test_the_result_says_what_the_cli_printed_and_what_was_written(
    both: tuple[str, Path, Path, str, api.Result],
) -> None:
    command, cli, py, printed, result = both
    assert result.command == command
    # The report is the CLI's, word for word (absolute paths aside: another folder).
    assert result.text.replace(str(py), "ROOT") + "\n" == printed.replace(str(cli), "ROOT")
    assert all(p.is_absolute() and p.is_file() for p in result.paths)
    if command == "inspect":
        assert result.out is None and result.paths == () and result.text.strip()
        return
    assert result.out == Path("w" if command != "convert" else "w.ply")
    if command == "convert":
        assert result.paths == ((py / "w.ply").absolute(),)
        return
    assert result.paths == tuple(sorted(p.absolute() for p in (py / "w").rglob("*") if p.is_file()))
    for note in result.notes:
        assert note in result.text
    fidelity = py / "w" / "fidelity.yaml"
    if fidelity.exists():
        assert result.fidelity == yaml.safe_load(fidelity.read_text())
        assert result.fidelity is not None
        assert all(w["beams"] > 0 for w in result.fidelity["worlds"].values())
    else:
        assert result.fidelity is None
    if command == "fidelity":
        assert result.spawn is None and result.worlds == ()
        return
    spawn = yaml.safe_load((py / "w" / "spawn.yaml").read_text())
    assert result.spawn is not None and result.spawn.why == spawn["why"]
    assert {w.simulator: list(w.spawn or ()) for w in result.worlds} == {
        sim: spawn[sim]["pose"] for sim in ("gz", "classic") if sim in spawn
    }
    assert {w.path for w in result.worlds} <= set(result.paths)


# --- refusals -------------------------------------------------------------------------------


def cli_error(capsys: pytest.CaptureFixture[str], argv: list[str]) -> str:
    """The error line the CLI prints for ``argv`` (exit 2), without its ``prog: error:``."""
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's refusals
        code = int(exc.code or 0)
    assert code == 2
    first = capsys.readouterr().err.splitlines()[0]
    return re.sub(r"^scan2terrain( \w+)?: error: ", "", first)


REFUSALS: dict[str, tuple[list[str], Callable[[Path], object], type[Exception]]] = {
    "not a choice": (
        ["--geometry", "voxel"],
        lambda out: api.map2world(TB3_MAP, out, geometry="voxel"),
        ConfigError,
    ),
    "not a number": (
        ["--upsample", "two"],
        lambda out: api.map2world(TB3_MAP, out, upsample="two"),
        ConfigError,
    ),
    "out of range": (
        ["--upsample", "0"],
        lambda out: api.map2world(TB3_MAP, out, upsample=0),
        ConfigError,
    ),
    "not an integer": (
        ["--upsample", "2.5"],
        lambda out: api.map2world(TB3_MAP, out, upsample=2.5),
        ConfigError,
    ),
    "option combination": (
        ["--simulator", "classic", "--bit-depth", "16", "--geometry", "heightmap"],
        lambda out: api.map2world(
            TB3_MAP, out, simulator="classic", bit_depth=16, geometry="heightmap"
        ),
        ConfigError,
    ),
    "missing input": (
        [],
        lambda out: api.map2world(out.parent / "nope.yaml", out),
        InputError,
    ),
    "missing config": (
        ["--config", "no_such_config.yaml"],
        lambda out: api.map2world(TB3_MAP, out, config="no_such_config.yaml"),
        Scan2TerrainError,
    ),
}


@pytest.mark.parametrize("case", sorted(REFUSALS))
def test_a_bad_argument_raises_the_refusal_the_cli_prints(
    case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    flags, call, kind = REFUSALS[case]
    out = tmp_path / "w"
    source = str(tmp_path / "nope.yaml") if case == "missing input" else str(TB3_MAP)
    expected = cli_error(capsys, ["map2world", source, "-o", str(out), *flags])
    with pytest.raises(kind) as info:
        call(out)
    assert str(info.value) == expected
    assert isinstance(info.value, Scan2TerrainError)
    assert not out.exists() and list(tmp_path.iterdir()) == []  # nothing written


def test_an_existing_output_is_refused_as_by_the_cli(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "w"
    out.mkdir()
    expected = cli_error(capsys, ["map2world", str(TB3_MAP), "-o", str(out)])
    with pytest.raises(OutputError) as info:
        api.map2world(TB3_MAP, out)
    assert str(info.value) == expected and "--overwrite" in expected
    assert list(out.iterdir()) == []


def test_a_wrong_count_of_values_is_refused_as_by_the_cli(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["bag2world", str(SICK_ROS1_DIR), "-o", str(tmp_path / "w"), "--pose", "0", "0", "1"]
    expected = cli_error(capsys, argv)
    with pytest.raises(ConfigError) as info:
        api.bag2world(SICK_ROS1_DIR, tmp_path / "w", pose=(0, 0, 1))
    assert str(info.value) == expected and "--pose" in expected


@pytest.mark.parametrize(
    ("keyword", "near"),
    [
        ("hieght", "'height'"),  # a typo: the nearest keywords
        ("wall_face", "'wall_faces'"),
        ("resolution", ""),  # another command's option (image2world's, the octree's)
        ("quiet", ""),  # the CLI's own: the API prints nothing
        ("out_dir", "'out'"),
    ],
)
def test_an_unknown_keyword_is_a_type_error_naming_it_and_the_nearest(
    keyword: str, near: str, tmp_path: Path
) -> None:
    with pytest.raises(TypeError) as info:
        api.map2world(TB3_MAP, tmp_path / "w", **{keyword: 1})
    text = str(info.value)
    assert text.startswith(f"map2world() got an unexpected keyword argument '{keyword}'"), text
    assert near in text
    assert not (tmp_path / "w").exists()


def test_a_flag_without_a_value_takes_a_bool(tmp_path: Path) -> None:
    with pytest.raises(TypeError, match=r"no_filter=True \(--no-filter\) or False"):
        api.map2world(TB3_MAP, tmp_path / "w", no_filter="yes")


def test_none_is_the_default(tmp_path: Path) -> None:
    """A keyword given None is as if not given (as a flag not typed), so callers can pass
    their own optional values straight through."""
    a = api.map2world(TB3_MAP, tmp_path / "a", height=None, no_filter=False)
    b = api.map2world(TB3_MAP, tmp_path / "b")
    assert tree(tmp_path / "a") == tree(tmp_path / "b")
    assert a.text.replace("/a", "/b") == b.text


def test_keywords_are_the_long_flags(tmp_path: Path) -> None:
    words = api.keywords("bag2world")
    assert {"wall_faces", "no_filter", "max_range", "topic", "pose", "overwrite"} <= set(words)
    assert {"out", "quiet", "verbose", "help", "progress"}.isdisjoint(words)
    assert "where mesh/boxes/polylines walls put their faces" in words["wall_faces"]
    with pytest.raises(ValueError, match=r"no command 'map2wrld' \(did you mean 'map2world'\?\)"):
        api.keywords("map2wrld")


# --- one path, progress, import -------------------------------------------------------------


def test_the_cli_runs_every_command_through_the_api(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    calls: list[str] = []
    real = api.run

    def spy(args: object, **kw: object) -> api.Result:
        calls.append(getattr(args, "command", ""))
        return real(args, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(api, "run", spy)
    assert main(["map2world", str(TB3_MAP), "-o", str(tmp_path / "w")]) == 0
    assert calls == ["map2world"]
    assert "Wrote" in capsys.readouterr().out


def test_progress_is_reported_to_the_callback(tmp_path: Path) -> None:
    seen: list[api.Progress] = []
    api.bag2world(SICK_ROS1_DIR, tmp_path / "w", topic=SICK_TOPIC, pose=POSE, progress=seen.append)
    assert seen and {p.unit for p in seen} == {"scan"}
    assert [p.done for p in seen] == sorted(p.done for p in seen)
    assert seen[-1].done == seen[-1].total > 0 and seen[-1].points > 0
    with pytest.raises(TypeError, match="progress"):
        api.map2world(TB3_MAP, tmp_path / "m", progress=seen.append)  # no progress to report


def test_importing_scan2terrain_stays_light_and_exposes_the_api() -> None:
    code = (
        "import sys, scan2terrain\n"
        "assert 'scan2terrain.api' not in sys.modules\n"
        "names = set(dir(scan2terrain))\n"
        "f = scan2terrain.map2world\n"
        "assert f is sys.modules['scan2terrain.api'].map2world\n"
        "print(sorted(names & {'map2world', 'fidelity', 'Result', 'inspect'}))\n"
        "print(sorted(m for m in ('numpy', 'yaml', 'PIL', 'numba') if m in sys.modules))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == ["['Result', 'fidelity', 'inspect', 'map2world']", "[]"]
    assert set(api.__all__) <= set(scan2terrain.__all__)
    for name in api.COMMAND_FUNCTIONS:
        assert getattr(scan2terrain, name) is getattr(api, name)


def test_every_command_has_a_function_with_a_numpydoc_docstring() -> None:
    from scan2terrain.cli.dispatch import COMMANDS

    assert set(api.COMMAND_FUNCTIONS) == set(COMMANDS)
    for name in COMMANDS:
        doc = getattr(api, name).__doc__ or ""
        for section in ("Parameters\n    ----------", "Returns\n    -------", "Raises\n    ------"):
            assert section in doc, (name, section)
        assert f"scan2terrain {name}" in doc


# --- the README's example -------------------------------------------------------------------


def test_the_readme_python_example_runs(tmp_path: Path) -> None:
    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"^```python\n(.*?)^```", text, flags=re.M | re.S)
    assert blocks, "README.md shows no Python example"
    example = blocks[0]
    assert len(example.strip().splitlines()) <= 14
    (tmp_path / "fixtures").symlink_to(ROOT / "fixtures", target_is_directory=True)
    done = subprocess.run(
        [sys.executable, "-c", example], cwd=tmp_path, capture_output=True, text=True, check=False
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip()
