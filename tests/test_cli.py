"""The command line end to end: outputs, bad input (one line, exit 2, nothing half-written)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

from scan2terrain.cli import main
from tests.conftest import write_map
from tests.fixtures import (
    CLOUDS,
    FR079,
    GEB079,
    HDL_PCD,
    IMAGES,
    MAPS,
    ROOT,
    SFBAY,
    SIMPLE_LAS,
    TB3_MAP,
    TERRAIN,
)


def run(capsys: pytest.CaptureFixture[str], *args: str | Path) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def leftovers(parent: Path) -> list[str]:
    return sorted(p.name for p in parent.iterdir())


HEIGHTMAP_FILES = (
    "model.config",
    "model.sdf",
    "materials/textures/heightmap.png",
    "materials/textures/floor.png",
    "materials/textures/unknown.png",
    "materials/textures/obstacle.png",
    "materials/textures/normal.png",
)
MESH_FILES = (
    "model.config",
    "model.sdf",
    "meshes/walls.stl",
    "meshes/walls.dae",
    "meshes/walls.obj",
)


@pytest.mark.parametrize("geometry", ["default", "heightmap"])
def test_map2world_writes_the_documented_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], geometry: str
) -> None:
    """The folder the README documents: by default an occupancy map becomes a wall mesh."""
    out = tmp_path / "w"
    options = [] if geometry == "default" else ["--geometry", geometry]
    code, stdout, err = run(capsys, "map2world", MAPS["tb3"], "-o", out, *options)
    assert code == 0, err
    files = sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file())
    name = next(p.name for p in (out / "models").iterdir() if not p.name.endswith("_classic"))
    gz_files: tuple[str, ...]
    classic_files: tuple[str, ...]
    if geometry == "heightmap":
        gz_files, classic_files = HEIGHTMAP_FILES, HEIGHTMAP_FILES[:3]
    else:
        gz_files = classic_files = MESH_FILES
    assert files == sorted(
        [
            "map/map.pgm",
            "map/map_classic.yaml",
            "map/map_gz.yaml",
            "preview.png",
            "preview3d.png",
            "robot/model.config",
            "robot/model_classic.sdf",
            "robot/model_gz.sdf",
            "scan2terrain.yaml",
            "spawn.yaml",
            "world_classic.world",
            "world_gz.sdf",
            *(f"models/{name}/{f}" for f in gz_files),
            *(f"models/{name}_classic/{f}" for f in classic_files),
        ]
    )
    assert f"GZ_SIM_RESOURCE_PATH={out}/models gz sim {out}/world_gz.sdf" in stdout
    assert f"GAZEBO_MODEL_PATH={out}/models gazebo {out}/world_classic.world" in stdout
    # The effective config can be fed back in.
    cfg = yaml.safe_load((out / "scan2terrain.yaml").read_text())
    assert cfg["terrain"]["height"] == 2.0 and cfg["filter"]["kind"] == "thin_wall"
    code, _, err = run(
        capsys,
        "map2world",
        MAPS["tb3"],
        "-o",
        tmp_path / "again",
        "--config",
        out / "scan2terrain.yaml",
    )
    assert code == 0, err


def test_outputs_are_byte_identical_run_to_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    for d in ("a", "b"):
        assert run(capsys, "map2world", MAPS["warehouse"], "-o", tmp_path / d)[0] == 0
    a = {
        p.relative_to(tmp_path / "a"): p.read_bytes()
        for p in (tmp_path / "a").rglob("*")
        if p.is_file()
    }
    b = {
        p.relative_to(tmp_path / "b"): p.read_bytes()
        for p in (tmp_path / "b").rglob("*")
        if p.is_file()
    }
    assert a == b


def test_image2world(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "img"
    code, _, err = run(
        capsys,
        "image2world",
        IMAGES["winding_valley"],
        "-o",
        out,
        "--resolution",
        "0.5",
        "--height",
        "12",
        "--simulator",
        "gz",
        "--no-filter",
    )
    assert code == 0, err
    model = next((out / "models").iterdir())
    with Image.open(model / "materials/textures/heightmap.png") as im:
        png = np.asarray(im)
    with Image.open(IMAGES["winding_valley"]) as im:
        src = np.asarray(im.convert("L"))
    assert png.shape == (513, 513)  # already 2^n+1: no padding, no stretching
    # Heights are scaled so the brightest pixel is full scale and size.z is its true height.
    sdf = (model / "model.sdf").read_text()
    top = float(src.max()) / 255 * 12
    assert f"<size>256.5 256.5 {round(top, 9)!r}</size>" in sdf  # 513 px * 0.5 m, gz sampling 1
    np.testing.assert_allclose(png / 255 * top, src / 255 * 12, atol=top / 255)
    assert not (out / "map").exists()  # an image is not an occupancy map


def test_help_lists_commands_with_examples(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main(["--help"])
    assert info.value.code == 0
    text = capsys.readouterr().out
    assert "map2world" in text and "image2world" in text and "examples:" in text


def test_help_does_not_import_heavy_modules() -> None:
    code = (
        "import sys; from scan2terrain.cli import build_parser; build_parser();"
        "print(sorted(m for m in ('numpy','PIL','lxml','scipy','yaml') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


# --- bad input --------------------------------------------------------------------------------


def _bad_inputs(tmp: Path) -> dict[str, tuple[list[str], str]]:
    good = write_map(tmp / "good", np.full((10, 10), 254, np.uint8))
    cases: dict[str, tuple[list[str], str]] = {}
    (tmp / "malformed.yaml").write_text("image: [unclosed\n")
    cases["malformed yaml"] = (["map2world", str(tmp / "malformed.yaml")], "malformed YAML")
    cases["missing yaml"] = (["map2world", str(tmp / "nope.yaml")], "map YAML file not found")
    y = write_map(tmp / "noimg", np.zeros((2, 2), np.uint8))
    (tmp / "noimg/m.png").unlink()
    cases["missing image"] = (["map2world", str(y)], "image file not found")
    y = write_map(tmp / "zero", np.zeros((2, 2), np.uint8), resolution=0)
    cases["zero resolution"] = (["map2world", str(y)], "'resolution' must be > 0")
    y = write_map(tmp / "neg", np.zeros((2, 2), np.uint8), resolution=-1)
    cases["negative resolution"] = (["map2world", str(y)], "'resolution' must be > 0")
    y = write_map(tmp / "order", np.zeros((2, 2), np.uint8), occ=0.1, free=0.5)
    cases["thresholds"] = (["map2world", str(y)], "thresholds out of order")
    y = write_map(tmp / "notimg", np.zeros((2, 2), np.uint8))
    (tmp / "notimg/m.png").write_text("plain text, not a picture")
    cases["not an image"] = (["map2world", str(y)], "not an image file")
    y = write_map(
        tmp / "trunc", np.random.default_rng(0).integers(0, 255, (300, 300), dtype=np.uint8)
    )
    data = (tmp / "trunc/m.png").read_bytes()
    (tmp / "trunc/m.png").write_bytes(data[: len(data) // 3])
    cases["truncated png"] = (["map2world", str(y)], "cannot decode image")
    cases["bomb"] = (["map2world", str(good), "--max-pixels", "50"], "over the limit of 50")
    (tmp / "t.txt").write_text("hello")
    cases["image2world not an image"] = (["image2world", str(tmp / "t.txt")], "not an image file")
    cases["bad option value"] = (["map2world", str(good), "--upsample", "0"], "terrain.upsample")
    (tmp / "cfg.yaml").write_text("terrain:\n  hieght: 3\n")
    cases["unknown config key"] = (
        ["map2world", str(good), "--config", str(tmp / "cfg.yaml")],
        "unknown config key 'terrain.hieght'",
    )
    return cases


@pytest.mark.parametrize(
    "case",
    [
        "malformed yaml",
        "missing yaml",
        "missing image",
        "zero resolution",
        "negative resolution",
        "thresholds",
        "not an image",
        "truncated png",
        "bomb",
        "image2world not an image",
        "bad option value",
        "unknown config key",
    ],
)
def test_bad_input_one_line_exit_2_nothing_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str
) -> None:
    args, message = _bad_inputs(tmp_path / "in")[case]
    outdir = tmp_path / "outs"
    outdir.mkdir()
    code, _, err = run(capsys, *args, "-o", outdir / "world")
    assert code == 2
    assert message in err
    assert err.count("\n") == 1 and err.startswith("scan2terrain: error: ")
    assert leftovers(outdir) == []  # nothing half-written, not even a temporary folder


def test_existing_output_refused_without_overwrite(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    good = write_map(tmp_path / "in", np.full((10, 10), 254, np.uint8))
    out = tmp_path / "o"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    code, _, err = run(capsys, "map2world", good, "-o", out)
    assert code == 2 and "output folder exists (use --overwrite" in err
    assert leftovers(out) == ["keep.txt"] and leftovers(tmp_path) == ["in", "o"]
    code, _, err = run(capsys, "map2world", good, "-o", out, "--overwrite")
    assert code == 2 and "not written by scan2terrain" in err  # not ours: kept
    assert leftovers(out) == ["keep.txt"]
    (out / "scan2terrain.yaml").write_text("as an earlier run leaves it")
    code, _, err = run(capsys, "map2world", good, "-o", out, "--overwrite")
    assert code == 0, err
    assert not (out / "keep.txt").exists() and (out / "world_gz.sdf").exists()
    assert leftovers(tmp_path) == ["in", "o"]


def test_failure_midway_leaves_old_output_intact(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    good = write_map(tmp_path / "in", np.full((10, 10), 254, np.uint8))
    out = tmp_path / "o"
    assert run(capsys, "map2world", good, "-o", out)[0] == 0
    before = sorted(p.name for p in out.rglob("*"))

    def boom(*a: object, **k: object) -> bytes:
        raise OSError("disk full")

    monkeypatch.setattr("scan2terrain.exporters.sdf.tiled_world_sdf", boom)
    code, _, err = run(capsys, "map2world", good, "-o", out, "--overwrite")
    assert code == 1 and "disk full" in err
    assert sorted(p.name for p in out.rglob("*")) == before
    assert leftovers(tmp_path) == ["in", "o"]


def test_image_invert_and_extend_keeps_added_cells_at_the_floor(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    Image.fromarray(np.full((4, 4), 255, np.uint8)).save(tmp_path / "white.png")
    out = tmp_path / "o"
    args: list[str | Path] = ["image2world", tmp_path / "white.png", "-o", out]
    args += ["--simulator", "gz", "--no-filter"]
    code, _, err = run(capsys, *args, "--invert", "--width", "6", "--offset-x", "1")
    assert code == 0, err
    model = next((out / "models").iterdir())
    with Image.open(model / "materials/textures/heightmap.png") as im:
        png = np.asarray(im)
    assert png.max() == 0  # inverted white is black; the two added columns are black too


@pytest.mark.parametrize(
    "argv",
    [
        ["map2world", str(MAPS["tb3"]), "--geometry", "heightmap"],
        ["image2world", str(IMAGES["bowl_rgb"])],
        ["dem2world", str(SFBAY)],
        ["octree2world", str(GEB079), "--grid", "height"],
        ["cloud2world", str(SIMPLE_LAS), "--grid", "height"],
    ],
    ids=["map2world", "image2world", "dem2world", "octree2world", "cloud2world"],
)
@pytest.mark.parametrize("simulator", ["classic", "both"])
def test_sixteen_bit_heightmaps_refused_for_classic_by_every_command(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], simulator: str
) -> None:
    """Gazebo Classic reads one byte a pixel: every command that writes a heightmap refuses
    --bit-depth 16 with Classic, with one message, and writes nothing."""
    out = tmp_path / "w"
    code, _, err = run(capsys, *argv, "-o", out, "--bit-depth", "16", "--simulator", simulator)
    assert code == 2 and err.count("\n") == 1
    assert "Gazebo Classic reads only the first byte of each heightmap pixel" in err
    assert leftovers(tmp_path) == []


@pytest.mark.parametrize("stream", [False, True])
def test_cloud_report_keeps_the_writers_notes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], stream: bool
) -> None:
    """What the reader says comes first, and what the writer says is kept: tiled terrain
    leaves Gazebo Classic out, and the report says so (it was overwritten by the reader's
    notes)."""
    config = tmp_path / "tiles.yaml"
    config.write_text("terrain: {max_side: 129}\n")
    cloud = HDL_PCD
    argv: list[str | Path] = ["cloud2world", cloud, "-o", tmp_path / "w", "--grid", "height"]
    argv += ["--resolution", "0.2", "--config", config, *(["--stream"] if stream else [])]
    code, out, err = run(capsys, *argv)
    assert code == 0, err
    assert "251370668.pcd: " in out  # the reader's note
    assert "heightmap tiles" in out and "Gazebo Classic world not written" in out


@pytest.mark.parametrize("no_filter", [False, True])
def test_preview_says_what_it_shows(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], no_filter: bool
) -> None:
    """Three panels (original | filtered | difference) when a filter ran; the input alone,
    labelled so, with --no-filter."""
    out = tmp_path / "w"
    flags = ["--no-filter"] if no_filter else []
    code, stdout, err = run(capsys, "image2world", IMAGES["bowl_rgb"], "-o", out, *flags)
    assert code == 0, err
    with Image.open(IMAGES["bowl_rgb"]) as src, Image.open(out / "preview.png") as im:
        k = im.size[1] // src.size[1]  # small previews are scaled up by a whole factor
        one_panel = im.size == (k * src.size[0], k * src.size[1])
    if no_filter:
        assert one_panel and "preview (the input; filtering off)" in stdout
    else:
        assert not one_panel and "preview (original | filtered | difference)" in stdout


def test_octree_file_written_is_reported(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "w"
    scan = FR079
    code, stdout, err = run(capsys, "octree2world", scan, "-o", out, "--resolution", "0.2")
    assert code == 0, err
    assert f"OctoMap's .bt (octovis, octomap_server, octree2world): {out}/octree.bt" in stdout


@pytest.mark.parametrize("stream", [False, True])
def test_grid_too_large_is_refused_before_allocating(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], stream: bool
) -> None:
    """Clouds in different coordinate systems (a UTM LAZ and a local XYZ) span ~10^11 cells:
    one line, exit 2, on the octree and the streamed path (was a 2 TiB MemoryError, exit 1)."""
    clouds = CLOUDS
    laz = clouds / "pc_laz_autzen_trim/autzen_trim.laz"
    xyz = clouds / "pc_xyz_street_lidar/multisensor_lidar.xyz"
    argv: list[str | Path] = ["cloud2world", laz, xyz, "-o", tmp_path / "w", "--grid", "height"]
    argv += ["--resolution", "1"]
    code, _, err = run(capsys, *argv, *(["--stream"] if stream else []))
    assert code == 2 and err.count("\n") == 1, err
    assert "different coordinate systems" in err  # the likely cause, not a setting already set
    assert leftovers(tmp_path) == []


@pytest.mark.parametrize("kind", ["tasks", "scans"])
def test_progress_rates_count_from_the_start(
    kind: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The points/s figure divides by the time since the command started, not since the bar
    first showed (after the first task: 110,000 points once read as 7819 M points/s)."""
    import time

    from scan2terrain.cli import display as cli
    from scan2terrain.types import ScanCounts

    now = [100.0]
    monkeypatch.setattr(time, "monotonic", lambda: now[0])  # the clock display reads
    bar = cli.TaskBar(enabled=True) if kind == "tasks" else cli.ProgressBar(enabled=True)
    with bar:
        now[0] += 2.0
        if isinstance(bar, cli.TaskBar):
            bar.update(1, 1, 4_000_000)
        else:
            bar.update(ScanCounts(messages=1, inserted=1, points=4_000_000), 1)
    assert "2.00 M points/s" in capsys.readouterr().err


def test_closed_stdout_pipe_is_not_an_error(tmp_path: Path) -> None:
    """``scan2terrain ... | head``: the reader leaves early; no traceback, no 'internal error',
    exit 0, and the world is written."""
    script = (
        "import subprocess, sys\n"
        "p = subprocess.Popen([sys.executable, '-m', 'scan2terrain.cli'] + sys.argv[1:],"
        " stdout=subprocess.PIPE, stderr=subprocess.PIPE)\n"
        "p.stdout.close()\n"
        "err = p.stderr.read().decode()\n"
        "sys.stderr.write(err)\n"
        "sys.exit(p.wait())\n"
    )
    out = tmp_path / "w"
    r = subprocess.run(
        [
            sys.executable,
            "-c",
            script,
            "map2world",
            str(TB3_MAP),
            "-o",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert r.returncode == 0 and r.stderr == "", r.stderr
    assert (out / "spawn.yaml").is_file()


@pytest.mark.parametrize("kind", ["ours", "bug"])
def test_every_error_is_one_line(
    kind: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """Libraries quote whole files or message definitions in their errors: whatever the text,
    the CLI prints one line (exit 2 for ours, 1 for a bug)."""
    from scan2terrain.commands import maps
    from scan2terrain.errors import InputError

    def fail(*args: object, **kwargs: object) -> None:
        if kind == "ours":
            raise InputError(Path("m.yaml"), "first line\n  second line\r\nthird")
        raise RuntimeError("x" * 1000 + "\nmore")

    monkeypatch.setattr(maps, "map2world", fail)
    code = main(
        [
            "map2world",
            str(TB3_MAP),
            "-o",
            str(tmp_path / "w"),
        ]
    )
    err = capsys.readouterr().err
    assert code == (2 if kind == "ours" else 1)
    assert err.count("\n") == 1 and len(err) < 600, err
    if kind == "ours":
        assert "first line second line third" in err


@pytest.mark.parametrize("name", ["dem_moon_polar_geotiff", "dem_sfbay_squared_geotiff"])
def test_image2world_refuses_a_dem_and_names_dem2world(tmp_path: Path, name: str) -> None:
    """Run as a user runs it (no pytest log handler): tifffile's complaint about sfbay's
    GDAL_NODATA tag must not reach stderr either."""
    (dem,) = (TERRAIN / name).glob("*.tif")
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "scan2terrain.cli",
            "image2world",
            str(dem),
            "-o",
            str(tmp_path / "w"),
        ],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert r.returncode == 2 and r.stdout == ""
    (line,) = r.stderr.splitlines()
    assert str(dem) in line and "elevation raster" in line and "dem2world" in line
    assert leftovers(tmp_path) == []


def test_python_dash_m_runs_the_command() -> None:
    """`python -m scan2terrain` is the scan2terrain command (as `python -m scan2terrain.cli`)."""
    for module in ("scan2terrain", "scan2terrain.cli"):
        r = subprocess.run(
            [sys.executable, "-m", module, "map2wrld"], capture_output=True, text=True, check=False
        )
        assert r.returncode == 2 and "did you mean 'map2world'?" in r.stderr, r.stderr


def test_version_has_one_source_the_package_metadata() -> None:
    """``--version`` and ``scan2terrain.__version__`` say pyproject.toml's version."""
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pytest depends on tomli before 3.11
        import tomli as tomllib

    import scan2terrain

    root = ROOT
    declared = tomllib.loads((root / "pyproject.toml").read_text())["project"]["version"]
    done = subprocess.run(
        [sys.executable, "-m", "scan2terrain", "--version"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0 and done.stdout == f"scan2terrain {declared}\n"
    assert scan2terrain.__version__ == declared
    with pytest.raises(AttributeError):
        _ = scan2terrain.no_such_name
