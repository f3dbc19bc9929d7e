"""The output commit under kills, failures and a rival run (issue 13): at every instant the
target is the old folder or the new one (or an old one the next run puts back), leftovers of a
killed run go away with the next run, two runs without ``--overwrite`` never both succeed, and
an OS error while writing is one line, exit 2, nothing left.

Kills are real: a forked child runs the commit with one step replaced by ``os._exit(9)``.
"""

from __future__ import annotations

import errno
import os
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import ParamSpec, TypeVar

import pytest

from scan2terrain.cli import main
from scan2terrain.errors import OutputError
from scan2terrain.exporters import output
from scan2terrain.exporters.output import OutputDir, atomic_output
from scan2terrain.fileio import TMP_PREFIX
from tests.fixtures import MAPS

P = ParamSpec("P")
R = TypeVar("R")

FILES = ("scan2terrain.yaml", "world.txt", "models/m/model.sdf", "models/m/meshes/walls.stl")


def make_old(target: Path) -> None:
    for name in FILES:
        (target / name).parent.mkdir(parents=True, exist_ok=True)
        (target / name).write_text(f"old {name}")


def state(target: Path) -> str:
    """'old', 'new' or 'missing'; anything else (a mixture, a half folder) fails the test."""
    if not target.exists():
        return "missing"
    names = sorted(str(p.relative_to(target)) for p in target.rglob("*") if p.is_file())
    assert names == sorted(FILES), names
    kinds = {(target / n).read_text().split()[0] for n in FILES}
    assert len(kinds) == 1, kinds
    return kinds.pop()


def leftovers(parent: Path) -> list[str]:
    return sorted(p.name for p in parent.iterdir() if p.name.startswith(TMP_PREFIX))


def write_new(target: Path, overwrite: bool) -> None:
    with atomic_output(target, overwrite=overwrite) as od:
        for name in FILES:
            od.write(name, f"new {name}".encode())


def die() -> None:
    os._exit(9)


def in_child(body: Callable[[], None]) -> int:
    """Run ``body`` in a forked child; its exit status (9: killed on purpose)."""
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child
        try:
            body()
        except BaseException:
            os._exit(3)
        os._exit(0)
    _, status = os.waitpid(pid, 0)
    return os.waitstatus_to_exitcode(status)


def kill_at(step: str, fallback: bool) -> None:
    """Make ``step`` of the commit kill the process (called in the child)."""
    if fallback:
        output._RENAMEAT2 = None
    calls = {"n": 0}

    def nth(n: int, real: Callable[P, R]) -> Callable[P, R]:
        def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
            calls["n"] += 1
            if calls["n"] == n:
                die()
            return real(*args, **kwargs)

        return wrapper

    if step == "writing":
        Path.write_bytes = nth(2, Path.write_bytes)  # type: ignore[method-assign]
    elif step == "before the commit":
        OutputDir.commit = lambda self: die()  # type: ignore[method-assign]
    elif step == "at the rename":
        output._rename = lambda *a: die()  # type: ignore[assignment]
    elif step == "old folder aside":  # fallback: after target -> aside, before tmp -> target
        Path.rename = nth(2, Path.rename)  # type: ignore[method-assign]
    elif step == "removing the old folder":
        # output's shutil is this module: rmtree replaced for the commit's call
        shutil.rmtree = lambda *a, **k: die()  # type: ignore[assignment]
    else:
        raise AssertionError(step)


STEPS = ["writing", "before the commit", "at the rename", "removing the old folder"]


#: (step, no renameat2, --overwrite); only a replacement without exchange puts a folder aside.
KILLS = [(s, f, o) for s in STEPS for f in (False, True) for o in (True, False)]
KILLS.append(("old folder aside", True, True))


@pytest.mark.parametrize(("step", "fallback", "overwrite"), KILLS)
def test_a_kill_at_any_step_keeps_old_or_new(
    tmp_path: Path, step: str, fallback: bool, overwrite: bool
) -> None:
    target = tmp_path / "world"
    if overwrite:
        make_old(target)

    def body() -> None:
        kill_at(step, fallback)
        write_new(target, overwrite)

    code = in_child(body)
    finished = step == "removing the old folder" and not overwrite  # nothing to remove
    assert code == (0 if finished else 9)
    # Before anything else runs: old, new, or (killed aside) missing with the old one aside.
    now = state(target)
    if overwrite:
        assert now in ("old", "new") or (now == "missing" and step == "old folder aside")
    else:
        assert now in ("missing", "new")
    # A check (what every command does first) puts the old folder back.
    if now == "missing" and overwrite:
        with pytest.raises(OutputError, match="exists"):
            OutputDir.check_target(target, overwrite=False)
        assert state(target) == "old"
    # The next run cleans up whatever the killed one left, and succeeds.
    write_new(target, overwrite=True)
    assert state(target) == "new"
    assert leftovers(tmp_path) == []


def test_leftovers_of_a_live_run_are_left_alone(tmp_path: Path) -> None:
    """A rival run's hidden folder is locked while it lives: a sweep passes it by."""
    rival = OutputDir(tmp_path / "a")
    write_new(tmp_path / "b", overwrite=False)
    assert leftovers(tmp_path) == [rival.tmp.name]
    rival.discard()
    assert leftovers(tmp_path) == []


def test_two_runs_without_overwrite_never_both_succeed(tmp_path: Path) -> None:
    """Both pass the check, both write, and both commit at the same moment: one wins."""
    for trial in range(8):
        target = tmp_path / f"w{trial}"
        go_r, go_w = os.pipe()

        def body(target: Path = target, go_r: int = go_r) -> None:
            od = OutputDir(target)
            for name in FILES:
                od.write(name, f"new {name}".encode())
            os.read(go_r, 1)  # wait for the start signal
            try:
                od.commit()
            except OutputError:
                od.discard()
                os._exit(2)
            od.discard()  # removes nothing: the folder was renamed into place
            os._exit(0)

        pids = []
        for _ in range(2):
            pid = os.fork()
            if pid == 0:  # pragma: no cover - the child
                try:
                    body()
                except BaseException:
                    os._exit(3)
            pids.append(pid)
        time.sleep(0.2)
        os.write(go_w, b"xx")
        codes = sorted(os.waitstatus_to_exitcode(os.waitpid(p, 0)[1]) for p in pids)
        os.close(go_r)
        os.close(go_w)
        assert codes == [0, 2], codes
        assert state(target) == "new"
        assert leftovers(tmp_path) == []


@pytest.mark.parametrize(
    ("where", "err"),
    [
        ("write", errno.ENOSPC),
        ("write", errno.EDQUOT),
        ("rename", errno.EXDEV),
        ("rename", errno.EACCES),
        ("rename", errno.EIO),
    ],
)
@pytest.mark.parametrize("overwrite", [False, True], ids=["new", "overwrite"])
def test_os_errors_while_writing_are_exit_2(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    *,
    where: str,
    err: int,
    overwrite: bool,
) -> None:
    target = tmp_path / "out"
    if overwrite:
        make_old(target)

    def fail(*args: object, **kwargs: object) -> None:
        raise OSError(err, os.strerror(err))

    if where == "write":
        monkeypatch.setattr(Path, "write_bytes", fail)
    else:
        monkeypatch.setattr(output, "_rename", fail)
    argv = ["map2world", str(MAPS["tb3"]), "-o", str(target), "-q"]
    code = main(argv + (["--overwrite"] if overwrite else []))
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(lines) == 1, lines
    assert str(target) in lines[0] and os.strerror(err) in lines[0]
    assert state(target) == ("old" if overwrite else "missing")
    assert leftovers(tmp_path) == []


def test_no_exchange_still_refuses_a_folder_that_appeared(tmp_path: Path) -> None:
    target = tmp_path / "w"
    od = OutputDir(target)
    od.write("world.txt", b"new")
    make_old(target)
    saved = output._RENAMEAT2
    output._RENAMEAT2 = None
    try:
        with pytest.raises(OutputError, match="exists"):
            od.commit()
    finally:
        output._RENAMEAT2 = saved
        od.discard()
    assert state(target) == "old" and leftovers(tmp_path) == []


def test_exchange_is_what_this_machine_uses(tmp_path: Path) -> None:
    """Linux with glibc >= 2.28 on a local file system: the atomic path is the one tested."""
    assert output._RENAMEAT2 is not None
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    (a / "x").write_text("a")
    assert output._rename(a, b, output._RENAME_EXCHANGE)
    assert (b / "x").read_text() == "a" and not (a / "x").exists()
    assert not output._rename(a, b, output._RENAME_NOREPLACE)
    shutil.rmtree(a)


def test_a_killed_single_file_write_leaves_nothing_after_the_next(tmp_path: Path) -> None:
    """convert and .bt writers write one file the same way: a kill mid-write leaves the old
    file and a hidden temporary, which the next write in that folder removes."""
    from scan2terrain.fileio import atomic_write

    target = tmp_path / "cloud.ply"
    target.write_bytes(b"old")

    def body() -> None:
        os.fdopen = lambda *a, **k: die()  # type: ignore[assignment]
        atomic_write(target, b"new")

    assert in_child(body) == 9
    assert target.read_bytes() == b"old" and len(leftovers(tmp_path)) == 1
    atomic_write(tmp_path / "other.ply", b"x")
    assert leftovers(tmp_path) == [] and target.read_bytes() == b"old"
