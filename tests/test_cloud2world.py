"""cloud2world acceptance (issue 4): point-cloud files in, worlds out.

* Twins (the same points in two formats) give identical outputs: PCD/PLY, LAS/LAZ.
* Ground-classified LAZ gives terrain at the heights the points say, through Gazebo's loader.
* Clouds far from the origin (UTM) get a local origin instead of leaving the octree's key range.
* Bad input: one line, exit 2, nothing written.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import laspy  # type: ignore[import-untyped]
import numpy as np
import pytest
from PIL import Image

from scan2terrain.cli import main
from scan2terrain.config import two_digits_up
from tests.fixtures import AUTZEN, HDL_PCD, HDL_PLY, SIMPLE_LAS, SIMPLE_LAZ
from tests.gazebo_harness import probe_world, terrain_height

KEY_OFFSET = 32768


def run(capsys: pytest.CaptureFixture[str], *args: object) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def heightmap(out: Path) -> np.ndarray:
    """The gz model's heightmap pixels."""
    (png,) = [
        p
        for p in (out / "models").glob("*/materials/textures/heightmap.png")
        if not p.parent.parent.parent.name.endswith("_classic")
    ]
    with Image.open(png) as im:
        return np.asarray(im)


def local_origin(stdout: str) -> np.ndarray:
    found = re.search(r"local origin \((-?\d+), (-?\d+), (-?\d+)\) subtracted", stdout)
    assert found, stdout
    return np.array([float(v) for v in found.groups()])


# --- twins -------------------------------------------------------------------------------------


TWINS = {
    # One HDL-32 frame, ground at about -1.9 m: the band keeps what stands on it.
    "hdl32-pcd-ply": (
        HDL_PCD,
        HDL_PLY,
        ["--resolution", "0.2", "--z-min", "-1.5", "--z-max", "1.5"],
    ),
    # 1,065 points over 3.4 x 4.6 km (feet): sparse, so no filter (a median would erase them).
    "las-laz": (SIMPLE_LAS, SIMPLE_LAZ, ["--resolution", "20", "--grid", "height", "--no-filter"]),
}


@pytest.mark.parametrize("case", list(TWINS))
def test_twin_files_give_identical_grids(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str
) -> None:
    first, second, options = TWINS[case]
    for src, name in ((first, "a"), (second, "b")):
        heightmap_world = ["--geometry", "heightmap"]  # its PNG holds the whole grid
        code, stdout, err = run(
            capsys, "cloud2world", src, "-o", tmp_path / name, *options, *heightmap_world
        )
        assert code == 0, err
        assert f"{src.name}: " in stdout
    a, b = tmp_path / "a", tmp_path / "b"
    pixels = heightmap(a)
    np.testing.assert_array_equal(pixels, heightmap(b))
    levels = len(np.unique(pixels))
    assert levels > 2 if "--grid" in options else levels == 2  # not a flat canvas
    assert (a / "octree.bt").read_bytes() == (b / "octree.bt").read_bytes()
    if "--grid" not in options:  # occupancy grids also write the map
        assert (a / "map/map.pgm").read_bytes() == (b / "map/map.pgm").read_bytes()
        with Image.open(a / "map/map.pgm") as im:
            px = np.asarray(im)
        assert (px == 0).sum() > 500 and (px == 254).sum() == 0  # end points: no free space


# --- terrain from ground points ----------------------------------------------------------------


def test_laz_ground_class_gives_the_terrain_the_points_say(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Autzen (real airborne lidar), class 2 only, 2.5D at 2 ft (the file's unit): at every cell
    centre where it has ground points, Gazebo's terrain is at the highest ground point's z
    (not its voxel's centre), within one grey level of the 8-bit heightmap. The local origin is
    the header's bounds' centre, as the streamed path, which reads no point first, takes it."""
    res = 2.0
    out = tmp_path / "w"
    code, stdout, err = run(
        capsys,
        "cloud2world",
        AUTZEN,
        "-o",
        out,
        "--las-classes",
        "2",
        "--grid",
        "height",
        "--resolution",
        res,
        "--no-filter",
        "--simulator",
        "gz",
    )
    assert code == 0, err
    las = laspy.read(AUTZEN)
    ground = np.column_stack([las.x, las.y, las.z])[np.asarray(las.classification) == 2]
    assert f"{len(ground):,} points" in stdout and len(ground) < len(las.points)
    origin = local_origin(stdout)
    np.testing.assert_array_equal(origin, np.round((las.header.mins + las.header.maxs) / 2))

    # The expected 2.5D grid, from the points alone: columns as OctoMap keys float32 points.
    local = (ground - origin).astype(np.float32)
    keys = np.floor(local.astype(np.float64) * (1.0 / res)).astype(np.int64)
    cols, inverse = np.unique(keys[:, :2], axis=0, return_inverse=True)
    top = np.full(len(cols), -np.inf, dtype=np.float32)
    np.maximum.at(top, inverse.reshape(-1), local[:, 2])
    want = top.astype(np.float64)
    x, y = (cols[:, 0] + 0.5) * res, (cols[:, 1] + 0.5) * res

    (world,) = out.glob("world_gz.sdf")
    _, probes = probe_world(world, [out / "models"], tmp_path / "probe")
    (col,) = [p for p in probes if p.kind == "collision"]
    got = terrain_height(col, x, y, "gz")
    level = col.size[2] / 255
    close = np.abs(got - want) <= 0.5 * level + 1e-6
    print(
        f"\nautzen ground: {len(cols)} columns, {close.mean():.4%} within half a grey level "
        f"({level:.3f} ft), heights {want.min():.1f} .. {want.max():.1f} ft"
    )
    assert close.mean() >= 0.995
    assert want.max() - want.min() > 10  # real relief, not a flat plate
    assert col.size[2] == pytest.approx(want.max() - want.min(), abs=1e-4)


def test_far_cloud_gets_a_local_origin(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A UTM-like cloud (5,000 km north) works: the note gives the subtracted origin and the
    world is the cloud minus it. Without the local origin, the error says why."""
    g = np.mgrid[0:20:0.25, 0:20:0.25].reshape(2, -1).T + 0.125
    box = (np.abs(g[:, 0] - 10) < 2) & (np.abs(g[:, 1] - 10) < 2)
    pts = np.column_stack([g[:, 0] + 500_000.0, g[:, 1] + 5_000_000.0, 100.0 + box * 1.0])
    src = tmp_path / "utm.xyz"
    np.savetxt(src, pts, fmt="%.3f")
    options = ["--grid", "height", "--resolution", "0.5", "--no-filter", "--simulator", "gz"]
    out = tmp_path / "w"
    code, stdout, err = run(capsys, "cloud2world", src, "-o", out, *options)
    assert code == 0, err
    np.testing.assert_array_equal(local_origin(stdout), [500_010, 5_000_010, 100])
    assert "world = cloud - origin" in stdout
    _, probes = probe_world(out / "world_gz.sdf", [out / "models"], tmp_path / "probe")
    (col,) = [p for p in probes if p.kind == "collision"]
    # the ground's points at 0 m, the box's at 1 m, the box around the local origin
    got = terrain_height(col, np.array([0.25, -0.25, 5.25, -7.75]), np.array([0.25] * 4), "gz")
    np.testing.assert_allclose(got, [1.0, 1.0, 0.0, 0.0], atol=1e-6)

    (tmp_path / "none.yaml").write_text("scans:\n  local_origin: none\n")
    outs = tmp_path / "outs"
    outs.mkdir()
    code, stdout, err = run(
        capsys, "cloud2world", src, "-o", outs / "w", *options, "--config", tmp_path / "none.yaml"
    )
    assert code == 2 and stdout == ""
    assert err.count("\n") == 1 and err.startswith(f"scan2terrain: error: {src}: ")
    assert "outside the octree's key range" in err
    assert list(outs.iterdir()) == []


# --- bad input ---------------------------------------------------------------------------------


def _write_no_finite(tmp: Path) -> Path:
    p = tmp / "nan.pcd"
    p.write_text(
        "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 3\nHEIGHT 1\n"
        "VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 3\nDATA ascii\nnan nan nan\nnan 1 2\n1 inf 2\n"
    )
    return p


@pytest.mark.parametrize(
    ("case", "message"),
    [
        ("no finite point", "no finite point in the cloud"),
        ("missing file", "point-cloud file not found"),
    ],
)
def test_bad_cloud_one_line_exit_2_nothing_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str, message: str
) -> None:
    src = _write_no_finite(tmp_path) if case == "no finite point" else tmp_path / "gone.ply"
    outs = tmp_path / "outs"
    outs.mkdir()
    code, stdout, err = run(capsys, "cloud2world", src, "-o", outs / "w")
    assert code == 2 and stdout == ""
    assert err.count("\n") == 1 and err.startswith(f"scan2terrain: error: {src}: ")
    assert message in err
    assert list(outs.iterdir()) == []  # no folder, no hidden temporary folder


def test_coarse_height_grid_is_filled_not_a_pin_cushion(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """At 2 m cells the nearest fill reaches 4 cells by default (a fixed 1 m filled nothing,
    leaving 86% of the grid at the floor between the points' columns); idw gives the same."""
    shares = {}
    for name, flags in (
        ("default", []),
        ("idw", ["--fill", "idw"]),
        ("1m", ["--fill-max-distance", "1"]),
    ):
        out = tmp_path / name
        argv = [AUTZEN, "-o", out, "--las-classes", "2", "--grid", "height", "--resolution", "2"]
        code, _, err = run(capsys, "cloud2world", *argv, "--no-filter", "--simulator", "gz", *flags)
        assert code == 0, err
        with Image.open(out / "preview.png") as im:  # the filled grid (one panel: no filter)
            grid = np.asarray(im)
        shares[name] = float((grid == grid.min()).mean())
    assert shares["default"] < 0.4 and abs(shares["default"] - shares["idw"]) < 0.05
    assert shares["1m"] > 0.8


@pytest.mark.parametrize("stream", [[], ["--stream"]])
def test_ground_as_an_occupancy_grid_says_how_to_make_terrain(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], stream: list[str]
) -> None:
    """Seen: four LAS tiles of a survey made, by default, one 400 x 400 m block of walls with
    no word why. A grid nearly all occupied gets a note naming --grid height and the z band;
    the same ground with the z band above it gets none."""
    g = np.mgrid[0:60:0.25, 0:60:0.25].reshape(2, -1).T + 0.125
    pts = np.column_stack([g, 0.1 * np.sin(g[:, 0])])
    pts = np.vstack([pts, [[30.0, 30.0, 1.5]]])  # one post standing up
    src = tmp_path / "ground.xyz"
    np.savetxt(src, pts, fmt="%.3f")
    common = ["--resolution", "0.5", *stream]
    code, stdout, err = run(capsys, "cloud2world", src, "-o", tmp_path / "w", *common)
    assert code == 0, err
    assert "of the grid is occupied" in stdout and "--grid height" in stdout
    code, stdout, err = run(
        capsys, "cloud2world", src, "-o", tmp_path / "w2", *common, "--z-min", "1.0"
    )
    assert code == 0, err
    assert "of the grid is occupied" not in stdout


@pytest.mark.parametrize("stream", [[], ["--stream"]])
def test_small_ground_grid_gets_the_solid_note_too(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], stream: list[str]
) -> None:
    """Seen: a 3 x 3 m field (900 cells at 0.1 m, 96% occupied) became one solid block with no
    note, because the note skipped grids under 10,000 cells. A field of a few hundred cells
    gets it; a post of a few cells (its own footprint is its grid, all of it occupied) does
    not."""
    rng = np.random.default_rng(5)
    g = np.mgrid[0:3:0.05, 0:3:0.05].reshape(2, -1).T + 0.025
    keep = ~((g[:, 0] > 1.0) & (g[:, 0] < 1.3) & (g[:, 1] > 1.0) & (g[:, 1] < 1.4))  # a hole
    field = np.column_stack([g[keep], rng.uniform(0.01, 0.04, int(keep.sum()))])
    src = tmp_path / "field.xyz"
    np.savetxt(src, field, fmt="%.3f")
    common = ["--resolution", "0.1", *stream]
    code, stdout, err = run(capsys, "cloud2world", src, "-o", tmp_path / "w", *common)
    assert code == 0, err
    share = re.search(r"(\d+)% of the grid is occupied", stdout)
    assert share is not None, stdout
    assert 90 <= int(share.group(1)) < 100 and "--grid height" in stdout
    post = np.column_stack([np.full(40, 0.05), np.full(40, 0.05), np.linspace(0, 4, 40)])
    src = tmp_path / "post.xyz"
    np.savetxt(src, post, fmt="%.3f")
    code, stdout, err = run(capsys, "cloud2world", src, "-o", tmp_path / "p", *common)
    assert code == 0, err
    assert "of the grid is occupied" not in stdout


def test_solid_note_starts_at_a_handful_of_cells() -> None:
    """Nine cells all occupied (a post's own footprint) get no note; ten get it, and stay
    over the share with one free cell, not with two."""
    from scan2terrain.steps import SOLID_MIN_CELLS, solid_hint
    from scan2terrain.types import OccupancyGrid, Pose2D

    def hint(data: np.ndarray) -> str | None:
        return solid_hint(OccupancyGrid(data.astype(np.int8), 0.1, Pose2D(0.0, 0.0)))

    assert SOLID_MIN_CELLS == 10
    assert hint(np.full((3, 3), 100)) is None
    ten = np.full((2, 5), 100)
    assert hint(ten) is not None and "100% of the grid is occupied" in str(hint(ten))
    ten[0, 0] = 0
    assert "90% of the grid is occupied" in str(hint(ten))
    ten[0, 1] = -1
    assert hint(ten) is None


# --- heights from the points (issue 25) --------------------------------------------------------


def _ray_cast_scene(tmp: Path) -> list[Path]:
    """Four clouds seen from one sensor at the origin, 1.5 m over flat ground: in the first a
    person stands at (5.1, 0.1), up to z = 0.3; in the other three the person is gone and rays
    to the ground and to a post at x = 12.1 behind them cross every voxel they took."""
    g = np.mgrid[1.0:12.05:0.1, -3.0:3.05:0.1].reshape(2, -1).T
    ground = np.column_stack([g, np.full(len(g), -1.5)])
    post = np.column_stack(
        [np.full(71, 12.1), np.full(71, 0.1), np.linspace(-1.5, 2.0, 71)]
    )  # fmt: skip
    person = np.column_stack([np.full(37, 5.1), np.full(37, 0.1), np.linspace(-1.5, 0.3, 37)])
    files = []
    for i, pts in enumerate([np.vstack([ground, person]), *[np.vstack([ground, post])] * 3]):
        files.append(tmp / f"cloud_{i}.xyz")
        np.savetxt(files[-1], pts, fmt="%.4f")
    return files


@pytest.mark.parametrize("insert", ["raycast", "endpoints"])
def test_ray_cast_heights_stay_on_what_the_octree_keeps(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], insert: str
) -> None:
    """Heights are the points' own z, but with ray casting the octree says which of the
    points' voxels are still there: the person's column keeps its ground only, so the
    terrain there is no higher than the top of the ground's voxel; end points keep them all."""
    out = tmp_path / "w"
    code, _, err = run(
        capsys, "cloud2world", *_ray_cast_scene(tmp_path), "-o", out, "--insert", insert,
        "--pose", 0, 0, 0, 0, 0, 0, "--grid", "height", "--resolution", 0.2, "--no-filter",
        "--simulator", "gz",
    )  # fmt: skip
    assert code == 0, err
    _, probes = probe_world(out / "world_gz.sdf", [out / "models"], tmp_path / "probe")
    (col,) = [p for p in probes if p.kind == "collision"]
    level = col.size[2] / 255
    person, ground = terrain_height(col, np.array([5.1, 3.1]), np.array([0.1, 0.1]), "gz")
    assert ground == pytest.approx(-1.5, abs=level)  # the points' z, not a voxel centre
    if insert == "raycast":
        assert person <= -1.4 + level
    else:
        assert person == pytest.approx(0.3, abs=level)


def _hills(tmp: Path, relief: float, noise: float, n: int = 200_000) -> Path:
    """A LAS file of ground points over 400 x 400 m: bumps about 60 m across with
    ``relief`` metres between the lowest and highest, ``noise`` metres of scatter."""
    rng = np.random.default_rng(5)
    xy = rng.uniform(0, 400, (n, 2))
    z = np.sin(xy[:, 0] / 20) * np.cos(xy[:, 1] / 25) * relief / 2 + rng.normal(0, noise, n)
    header = laspy.LasHeader(point_format=0, version="1.2")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.zeros(3)
    las = laspy.LasData(header)
    las.x, las.y, las.z = xy[:, 0], xy[:, 1], z + 50
    path = tmp / f"hills_{relief:g}_{noise:g}.las"
    las.write(path)
    return path


@pytest.mark.parametrize(
    "case",
    [
        (40.0, 0.03, 40.0, True),  # bumps of 60 m in cells of 40: a few blocks
        (40.0, 0.03, 2.0, False),
        # Flat and noisy, 500 points a cell: they span over half a metre, above the relief,
        # but the scatter is no hidden relief.
        (0.3, 0.08, 20.0, False),
    ],
)
def test_cells_coarser_than_the_relief_get_a_note_on_every_path(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], case: tuple[float, float, float, bool]
) -> None:
    """(relief, noise, cell side, whether the cells are too coarse); the note names the
    resolution of about four points a cell, from the points where they are."""
    relief, noise, res, coarse = case
    las = _hills(tmp_path, relief, noise)
    notes = []
    for i, stream in enumerate([[], ["--stream"]]):
        code, out, err = run(
            capsys, "cloud2world", las, "-o", tmp_path / f"w{i}", "--grid", "height",
            "--resolution", res, "--no-preview", "--simulator", "gz", *stream,
        )  # fmt: skip
        assert code == 0, err
        notes.append([line for line in out.splitlines() if "coarse for this terrain" in line])
    assert notes[0] == notes[1]
    assert bool(notes[0]) == coarse, notes[0]
    if coarse:
        (note,) = notes[0]
        fine = two_digits_up(2 * math.sqrt(400 * 400 / 200_000))  # every cell has points
        assert f"cells of {res:g} m" in note and f"--resolution {fine:g} " in note, note
