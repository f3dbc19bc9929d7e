"""Heightmap images: 2^n+1, padded not stretched, brightest pixel = full scale, placement."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from scan2terrain.exporters.heightmap import heightmap_side, make_heightmap
from scan2terrain.types import HeightGrid, Pose2D


def grid(h: np.ndarray, res: float = 0.1, origin: Pose2D | None = None) -> HeightGrid:
    origin = Pose2D(0, 0) if origin is None else origin
    return HeightGrid(h.astype(np.float32), np.ones(h.shape, bool), res, origin)


@pytest.mark.parametrize(
    ("rows", "cols", "side"),
    [
        (1, 1, 3),
        (3, 3, 3),
        (4, 2, 5),
        (129, 50, 129),
        (130, 1, 257),
        (945, 1165, 2049),
        (2048, 2048, 2049),
        (2049, 10, 2049),
    ],
)
def test_side(rows: int, cols: int, side: int) -> None:
    assert heightmap_side(rows, cols) == side


def test_padding_keeps_cells_and_centre_is_placed() -> None:
    h = np.zeros((3, 6))
    h[0, 0] = 2.0  # lowest-left cell is a wall
    hm = make_heightmap(grid(h, 0.5, Pose2D(10.0, 20.0)))
    assert hm.side == 9 and hm.pad == (1, 3)
    # Image row 0 is the top (largest y): the grid's row 0 is image row side-1-pad_bottom.
    assert hm.pixels[9 - 1 - 3, 1] == 255
    assert hm.pixels.sum() == 255
    # Centre pixel (4, 4) is grid cell (row 1, col 3): centre (10 + 3.5*0.5, 20 + 1.5*0.5).
    assert hm.centre == pytest.approx((11.75, 20.75))


def test_brightest_is_full_scale_and_size_z_is_its_height() -> None:
    hm = make_heightmap(grid(np.array([[0.0, 0.3], [0.6, 0.45]])))
    assert hm.pixels.max() == 255 and hm.z_range == pytest.approx(0.6) and hm.z_min == 0.0
    hm16 = make_heightmap(grid(np.array([[0.0, 0.3], [0.6, 0.45]])), bit_depth=16)
    assert hm16.pixels.max() == 65535 and hm16.pixels.dtype == np.uint16
    img = Image.open(io.BytesIO(hm16.png()))
    assert img.mode.startswith("I") and np.asarray(img).max() == 65535


def test_negative_heights_move_the_base() -> None:
    hm = make_heightmap(grid(np.array([[-1.0, 1.0]])), pad_height=0.0)
    assert hm.z_min == -1.0 and hm.z_range == 2.0
    assert hm.pixels.min() == 0 and hm.pixels.max() == 255


def test_flat_grid() -> None:
    hm = make_heightmap(grid(np.zeros((4, 4))))
    assert hm.pixels.max() == 0 and hm.z_range == 1.0


def test_size_per_simulator() -> None:
    hm = make_heightmap(grid(np.zeros((5, 5)), 0.05))
    # gz-sim/DART: spacing size / vertSize, vertSize = N*s - s + 1.
    assert hm.size_xy("gz", 1) == pytest.approx(0.05 * 5)
    assert hm.size_xy("gz", 2) == pytest.approx(0.05 * 9 / 2)
    # Classic/ODE: size spans first to last vertex.
    assert hm.size_xy("classic", 2) == pytest.approx(0.05 * 4)


def test_rotated_grid_refused() -> None:
    with pytest.raises(ValueError, match="axis-aligned"):
        make_heightmap(grid(np.zeros((2, 2)), origin=Pose2D(0, 0, 0.1)))


def test_map_export_round_trips_through_map_server(tmp_path: Path) -> None:
    from scan2terrain.exporters.mapserver import map_pgm, map_yaml
    from scan2terrain.readers import read_map_yaml
    from scan2terrain.types import OccupancyGrid

    data = np.random.default_rng(3).choice(np.array([-1, 0, 100], np.int8), (7, 11))
    grid = OccupancyGrid(data, 0.05, Pose2D(-1.5, 2.25, 0.0))
    (tmp_path / "m.pgm").write_bytes(map_pgm(grid))
    (tmp_path / "m.yaml").write_bytes(map_yaml(grid, "m.pgm", comment="test"))
    meta, back = read_map_yaml(tmp_path / "m.yaml")
    np.testing.assert_array_equal(back.data, data)  # unknown stays unknown (205 vs free_thresh)
    assert (meta.origin.x, meta.origin.y, meta.resolution) == (-1.5, 2.25, 0.05)
