"""Outputs for extents bigger than one heightmap or one map image (issue 6).

A terrain wider or taller than ``terrain.max_side`` samples becomes heightmap tiles of that side
with a stride of ``max_side - 1`` (neighbours share their border samples), one model each, in one
gz-sim world; a map_server map bigger than ``output.map_max_side`` becomes map tiles, each with
its own YAML. Small ``max_side`` values keep these tests fast; the rules do not depend on size.

The worlds are checked with Gazebo's own code (tests/gazebo_harness.py: SDFormat 12 strictly,
gz-common 4's heightmap loader as gz-physics' DART plugin uses it): at every shared border sample
both tiles give the same height, equal to the source grid within the quantisation; every sample
lies at the centre of its grid cell.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from types import MappingProxyType

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray
from PIL import Image

from scan2terrain.cli import COMMAND_DEFAULTS
from scan2terrain.commands import dem, maps
from scan2terrain.config import Config, load_config
from scan2terrain.errors import ConfigError
from scan2terrain.exporters import sdf
from scan2terrain.exporters.heightmap import quantise
from scan2terrain.exporters.mapserver import map_tiles
from scan2terrain.exporters.tiles import TileSpec, make_tiled_heightmap, tile_specs
from scan2terrain.readers import read_map_yaml
from scan2terrain.readers.dem import read_dem
from scan2terrain.types import HeightGrid, OccupancyGrid, Pose2D
from scan2terrain.world.folder import Result, write_world_folder
from tests.conftest import write_map
from tests.gazebo_harness import HeightmapProbe, probe_world, terrain_height, vertex_world_xy
from tests.geotiff import write_geotiff

S = 33  # terrain.max_side in these tests
ORIGIN = Pose2D(-3.0, 2.0, 0.0)
RES = 0.5


def rolling(rows: int, cols: int) -> NDArray[np.float32]:
    """Smooth hills, float32 metres, grid order."""
    yy, xx = np.mgrid[0:rows, 0:cols]
    hills: NDArray[np.float64] = (
        np.sin(xx / 7.0) * 1.5 + np.cos(yy / 5.0) + 0.3 * np.sin((xx + yy) / 3.0) + 3
    )
    return hills.astype(np.float32)


def config(**overrides: object) -> Config:
    return load_config(
        None,
        {
            "terrain.max_side": S,
            "filter.enabled": False,
            "world.simulator": "gz",
            "world.geometry": "heightmap",
            **overrides,
        },
    )


def height_world(
    heights: np.ndarray,
    out: Path,
    overrides: Mapping[str, object] = MappingProxyType({}),
    *,
    origin: Pose2D = ORIGIN,
    res: float = RES,
) -> Result:
    """The world of ``heights`` with config ``overrides`` (dotted keys, as ``--set`` takes)."""
    grid = HeightGrid(heights, np.ones(heights.shape, dtype=bool), res, origin)
    cfg = config(**overrides)
    folder = maps.height_folder(grid, Path("hills.xyz"), cfg)
    return write_world_folder(folder, out, overwrite=False)


def centres(
    origin: Pose2D, res: float, rows: np.ndarray, cols: np.ndarray
) -> tuple[np.ndarray, ...]:
    """Map-frame (x, y) of the centres of grid cells (rows, cols)."""
    return origin.transform((np.asarray(cols) + 0.5) * res, (np.asarray(rows) + 0.5) * res)


def collisions(result: Result, tmp: Path) -> dict[str, HeightmapProbe]:
    """The world's collision heightmaps by model name, as Gazebo's code loads them."""
    (w,) = result.worlds
    assert w.placement.simulator == "gz"
    version, probes = probe_world(w.world, [w.models], tmp / "probe")
    assert version  # parsed strictly by SDFormat
    cols = {p.model: p for p in probes if p.kind == "collision"}
    for vis in (p for p in probes if p.kind == "visual"):
        # gz-sim rendering places the visual by <pos> alone; it must match the collision.
        assert vis.pos == pytest.approx(cols[vis.model].pose[:3])
    return cols


def check_tiled_terrain(
    result: Result,
    tmp: Path,
    heights: np.ndarray,
    origin: Pose2D,
    res: float,
    *,
    bit_depth: int,
    sampling: int = 1,
    max_side: int = S,
) -> None:
    """Every sample from every tile that holds it, the shared ones from both, against
    ``heights`` (grid order; world = map frame), through Gazebo's heightmap loader."""
    probes = collisions(result, tmp)
    specs = tile_specs(heights.shape, max_side)
    assert len(probes) == len(specs)
    assert result.tiles == (specs[-1].row + 1, specs[-1].col + 1)
    full = (1 << bit_depth) - 1
    step = result.size_z / (full - 2)  # levels 0 and 1 are left unused
    tol = step / 2 + 1e-5 * result.size_z  # rounding to a level, float32 inside gz-common
    seen = np.zeros(heights.shape, dtype=int)
    by_index: dict[tuple[int, int], tuple[TileSpec, HeightmapProbe]] = {}
    base = result.worlds[0].placement.model_name
    for spec in specs:
        probe = probes[f"{base}_{spec.row}_{spec.col}"]
        by_index[spec.row, spec.col] = (spec, probe)
        assert probe.image_width == spec.side and probe.image_bpp == bit_depth
        vert = spec.side * sampling - sampling + 1
        # The size/vertSize rule, per tile: vertices res / sampling apart.
        assert probe.size[0] / vert == pytest.approx(res / sampling, rel=1e-9)
        # Pixel k (vertex k * sampling) is the centre of grid sample (r0 + k, c0 + k).
        k = np.arange(spec.side)
        vx, vy = vertex_world_xy(probe, k * sampling, k * sampling, "gz")
        cx, cy = centres(origin, res, spec.r0 + k, spec.c0 + k)
        np.testing.assert_allclose(vx, cx, atol=1e-6)
        np.testing.assert_allclose(vy[::-1], cy, atol=1e-6)  # image row 0 is the largest y
        rows, cols = np.mgrid[spec.r0 : spec.r0 + spec.rows, spec.c0 : spec.c0 + spec.cols]
        x, y = centres(origin, res, rows, cols)
        got = terrain_height(probe, x, y, "gz")
        want = heights[rows, cols]
        assert np.abs(got - want).max() <= tol, (spec, np.abs(got - want).max(), tol)
        seen[rows, cols] += 1
    assert seen.min() == 1  # every sample is in a tile
    # Seams: the shared row / column of neighbouring tiles, from either tile.
    shared = 0
    for (i, j), (spec, probe) in by_index.items():
        for di, dj in ((1, 0), (0, 1)):
            if (i + di, j + dj) not in by_index:
                continue
            other = by_index[i + di, j + dj][1]
            if di:
                cols = np.arange(spec.c0, spec.c0 + spec.cols)
                rows = np.full(cols.shape, spec.r0 + max_side - 1)
            else:
                rows = np.arange(spec.r0, spec.r0 + spec.rows)
                cols = np.full(rows.shape, spec.c0 + max_side - 1)
            x, y = centres(origin, res, rows, cols)
            a = terrain_height(probe, x, y, "gz")
            b = terrain_height(other, x, y, "gz")
            assert not np.isnan(a).any() and not np.isnan(b).any()
            # The same pixel value in both images and the same scale: the same height, up to
            # float32 rounding in gz-common / DART.
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-6 * (abs(result.size_z) + 10))
            np.testing.assert_allclose(a, heights[rows, cols], rtol=0, atol=tol)
            shared += rows.size
    # A sample shared by 2 tiles is on one seam, a corner shared by 4 tiles on 4.
    assert shared == int((seen == 2).sum()) + 4 * int((seen == 4).sum())


# --- layout ----------------------------------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(
    rows=st.integers(1, 200),
    cols=st.integers(1, 200),
    n=st.integers(1, 5),
)
def test_tile_layout_covers_every_sample_and_neighbours_share_one(
    rows: int, cols: int, n: int
) -> None:
    side = (1 << n) + 1
    specs = tile_specs((rows, cols), side)
    count = np.zeros((rows, cols), dtype=int)
    for s in specs:
        assert (s.r0, s.c0) == (s.row * (side - 1), s.col * (side - 1))
        assert 1 <= s.rows <= side and 1 <= s.cols <= side
        assert max(s.rows, s.cols) <= s.side <= side and (s.side - 1) & (s.side - 2) == 0
        count[s.r0 : s.r0 + s.rows, s.c0 : s.c0 + s.cols] += 1
    assert count.min() == 1
    # Exactly the rows/columns at multiples of side - 1 (inside the grid) are shared.
    shared_rows = np.arange(side - 1, rows - 1, side - 1)
    shared_cols = np.arange(side - 1, cols - 1, side - 1)
    want = np.ones((rows, cols), dtype=int)
    want[shared_rows, :] *= 2
    want[:, shared_cols] *= 2
    np.testing.assert_array_equal(count, want)


def test_tiles_share_one_quantisation_and_place_pixels_on_cell_centres() -> None:
    heights = rolling(70, 45)
    heights[3, 4] = -1.25  # below 0: the scale starts below the lowest height
    origin = Pose2D(10.0, -4.0, 0.0)
    tiled = make_tiled_heightmap(
        HeightGrid(heights, np.ones(heights.shape, dtype=bool), 0.2, origin),
        max_side=S,
        bit_depth=8,
        pad_height=0.5,
    )
    assert tiled.shape == (3, 2) and tiled.side == S
    levels = np.flipud(quantise(heights, tiled.z_min, tiled.z_range, 8))
    assert levels.min() == 2 and levels.max() == 255  # levels 0 and 1 unused
    top = np.zeros(heights.shape, dtype=int) - 1
    for spec, hm in tiled.tiles():
        grid_order = np.flipud(hm.pixels).astype(int)
        own = grid_order[: spec.rows, : spec.cols]
        np.testing.assert_array_equal(own, levels[spec.r0 :, spec.c0 :][: spec.rows, : spec.cols])
        assert not (hm.pixels == 1).any()
        # The tile's brightest pixel sits at its size.z above z_min, on the shared scale.
        brightest = int(hm.pixels.max())
        assert hm.z_min == tiled.z_min
        assert hm.z_range == pytest.approx(tiled.z_range * brightest / 255)
        # Pixel (N-1)/2 is at its cell centre.
        mid = (hm.side - 1) // 2
        cx, cy = origin.transform(
            np.array((spec.c0 + mid + 0.5) * 0.2), np.array((spec.r0 + mid + 0.5) * 0.2)
        )
        assert hm.centre == pytest.approx((float(cx), float(cy)), abs=1e-12)
        top[spec.r0 : spec.r0 + spec.rows, spec.c0 : spec.c0 + spec.cols] = own
    np.testing.assert_array_equal(top, levels)
    # Padding (beyond the grid, in the last tiles) at the padding height's level.
    corner = tiled.tile(tiled.specs()[-1])
    pad_level = quantise(np.array([[0.5]], np.float32), tiled.z_min, tiled.z_range, 8)[0, 0]
    assert (np.flipud(corner.pixels)[corner.grid_shape[0] :, :] == pad_level).all()


def test_map_tiles_partition_the_cells_along_the_grid_axes() -> None:
    rng = np.random.default_rng(5)
    data = rng.choice(np.array([-1, 0, 100], dtype=np.int8), size=(23, 17))
    grid = OccupancyGrid(data, 0.25, Pose2D(1.0, -2.0, 0.7))
    tiles = map_tiles(grid, 10)
    assert [(i, j) for i, j, _ in tiles] == [(i, j) for i in range(3) for j in range(2)]
    for i, j, tile in tiles:
        np.testing.assert_array_equal(tile.data, data[i * 10 : i * 10 + 10, j * 10 : j * 10 + 10])
        # The tile's cell (0, 0) has the centre of the grid's cell (10 i, 10 j).
        x0, y0 = tile.origin.transform(np.array(0.125), np.array(0.125))
        gx, gy = grid.origin.transform(np.array(j * 2.5 + 0.125), np.array(i * 2.5 + 0.125))
        assert (float(x0), float(y0)) == pytest.approx((float(gx), float(gy)), abs=1e-12)
        assert tile.origin.yaw == grid.origin.yaw
    assert map_tiles(grid, 23) == [(0, 0, grid)]


# --- worlds, through Gazebo's code -----------------------------------------------------------


@pytest.mark.parametrize(("bit_depth", "sampling"), [(8, 1), (16, 1), (8, 2)])
def test_tiled_height_world_has_no_seams(tmp_path: Path, bit_depth: int, sampling: int) -> None:
    """70 x 45 samples, max_side 33: 3 x 2 tiles, the corner one 17 px (6 x 13 samples)."""
    heights = rolling(70, 45)
    result = height_world(
        heights,
        tmp_path / "w",
        {"terrain.bit_depth": bit_depth, "world.sampling": sampling},
    )
    assert result.tiles == (3, 2) and result.heightmap_side == S
    assert result.size_z == pytest.approx(float(heights.max()))  # as one heightmap's size.z
    check_tiled_terrain(
        result, tmp_path, heights, ORIGIN, RES, bit_depth=bit_depth, sampling=sampling
    )
    names = sorted(p.name for p in (tmp_path / "w" / "models").iterdir())
    base = result.worlds[0].placement.model_name
    assert names == [f"{base}_{i}_{j}" for i in range(3) for j in range(2)]
    model = tmp_path / "w" / "models" / f"{base}_2_1"
    assert {p.name for p in (model / sdf.TEXTURE_DIR).iterdir()} == {
        sdf.HEIGHTMAP_FILE,
        *sdf.texture_pngs(),
    }
    with Image.open(model / sdf.TEXTURE_DIR / sdf.HEIGHTMAP_FILE) as im:
        assert im.size == (17, 17)
    assert any("3x2 heightmap tiles" in n for n in result.notes)


def test_tiled_upsampled_terrain(tmp_path: Path) -> None:
    """terrain.upsample applies first: 20 x 12 cells x 3 = 60 x 36 samples, 2 x 2 tiles."""
    coarse = rolling(20, 12)
    result = height_world(coarse, tmp_path / "w", {"terrain.upsample": 3})
    fine = np.repeat(np.repeat(coarse, 3, axis=0), 3, axis=1)
    assert result.tiles == (2, 2)
    check_tiled_terrain(result, tmp_path, fine, ORIGIN, RES / 3, bit_depth=8)


def test_grid_that_fits_stays_one_heightmap(tmp_path: Path) -> None:
    heights = rolling(S, 20)
    result = height_world(heights, tmp_path / "w", {"world.simulator": "both"})
    assert result.tiles == (1, 1) and len(result.worlds) == 2
    names = {p.name for p in (tmp_path / "w" / "models").iterdir()}
    assert names == {w.placement.model_name for w in result.worlds}
    assert (tmp_path / "w" / "world_classic.world").is_file()


def test_classic_is_refused_and_nothing_written(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="Only one Heightmap can be created per Scene"):
        height_world(rolling(40, 10), tmp_path / "w", {"world.simulator": "classic"})
    assert list(tmp_path.iterdir()) == []


def test_both_writes_gz_only_with_a_note(tmp_path: Path) -> None:
    result = height_world(rolling(40, 10), tmp_path / "w", {"world.simulator": "both"})
    assert [w.placement.simulator for w in result.worlds] == ["gz"]
    assert any(n.startswith("Gazebo Classic world not written") for n in result.notes)
    assert not (tmp_path / "w" / "world_classic.world").exists()
    assert not any("classic" in p.name for p in (tmp_path / "w" / "models").iterdir())


def test_occupancy_world_tiles_terrain_and_map(tmp_path: Path) -> None:
    """map2world of an 80 x 50 map: 3 x 2 terrain tiles (max_side 33) and 3 x 2 map tiles
    (map_max_side 30) that give back the whole map, cell for cell, by their YAML origins."""
    rng = np.random.default_rng(11)
    pixels = np.full((80, 50), 254, dtype=np.uint8)
    pixels[10:14, 3:47] = 0
    pixels[20:70, 30:33] = 0
    pixels[60:75, 5:20] = 205
    pixels[rng.random(pixels.shape) < 0.01] = 0
    yaml_path = write_map(tmp_path / "m", pixels, resolution=0.1, origin="[-2.0, 1.5, 0.0]")
    cfg = config(**{"output.map_max_side": 30, "world.simulator": "both", "terrain.height": 2.0})
    result = maps.map2world(yaml_path, tmp_path / "w", cfg)
    (w,) = result.worlds
    assert result.tiles == (3, 2) and w.placement.simulator == "gz"
    assert w.map_yaml is None and len(w.map_tiles) == 6
    files = sorted(p.name for p in (tmp_path / "w" / "map").iterdir())
    stems = [f"map_{i}_{j}" for i in range(3) for j in range(2)]
    assert files == sorted([f"{s}.pgm" for s in stems] + [f"{s}_gz.yaml" for s in stems])
    assert any("3x2 tiles map/map_<row>_<col>.pgm" in n for n in result.notes)

    # The same map in one piece, from a run whose map fits.
    single = maps.map2world(yaml_path, tmp_path / "w1", config(**{"terrain.height": 2.0}))
    (w1,) = single.worlds
    assert w1.map_yaml is not None
    _, whole = read_map_yaml(w1.map_yaml)
    rebuilt = np.full(whole.shape, 42, dtype=np.int8)
    for path in w.map_tiles:
        _, tile = read_map_yaml(path)
        assert tile.resolution == whole.resolution and tile.origin.yaw == 0.0
        r0 = round((tile.origin.y - whole.origin.y) / whole.resolution)
        c0 = round((tile.origin.x - whole.origin.x) / whole.resolution)
        assert (tile.origin.x, tile.origin.y) == pytest.approx(
            (whole.origin.x + c0 * 0.1, whole.origin.y + r0 * 0.1), abs=1e-9
        )
        h, wd = tile.shape
        assert (rebuilt[r0 : r0 + h, c0 : c0 + wd] == 42).all()  # tiles do not overlap
        rebuilt[r0 : r0 + h, c0 : c0 + wd] = tile.data
    np.testing.assert_array_equal(rebuilt, whole.data)

    # The terrain: occupied cells at the wall height, free ones at 0, seams shared.
    heights = np.where(whole.data == 100, np.float32(2.0), np.float32(0.0)).astype(np.float32)
    check_tiled_terrain(result, tmp_path, heights, whole.origin, 0.1, bit_depth=8)


def test_walls_world_map_is_tiled_too(tmp_path: Path) -> None:
    pixels = np.full((45, 20), 254, dtype=np.uint8)
    pixels[5:40, 8:11] = 0
    yaml_path = write_map(tmp_path / "m", pixels, resolution=0.1)
    cfg = config(**{"output.map_max_side": 16, "world.geometry": "boxes"})
    result = maps.map2world(yaml_path, tmp_path / "w", cfg)
    (w,) = result.worlds
    assert w.map_yaml is None and [p.name for p in w.map_tiles] == [
        f"map_{i}_{j}_gz.yaml" for i in range(3) for j in range(2)
    ]


def test_dem_bigger_than_max_side_is_tiled(tmp_path: Path) -> None:
    """A projected DEM (square 2 m pixels, 40 x 50) with max_side 17: 3 x 4 tiles at the DEM's
    own samples, z = elevation, every sample within 16-bit quantisation, no seams."""
    yy, xx = np.mgrid[0:40, 0:50]
    raster = (120.0 + 15 * np.sin(xx / 6.0) + 10 * np.cos(yy / 4.0)).astype(np.float32)
    path = write_geotiff(tmp_path / "d.tif", raster, scale=(2.0, 2.0))
    cfg = load_config(
        None,
        {"terrain.max_side": 17},
        defaults=COMMAND_DEFAULTS["dem2world"],
    )
    out = tmp_path / "w"
    result = dem.dem2world(path, out, cfg)
    source = read_dem(path)
    assert result.tiles == (3, 4)
    origin = Pose2D(-50 * 2.0 / 2, -40 * 2.0 / 2, 0.0)  # the DEM's centre at the origin
    check_tiled_terrain(result, tmp_path, source.heights, origin, 2.0, bit_depth=16, max_side=17)
    assert any("full scale" in n for n in result.notes)


def test_failure_mid_way_leaves_nothing_behind(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Outputs are atomic: a tile that fails to be written leaves no partial folder, and
    under --overwrite the old folder is kept as it was."""
    real = sdf.model_sdf
    calls = 0

    def failing(*args: object, **kwargs: object) -> bytes:
        nonlocal calls
        calls += 1
        if calls == 3:
            raise OSError("disk full")
        return real(*args, **kwargs)  # type: ignore[arg-type]

    old = tmp_path / "w"
    old.mkdir()
    (old / "keep.txt").write_text("old")
    monkeypatch.setattr(sdf, "model_sdf", failing)
    grid = HeightGrid(rolling(70, 45), np.ones((70, 45), dtype=bool), RES, ORIGIN)
    with pytest.raises(OSError, match="disk full"):
        write_world_folder(
            maps.height_folder(grid, Path("hills.xyz"), config()), old, overwrite=True
        )
    assert calls == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["w"]
    assert [p.name for p in old.iterdir()] == ["keep.txt"]
    calls = 0
    with pytest.raises(OSError, match="disk full"):
        folder = maps.height_folder(grid, Path("hills.xyz"), config())
        write_world_folder(folder, tmp_path / "new", overwrite=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["w"]
