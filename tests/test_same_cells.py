"""One cell rule on every path (issue 12, "Same input, same bytes, whichever path").

Points placed within 1e-7 m of cell edges, where float32 and float64 coordinates fall in
different cells: the octree (cloud2world/bag2world's default, end points), ``--stream`` and
``--workers 2`` must put every point in the same cell and count the same points in the z band,
so they write the same map, byte for byte, and the same world files.
"""

from __future__ import annotations

import math
from pathlib import Path

import laspy  # type: ignore[import-untyped]
import numpy as np
import pytest

from scan2terrain.cli import main
from scan2terrain.exporters.pointcloud import write_points
from scan2terrain.grids.tiles import Lattice, TileSet
from scan2terrain.octree.keys import KEY_OFFSET, coord_cell, key_to_coord
from scan2terrain.octree.tree import VoxelOctree
from tests.bagmaker import synthetic_room
from tests.fixtures import AUTZEN

RES = 0.05
#: Outputs that name the path taken or the octree it built, not the map.
PATH_FILES = {"scan2terrain.yaml", "octree.bt"}


def edge_points(rng: np.random.Generator, n: int, origin: float = 0.0) -> np.ndarray:
    """(n, 3) points within 1e-7 m of cell edges on every axis (x, y in 0..6 m, z in 0..1 m),
    ``origin`` added to x and y."""
    k = rng.integers(0, [120, 120, 20], (n, 3))
    pts = k * RES + rng.uniform(-1e-7, 1e-7, (n, 3))
    pts[:, :2] += origin
    return pts


def float64_cells_differ(pts: np.ndarray, res: float = RES) -> int:
    """How many points the float64 rule (floor(x / r) on the float64 coordinate) puts in another
    cell than OctoMap's float32 rule: the test is only worth something if this is large."""
    inv = 1.0 / res
    f64 = np.floor(pts * inv)
    f32 = np.floor(pts.astype(np.float32).astype(np.float64) * inv)
    return int((f64 != f32).any(axis=1).sum())


def octree_columns(pts: np.ndarray, z_min: float, z_max: float) -> set[tuple[int, int]]:
    tree = VoxelOctree(RES)
    tree.insert_endpoints(pts)
    keys, occupied = tree.occupied_and_free()
    keys = keys[occupied].astype(np.int64)
    centre = key_to_coord(keys[:, 2], RES)
    keys = keys[(centre >= z_min) & (centre <= z_max)]
    return {(int(ky) - KEY_OFFSET, int(kx) - KEY_OFFSET) for kx, ky, _ in keys}


def tile_columns(pts: np.ndarray, z_min: float, z_max: float) -> set[tuple[int, int]]:
    tiles = TileSet(Lattice(RES, 16, z_min, z_max))
    tiles.add_points(pts)
    grid = tiles.occupancy()
    r0 = round(grid.origin.y / RES)
    c0 = round(grid.origin.x / RES)
    rows, cols = np.nonzero(grid.data == 100)
    return {(int(r) + r0, int(c) + c0) for r, c in zip(rows, cols, strict=True)}


def test_the_cell_rule_is_the_octrees_key_rule() -> None:
    rng = np.random.default_rng(1)
    pts = edge_points(rng, 5_000)
    assert float64_cells_differ(pts) > 1_000
    tree = VoxelOctree(RES)
    tree.insert_endpoints(pts)
    keys, _ = tree.occupied_and_free()
    got = {tuple(int(k) - KEY_OFFSET for k in key) for key in keys}
    rule = {tuple(coord_cell(float(c), 1.0 / RES) for c in p) for p in pts}
    assert got == rule
    # Vectorised or one at a time, the same integers.
    assert coord_cell(np.float64(0.15), 1.0 / RES) == math.floor(np.float32(0.15) * (1.0 / RES))


@pytest.mark.parametrize("band", [(-math.inf, math.inf), (0.26, 0.74), (0.225, 0.775)])
def test_tiles_land_points_in_the_octrees_columns(band: tuple[float, float]) -> None:
    """The same cells, and the same points in the z band (voxel centres, as the octree's
    projection tests them; 0.225 and 0.775 are centres themselves)."""
    pts = edge_points(np.random.default_rng(2), 20_000)
    assert tile_columns(pts, *band) == octree_columns(pts, *band)


#: The finest LAS scale the readers accept (readers/_limits.MIN_SPACING_M, a micrometre): the
#: LAS files' points sit within it of the cell edges (the text and PLY/PCD files' within 1e-7).
LAS_SCALE = 1e-6


def _write_las(path: Path, pts: np.ndarray, offset: float, scale: float) -> None:
    header = laspy.LasHeader(point_format=0, version="1.2")
    header.scales = np.full(3, scale)
    header.offsets = np.array([offset, offset, 0.0])
    las = laspy.LasData(header)
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    las.write(path)


def run(capsys: pytest.CaptureFixture[str], *args: object) -> str:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    assert code == 0, err
    return out


def world_files(folder: Path) -> dict[str, bytes]:
    return {
        str(f.relative_to(folder)): f.read_bytes()
        for f in sorted(folder.rglob("*"))
        if f.is_file() and f.name not in PATH_FILES
    }


def assert_same_world(a: Path, b: Path) -> None:
    fa, fb = world_files(a), world_files(b)
    assert "map/map.pgm" in fa
    assert sorted(fa) == sorted(fb)  # the same model names and files
    for name in fa:
        assert fa[name] == fb[name], name


def test_cloud2world_octree_stream_and_dask_write_the_same_bytes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A LAS file at the finest scale the readers accept (a micrometre: its points on or a
    micrometre from cell edges), a float64 PLY and a float32 PCD within 1e-7 m of them, with
    a z band whose ends sit between voxel centres."""
    rng = np.random.default_rng(3)
    las_pts = edge_points(rng, 30_000)
    _write_las(tmp_path / "edges.las", las_pts, 0.0, LAS_SCALE)
    ply_pts = edge_points(rng, 30_000)
    write_points(tmp_path / "edges.ply", ply_pts)
    pcd_pts = edge_points(rng, 30_000)
    write_points(tmp_path / "edges.pcd", pcd_pts)
    assert float64_cells_differ(ply_pts) > 5_000
    files = [tmp_path / n for n in ("edges.las", "edges.ply", "edges.pcd")]
    common = ["--resolution", RES, "--z-min", 0.26, "--z-max", 0.74, "--no-preview"]
    run(capsys, "cloud2world", *files, "-o", tmp_path / "octree", *common)
    run(capsys, "cloud2world", *files, "-o", tmp_path / "stream", "--stream", *common)
    run(capsys, "cloud2world", *files, "-o", tmp_path / "dask", "--workers", 2, *common)
    assert_same_world(tmp_path / "octree", tmp_path / "stream")
    assert_same_world(tmp_path / "octree", tmp_path / "dask")


def test_local_origin_is_subtracted_alike(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """UTM-like LAS coordinates at cell edges: the origin subtracted in float64, then float32,
    on both paths (here with a heightmap)."""
    pts = edge_points(np.random.default_rng(4), 40_000, origin=500_000.0)
    _write_las(tmp_path / "far.las", pts, 500_000.0, LAS_SCALE)
    local = laspy.read(tmp_path / "far.las").xyz - np.array([500_003.0, 500_003.0, 0.0])
    assert float64_cells_differ(local) > 5_000
    common = ["--resolution", RES, "--no-preview", "--geometry", "heightmap"]
    out = run(capsys, "cloud2world", tmp_path / "far.las", "-o", tmp_path / "octree", *common)
    assert "local origin (500003, 500003, 0)" in out
    run(capsys, "cloud2world", tmp_path / "far.las", "-o", tmp_path / "stream", "--stream", *common)
    assert_same_world(tmp_path / "octree", tmp_path / "stream")


def test_bag2world_octree_stream_and_dask_write_the_same_bytes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """At 0.025 m the room's walls (x = -4.975, 5.025, ...) lie on cell edges: the posed hits
    fall either side of them by rounding."""
    room = synthetic_room("cloud", n_scans=6, resolution=0.025)
    bag = room.write(tmp_path / "room.mcap", "mcap")
    common = ["--resolution", 0.025, "--no-preview", "--no-filter", "--simulator", "gz"]
    run(capsys, "bag2world", bag, "-o", tmp_path / "octree", "--insert", "endpoints", *common)
    run(capsys, "bag2world", bag, "-o", tmp_path / "stream", "--stream", *common)
    run(capsys, "bag2world", bag, "-o", tmp_path / "dask", "--workers", 2, *common)
    assert_same_world(tmp_path / "octree", tmp_path / "stream")
    assert_same_world(tmp_path / "octree", tmp_path / "dask")


# --- terrain: heights from the points on every path (issue 25) --------------------------------


def heightmap_levels(folder: Path) -> int:
    """Distinct grey levels of the gz-sim heightmap (the Classic model's image is the same)."""
    from PIL import Image

    (png,) = [
        p
        for p in folder.glob("models/*/materials/textures/heightmap.png")
        if not p.parent.parent.parent.name.endswith("_classic")
    ]
    return len(np.unique(np.asarray(Image.open(png))))


def assert_same_terrain(a: Path, b: Path) -> None:
    fa, fb = world_files(a), world_files(b)
    assert any(n.endswith("heightmap.png") for n in fa)
    assert sorted(fa) == sorted(fb)
    for name in fa:
        assert fa[name] == fb[name], name


def hill_points(rng: np.random.Generator, n: int, res: float) -> np.ndarray:
    """(n, 3) points of a smooth hill with 6 m of relief over 40 x 30 m (and 2 cm of noise),
    x and y within 1e-7 m of the edges of ``res`` cells."""
    k = rng.integers(0, [round(40 / res), round(30 / res)], (n, 2))
    xy = k * res + rng.uniform(-1e-7, 1e-7, (n, 2)) + rng.integers(0, 2, (n, 2)) * res / 2
    z = 6 * np.exp(-((xy[:, 0] - 22) ** 2 + (xy[:, 1] - 14) ** 2) / 150) + 0.05 * xy[:, 0]
    z += rng.normal(0, 0.02, n)
    return np.column_stack([xy, z])


def test_autzen_heights_are_the_points_on_every_path(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The README's example: 28 m of ground at 2 m cells was 15 levels (the voxels' 2 m
    terraces) on the octree path against 253 streamed; and the octree path took its local
    origin from the ground points, 43 m below the header's the streamed path takes."""
    common = ["--las-classes", 2, "--grid", "height", "--resolution", 2, "--no-filter"]
    out = run(capsys, "cloud2world", AUTZEN, "-o", tmp_path / "octree", *common)
    run(capsys, "cloud2world", AUTZEN, "-o", tmp_path / "stream", "--stream", *common)
    run(capsys, "cloud2world", AUTZEN, "-o", tmp_path / "dask", "--workers", 2, *common)
    assert "local origin (636590, 849217, 463)" in out  # the header's bounds, as streamed
    assert_same_terrain(tmp_path / "octree", tmp_path / "stream")
    assert_same_terrain(tmp_path / "octree", tmp_path / "dask")
    ground = laspy.read(AUTZEN)
    relief = float(np.ptp(ground.z[ground.classification == 2]))
    # Voxel centres would give at most relief / 2 m + 1 levels.
    assert heightmap_levels(tmp_path / "octree") > 4 * (relief / 2 + 1)


@pytest.mark.parametrize("stat", ["max", "min", "mean"])
def test_a_smooth_hill_is_the_same_terrain_on_the_octree_and_streamed_paths(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], stat: str
) -> None:
    """A LAS file and a PLY of a hill, points at cell edges, with a z band cutting the top
    of the hill and one ending between voxel centres."""
    res = 0.5
    rng = np.random.default_rng(11)
    _write_las(tmp_path / "hill.las", hill_points(rng, 20_000, res), 0.0, LAS_SCALE)
    write_points(tmp_path / "hill.ply", hill_points(rng, 20_000, res))
    files = [tmp_path / "hill.las", tmp_path / "hill.ply"]
    common = ["--grid", "height", "--resolution", res, "--height-stat", stat, "--no-preview"]
    common += ["--z-max", 5.1]
    run(capsys, "cloud2world", *files, "-o", tmp_path / "octree", *common)
    run(capsys, "cloud2world", *files, "-o", tmp_path / "stream", "--stream", *common)
    assert_same_terrain(tmp_path / "octree", tmp_path / "stream")
    # 5.1 m of hill in 0.5 m voxels: at most 11 levels from voxel centres.
    assert heightmap_levels(tmp_path / "octree") > 100


def test_a_smooth_hill_on_dask_is_the_octree_paths_terrain(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    res = 0.25
    rng = np.random.default_rng(12)
    _write_las(tmp_path / "hill.las", hill_points(rng, 40_000, res), 0.0, LAS_SCALE)
    write_points(tmp_path / "hill.pcd", hill_points(rng, 20_000, res))
    files = [tmp_path / "hill.las", tmp_path / "hill.pcd"]
    common = ["--grid", "height", "--resolution", res, "--height-stat", "mean", "--no-preview"]
    run(capsys, "cloud2world", *files, "-o", tmp_path / "octree", *common)
    run(capsys, "cloud2world", *files, "-o", tmp_path / "dask", "--workers", 2, *common)
    assert_same_terrain(tmp_path / "octree", tmp_path / "dask")


def test_bag2world_end_points_terrain_is_the_same_on_every_path(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A bag's hits as a height grid: the octree path (end points) takes its heights from the
    same hits the streamed path rasterises."""
    room = synthetic_room("cloud", n_scans=6, resolution=0.025)
    bag = room.write(tmp_path / "room.mcap", "mcap")
    common = ["--resolution", 0.025, "--no-preview", "--no-filter", "--grid", "height"]
    run(capsys, "bag2world", bag, "-o", tmp_path / "octree", "--insert", "endpoints", *common)
    run(capsys, "bag2world", bag, "-o", tmp_path / "stream", "--stream", *common)
    run(capsys, "bag2world", bag, "-o", tmp_path / "dask", "--workers", 2, *common)
    assert_same_terrain(tmp_path / "octree", tmp_path / "stream")
    assert_same_terrain(tmp_path / "octree", tmp_path / "dask")
