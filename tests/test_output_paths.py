"""Issue 12: every user mistake about an output or an input is exit 2 with one line on stderr,
and nothing is left behind (no output, no hidden ``.part`` or ``.old`` folder, no parent
folder made for it), for every command.

Each case runs in-process in its own copy of the inputs, from a working folder of its own
(``run``), and compares every entry under the sandbox (hidden ones too) before and after.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from scan2terrain.cli import main
from tests.conftest import write_map
from tests.fixtures import CCNY, GEB079, IMAGES, LEG_TRACKER_DIR, MAPS, SFBAY, SIMPLE_LAS

#: command -> the fixture files it reads (the first is the one named on the command line).
INPUTS: dict[str, list[Path]] = {
    "map2world": [MAPS["tb3"], MAPS["tb3"].with_name("map.pgm")],
    "image2world": [IMAGES["bowl_rgb"]],
    "dem2world": [SFBAY],
    "octree2world": [GEB079],
    "bag2world": [CCNY],
    "cloud2world": [SIMPLE_LAS],
    "convert": [SIMPLE_LAS],
}
COMMANDS = sorted(INPUTS)


class Sandbox:
    def __init__(self, root: Path, command: str) -> None:
        self.root = root
        self.command = command
        self.inputs = root / "in"
        self.inputs.mkdir()
        for f in INPUTS[command]:
            shutil.copy(f, self.inputs / f.name)
        self.input = self.inputs / INPUTS[command][0].name
        self.run = root / "run"  # the working folder
        (self.run / "sub").mkdir(parents=True)
        (self.run / "notes.txt").write_text("mine")
        (self.run / "link_in").symlink_to(self.inputs)
        (self.run / "link_here").symlink_to(".")
        (self.run / "dangling").symlink_to(self.root / "gone")

    def argv(self, out: str, *extra: str, source: str | None = None) -> list[str]:
        src = str(self.input) if source is None else source
        if self.command == "convert":
            return ["convert", src, out, *extra]
        return [self.command, src, "-o", out, *extra]


def snapshot(*roots: Path) -> set[tuple[str, bool, int, int, int]]:
    """Every entry under ``roots`` (hidden ones too): path, is link, mode, size, mtime."""
    seen = set()
    for root in roots:
        for top, dirs, files in os.walk(root):
            for name in dirs + files:
                p = Path(top, name)
                st = p.lstat()
                seen.add((str(p), p.is_symlink(), st.st_mode, st.st_size, st.st_mtime_ns))
    return seen


def hidden_temporaries(*folders: Path) -> list[str]:
    return [p.name for f in folders for p in f.iterdir() if p.name.startswith(".s2t-")]


def assert_refused(
    capsys: pytest.CaptureFixture[str], box: Sandbox, argv: list[str], *message: str
) -> str:
    before = snapshot(box.root)
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2, (argv, err)
    assert err.startswith("scan2terrain: error: ") and err.count("\n") == 1, err
    assert "Traceback" not in err and "internal error" not in err
    for m in message:
        assert m in err, (m, err)
    assert snapshot(box.root) == before  # nothing new, nothing changed, nothing removed
    assert hidden_temporaries(box.root.parent, Path("/")) == []
    return err


@pytest.fixture(params=COMMANDS)
def box(request: pytest.FixtureRequest, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Sandbox:
    b = Sandbox(tmp_path, request.param)
    monkeypatch.chdir(b.run)
    return b


#: case -> (output as typed, from the sandbox; extra flags; words of the one line)
OUTPUTS: dict[str, Callable[[Sandbox], tuple[str, list[str], list[str]]]] = {
    "dot": lambda b: (".", [], ["current folder"]),
    "dot_overwrite": lambda b: (".", ["--overwrite"], ["current folder"]),
    "dotdot_overwrite": lambda b: ("..", ["--overwrite"], ["contains the current folder"]),
    "x_dotdot_overwrite": lambda b: ("sub/..", ["--overwrite"], ["current folder"]),
    "link_to_cwd_overwrite": lambda b: ("link_here", ["--overwrite"], ["current folder"]),
    "root_overwrite": lambda b: ("/", ["--overwrite"], ["root folder"]),
    "input_itself_overwrite": lambda b: (str(b.input), ["--overwrite"], [str(b.input)]),
    "input_folder": lambda b: (str(b.inputs), ["--overwrite"], ["contains the input"]),
    "link_to_input_folder": lambda b: ("link_in", ["--overwrite"], ["contains the input"]),
    "existing_file": lambda b: ("notes.txt", [], ["notes.txt"]),
    "through_a_file": lambda b: ("notes.txt/out", [], ["notes.txt is not a folder"]),
    "dangling_link": lambda b: ("dangling", ["--overwrite"], ["broken symbolic link"]),
    "long_name_over_255": lambda b: ("a" * 256, [], ["name too long"]),
}


def _as_file(name: str, command: str) -> str:
    """convert writes a file: give the case a point-cloud extension where it has a name."""
    if command != "convert" or name in (".", "..", "/", "sub/..", "link_here", "link_in"):
        return name
    if name in ("notes.txt", "dangling") or name.startswith("/"):
        return name
    return name[:-4] + ".ply" if name.startswith("aaa") else name + ".ply"


@pytest.mark.parametrize("case", sorted(OUTPUTS))
def test_bad_output_is_refused_and_leaves_nothing(
    box: Sandbox, case: str, capsys: pytest.CaptureFixture[str]
) -> None:
    out, extra, words = OUTPUTS[case](box)
    out = _as_file(out, box.command)
    if box.command == "convert":
        # a file target: folders are 'is a folder', an existing file names itself
        words = {
            "existing_file": ["notes.txt", "exists (use --overwrite"],
            "input_folder": ["contains the input"],
            "link_to_input_folder": ["contains the input"],
            "input_itself_overwrite": ["is the input"],
        }.get(case, words)
    elif case == "input_itself_overwrite":
        words = ["is the input", "name another output folder"]
    elif case == "existing_file":
        words = ["exists and is not a folder"]
    assert_refused(capsys, box, box.argv(out, *extra), *words)


@pytest.mark.parametrize("target", ["out.docx", "out", "out.PLY.txt"])
def test_convert_wrong_extension_is_refused_before_any_work(
    tmp_path: Path, target: str, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    box = Sandbox(tmp_path, "convert")
    monkeypatch.chdir(box.run)
    # the source does not exist: the target is refused first, without reading anything
    argv = ["convert", "missing.las", target]
    err = assert_refused(capsys, box, argv, f"{target}: ")
    assert "unsupported point cloud extension" in err or "no point cloud extension" in err
    assert ".ply" in err and ".laz" in err


# An unreadable (mode 000) input is not a case here: CI runs as root, who reads it anyway; a
# folder where a file is expected fails the same way (the open fails).
@pytest.mark.parametrize("case", ["missing", "a_folder", "empty"])
def test_bad_input_is_refused_and_leaves_nothing(
    box: Sandbox, case: str, capsys: pytest.CaptureFixture[str]
) -> None:
    out = "out.ply" if box.command == "convert" else "deep/er/out"  # parents made, then removed
    if case == "missing":
        source = str(box.inputs / ("missing" + box.input.suffix))
    elif case == "a_folder":
        source = str(box.run / "sub")  # a folder where a file is expected
        if box.command == "bag2world":
            (box.run / "sub").rmdir()
            (box.run / "sub").mkdir()  # a folder is a ROS 2 bag: an empty one, no metadata
    elif case == "empty":
        source = str(box.inputs / ("empty" + box.input.suffix))
        Path(source).write_bytes(b"")
    else:
        raise AssertionError(case)
    assert_refused(capsys, box, box.argv(out, source=source), source)


def test_the_reported_case_map2world_dot_overwrite(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """`scan2terrain map2world map.yaml -o . --overwrite`, from the map's folder."""
    good = write_map(tmp_path / "in", np.full((10, 10), 254, np.uint8))
    monkeypatch.chdir(good.parent)
    before = snapshot(tmp_path)
    code = main(["map2world", "m.yaml", "-o", ".", "--overwrite"])
    err = capsys.readouterr().err
    assert code == 2
    assert err == "scan2terrain: error: .: is the current folder; name a new output folder\n"
    assert snapshot(tmp_path) == before and hidden_temporaries(tmp_path, tmp_path.parent) == []


def test_a_250_character_output_name_is_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    good = write_map(tmp_path / "in", np.full((10, 10), 254, np.uint8))
    monkeypatch.chdir(tmp_path)
    name = "w" * 250
    assert main(["map2world", str(good), "-o", name, "--simulator", "gz", "-q"]) == 0
    assert (tmp_path / name / "world_gz.sdf").exists()
    # and replaced under --overwrite (the old folder is set aside under a short name too)
    assert main(["map2world", str(good), "-o", name, "--simulator", "gz", "-q", "--overwrite"]) == 0
    cloud = "c" * 246 + ".ply"
    src = SIMPLE_LAS
    assert main(["convert", str(src), cloud, "-q"]) == 0
    assert main(["convert", str(src), cloud, "-q", "--overwrite"]) == 0
    capsys.readouterr()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["in", name, cloud])


def test_overwrite_through_a_symlink_replaces_the_folder_it_names(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    good = write_map(tmp_path / "in", np.full((10, 10), 254, np.uint8))
    real = tmp_path / "real"
    real.mkdir()
    (real / "keep.txt").write_text("old")
    (real / "scan2terrain.yaml").write_text("an earlier output")
    link = tmp_path / "link"
    link.symlink_to(real)
    assert main(["map2world", str(good), "-o", str(link), "--overwrite", "-q"]) == 0
    capsys.readouterr()
    assert link.is_symlink() and (real / "world_gz.sdf").exists()
    assert not (real / "keep.txt").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in", "link", "real"]


def test_failure_midway_removes_the_parent_folders_it_made(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    good = write_map(tmp_path / "in", np.full((10, 10), 254, np.uint8))

    def boom(*a: object, **k: object) -> bytes:
        raise OSError("disk full")

    monkeypatch.setattr("scan2terrain.exporters.sdf.tiled_world_sdf", boom)
    code = main(["map2world", str(good), "-o", str(tmp_path / "a/b/out")])
    assert code == 1 and "disk full" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in"]


def test_every_file_read_is_an_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A map's image in another folder, a --config file, a --trajectory file: an output that
    is or holds one is refused even with --overwrite, and the file stays."""
    images, yamls = tmp_path / "images", tmp_path / "yamls"
    images.mkdir()
    yamls.mkdir()
    shutil.copy(MAPS["tb3"].with_name("map.pgm"), images / "map.pgm")
    text = MAPS["tb3"].read_text().replace("image: map.pgm", f"image: {images / 'map.pgm'}")
    assert str(images) in text
    (yamls / "map.yaml").write_text(text)
    (images / "cfg.yaml").write_text("terrain: {height: 1.5}\n")
    (images / "scan2terrain.yaml").write_text("as if an earlier output: only inputs stop it")
    cases = [
        ["map2world", str(yamls / "map.yaml"), "-o", str(images), "--overwrite"],
        [
            "map2world",
            str(MAPS["tb3"]),
            "-o",
            str(images),
            "--overwrite",
            "--config",
            str(images / "cfg.yaml"),
        ],
        [
            "bag2world",
            str(LEG_TRACKER_DIR),
            "-o",
            str(images),
            "--overwrite",
            "--trajectory",
            str(images / "cfg.yaml"),
        ],
    ]
    for argv in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "input" in err[0], err
        assert sorted(p.name for p in images.iterdir()) == [
            "cfg.yaml",
            "map.pgm",
            "scan2terrain.yaml",
        ]


@pytest.mark.parametrize("command", [c for c in COMMANDS if c != "convert"])  # one file
def test_overwrite_refuses_a_folder_this_tool_did_not_write(
    command: str,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Issue 25 item 9: `-o mydata --overwrite` removed a user's notes and sub-folders. Only a
    folder holding scan2terrain.yaml (what every world folder holds) is replaced."""
    box = Sandbox(tmp_path, command)
    monkeypatch.chdir(box.run)
    mine = box.run / "mydata"
    (mine / "deeper").mkdir(parents=True)
    (mine / "notes.md").write_text("field notes")
    (mine / "deeper" / "scan.ply").write_text("ply")
    err = assert_refused(
        capsys, box, box.argv("mydata", "--overwrite"), "mydata", "not written by scan2terrain"
    )
    assert "scan2terrain.yaml" in err and "notes.md" in err


def test_overwrite_replaces_its_own_output_and_an_empty_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    good = write_map(tmp_path / "in", np.full((10, 10), 254, np.uint8))
    out = tmp_path / "out"
    out.mkdir()  # empty: nothing to lose
    assert main(["map2world", str(good), "-o", str(out), "--overwrite", "-q"]) == 0
    (out / "extra.txt").write_text("left by the user in an output folder")
    assert main(["map2world", str(good), "-o", str(out), "--overwrite", "-q"]) == 0
    capsys.readouterr()
    assert (out / "scan2terrain.yaml").exists() and not (out / "extra.txt").exists()


def test_missing_parent_folders_are_named_when_made(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 25 item 12: `-o /nonexistent/deep/out` does not create folders silently."""
    good = write_map(tmp_path / "in", np.full((10, 10), 254, np.uint8))
    out = tmp_path / "new" / "deep" / "out"
    assert main(["map2world", str(good), "-o", str(out), "--simulator", "gz"]) == 0
    printed = capsys.readouterr().out
    made = f"{tmp_path / 'new'}, {tmp_path / 'new' / 'deep'}"
    assert f"Created the missing folders {made} for the output" in printed, printed


@pytest.mark.parametrize("signame", ["SIGTERM", "SIGINT", "SIGHUP"])
def test_a_run_stopped_while_writing_says_so_and_leaves_nothing(
    tmp_path: Path,
    signame: str,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Issue 25 item 10: `kill` (SIGTERM), Ctrl-C or a closed terminal while the world is
    written: the hidden .part folder is removed at once and stderr says what happened."""
    import signal

    good = write_map(tmp_path / "in", np.full((10, 10), 254, np.uint8))
    out = tmp_path / "out"
    real_world_sdf = __import__("scan2terrain.exporters.sdf", fromlist=["x"]).tiled_world_sdf

    def stop_here(*a: object, **k: object) -> bytes:
        os.kill(os.getpid(), getattr(signal, signame))
        return real_world_sdf(*a, **k)  # type: ignore[no-any-return]

    monkeypatch.setattr("scan2terrain.exporters.sdf.tiled_world_sdf", stop_here)
    before = signal.getsignal(signal.SIGTERM)
    # Run under nohup (SIGHUP ignored), scan2terrain keeps going on a closed terminal, as asked:
    # the test's own process must not ignore it.
    hup = signal.signal(signal.SIGHUP, signal.SIG_DFL)
    # Started in the background (`cmd &`), the process ignores SIGINT from birth and Python
    # raises no KeyboardInterrupt: give it Python's own handler, as a terminal's process has.
    intr = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        code = main(["map2world", str(good), "-o", str(out)])
    finally:
        signal.signal(signal.SIGHUP, hup)
        signal.signal(signal.SIGINT, intr)
    err = capsys.readouterr().err
    assert code == 128 + getattr(signal, signame), err
    assert err.startswith(f"scan2terrain: interrupted ({signame})") and err.count("\n") == 1
    assert f"{out} was not written" in err and "nothing half-written is left" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in"]
    assert signal.getsignal(signal.SIGTERM) is before  # main() restores the handlers
