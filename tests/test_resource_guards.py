"""Issue 13's cases outside the readers, each as it was seen: sizes checked before work, a
config file that is not one, values that make no sense. Memory-hungry regressions run in a
child under an address-space limit and a timeout, so they fail here instead of taking the
machine down."""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from scan2terrain.cli import main
from scan2terrain.config import Config, cloud_resolution
from tests.fixtures import AUTZEN, AUTZEN_CSV, MAPS, SIMPLE_LAS

LIMIT = 3 << 30  # bytes of address space for a child run


def run_limited(
    argv: list[str], cwd: Path, timeout: float = 120
) -> subprocess.CompletedProcess[str]:
    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (LIMIT, LIMIT))

    return subprocess.run(
        [sys.executable, "-m", "scan2terrain.cli", *argv],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=timeout,
        preexec_fn=limit,
        check=False,
    )


@pytest.mark.parametrize(
    "cloud",
    [
        AUTZEN_CSV,
        SIMPLE_LAS,
    ],
    ids=["autzen-txt", "simple-las"],
)
def test_a_survey_at_its_default_resolution_fits_and_a_fine_one_is_refused(
    cloud: Path, tmp_path: Path
) -> None:
    """Seen: default cloud2world (then 0.05 m) grew to 24 GB on the 107-point Autzen text file
    (OOM killed) and ended in MemoryError on simple.las: their points span kilometres. Now the
    default follows the clouds' extent (said in the report), and 0.05 m given on purpose is
    refused in one line before the grid is allocated."""
    r = run_limited(["cloud2world", str(cloud), "-o", str(tmp_path / "w")], tmp_path)
    assert r.returncode == 0, r.stderr[-500:]
    assert "m (chosen: the clouds span" in r.stdout
    fine = tmp_path / "fine"
    fine.mkdir()
    r = run_limited(
        ["cloud2world", str(cloud), "-o", str(fine / "w"), "--resolution", "0.05"], fine
    )
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2, r.stderr[-500:]
    assert len(lines) == 1 and "--resolution" in lines[0] and str(cloud) in lines[0]
    assert sorted(p.name for p in fine.iterdir()) == []


@pytest.mark.parametrize(
    ("hi", "points", "res", "why"),
    [
        ((150.0, 80.0), 50_000_000, 0.05, "the default"),  # robot scale: dense or not
        ((150.0, 80.0), 1_000, 0.05, "the default"),
        ((400.0, 400.0), 2_400_000, 0.52, "400 x 400 m with 2,400,000 points"),  # spacing
        ((1000.0, 1000.0), 1_000_000_000, 0.25, "span 1,000 m, over terrain.max_side"),
        ((1000.0, 0.0), 10, 0.25, "over terrain.max_side"),  # a line: no area, no spacing
    ],
)
def test_a_survey_gets_cells_no_finer_than_its_point_spacing(
    hi: tuple[float, float], points: int, res: float, why: str
) -> None:
    """Seen: the default on four 600k-point LAS tiles over 400 x 400 m was 0.098 m (16.7 M
    cells, most without a point: speckle), 3.5 GB in the walls path; at the spacing itself
    (0.26 m) a third of the cells stay empty and the walls' caps took minutes."""
    got, reason = cloud_resolution([0.0, 0.0, 0.0], [*hi, 5.0], points, Config())
    assert got == res and why in reason, reason


@pytest.mark.parametrize(
    ("hi", "points", "grid", "res"),
    [
        # A 2 km strip 20 m wide: one heightmap's side would make its cells 0.49 m wide and
        # hold 25 points each; terrain is tiled, so its cells follow the points (four a cell).
        ((2000.0, 20.0), 4_000_000, "height", 0.2),
        ((2000.0, 20.0), 4_000_000, "occupancy", 0.49),  # walls: one map, as before
        # A square as large: as many cells as one full heightmap at most, either way.
        ((1000.0, 1000.0), 1_000_000_000, "height", 0.25),
        ((400.0, 400.0), 2_400_000, "height", 0.52),  # the points' spacing decides
        ((2000.0, 0.0), 10, "height", 0.49),  # a line: no area, its side alone
    ],
)
def test_terrain_cells_follow_the_point_density_not_one_heightmaps_side(
    hi: tuple[float, float], points: int, grid: str, res: float
) -> None:
    cfg = Config()
    cfg.octree.grid = grid  # type: ignore[assignment]
    got, reason = cloud_resolution([0.0, 0.0, 0.0], [*hi, 5.0], points, cfg)
    assert got == res, reason
    cells = (hi[0] / got) * (hi[1] / got)
    assert cells <= (cfg.terrain.max_side - 1) ** 2 * 1.0001


def test_a_grid_over_the_memory_budget_is_refused_naming_what_fits(tmp_path: Path) -> None:
    """The autzen LAZ at 0.05 m: 265 M cells, 17.8 GB and 70 s before the budget; now one line
    with the resolution that fits and the setting that raises it, nothing written."""
    laz = AUTZEN
    for stream in ([], ["--stream"]):
        r = run_limited(
            ["cloud2world", str(laz), "-o", str(tmp_path / "w"), "--resolution", "0.05", *stream],
            tmp_path,
        )
        assert r.returncode == 2, r.stderr[-500:]
        (line,) = r.stderr.strip().splitlines()
        assert "over --max-memory 8192 MiB: choose --resolution 0.13 or coarser" in line, line
        assert "raise --max-memory" in line
        assert not (tmp_path / "w").exists()
    r = run_limited(
        ["cloud2world", str(laz), "-o", str(tmp_path / "w"), "--resolution", "0.2",
         "--max-memory", "1000"],
        tmp_path,
    )  # fmt: skip
    assert r.returncode == 2 and "over --max-memory 1000 MiB: choose --resolution 0.36" in r.stderr
    r = run_limited(
        ["cloud2world", str(laz), "-o", str(tmp_path / "w"), "--resolution", "0.36",
         "--max-memory", "1000", "-q"],
        tmp_path,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr  # what it names fits


def test_a_fifo_as_config_is_refused_not_waited_on(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    fifo = tmp_path / "cfg.yaml"
    os.mkfifo(fifo)
    result: list[int] = []
    worker = threading.Thread(
        target=lambda: result.append(
            main(["map2world", str(MAPS["tb3"]), "-o", str(tmp_path / "w"), "--config", str(fifo)])
        ),
        daemon=True,
    )
    worker.start()
    worker.join(30)
    if worker.is_alive():  # unblock the reader so the session can go on, then fail
        with open(fifo, "w"):  # noqa: PTH123
            pass
        worker.join(5)
        pytest.fail("--config on a FIFO waited for a writer")
    assert result == [2]
    assert "not a regular file" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("text", "what"),
    [
        ("terrain: {height: " + "9" * 400 + "}\n", "terrain.height"),
        ("filter: {size: " + "9" * 400 + "}\n", "filter.size"),
        ("terrain: " + "[" * 5000 + "]" * 5000 + "\n", "malformed"),
        ("terrain: {height: .nan}\n", "finite"),
        ("terrain: {height: .inf}\n", "finite"),
    ],
    ids=["huge-float", "huge-int", "deep", "nan", "inf"],
)
def test_absurd_config_files_are_one_line(
    text: str, what: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Seen: a 400-digit integer or deep nesting in --config was exit 1."""
    cfg = tmp_path / "c.yaml"
    cfg.write_text(text)
    code = main(["map2world", str(MAPS["tb3"]), "-o", str(tmp_path / "w"), "--config", str(cfg)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and what in err[0], err
    assert not (tmp_path / "w").exists()


def test_an_octree_over_the_memory_budget_is_refused_not_a_memory_error(tmp_path: Path) -> None:
    """Free space along long beams fills the octree's dense blocks: a fan of 4,096 beams of
    400 m at 0.1 m took 5.8 GB. Growing past max_memory is one line naming the settings, exit
    2, nothing written; a shorter --max-range fits."""
    angles = np.linspace(-np.pi, np.pi, 720, endpoint=False)
    fan = np.column_stack([150 * np.cos(angles), 150 * np.sin(angles), np.zeros(720)])
    scan = tmp_path / "fan.dat"
    scan.write_text("NODE 0 0 0 0 0 0\n" + "".join(f"{x} {y} {z}\n" for x, y, z in fan))
    out = tmp_path / "w"
    r = run_limited(
        ["octree2world", str(scan), "-o", str(out), "--resolution", "0.1", "--max-memory", "100"],
        tmp_path,
    )
    assert r.returncode == 2, r.stderr[-500:]
    (line,) = r.stderr.strip().splitlines()
    assert str(scan) in line and "over --max-memory 100 MiB" in line, line
    assert "--resolution" in line and "--max-range" in line and "raise --max-memory" in line
    assert not out.exists()
    r = run_limited(
        ["octree2world", str(scan), "-o", str(out), "--resolution", "0.1", "--max-memory", "100",
         "--max-range", "20", "-q"],
        tmp_path,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
