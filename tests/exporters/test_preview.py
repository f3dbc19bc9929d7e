"""preview.png: small maps scaled up by a whole factor (nearest neighbour) to be readable, big
ones as before (issue 25 item 12)."""

from __future__ import annotations

import io

import numpy as np
import pytest
from numpy.typing import NDArray
from PIL import Image

from scan2terrain.exporters.mapserver import trinary_shades
from scan2terrain.exporters.preview import GAP, MAX_PANEL, MIN_WIDTH, preview_png


def decoded(png: bytes) -> NDArray[np.uint8]:
    with Image.open(io.BytesIO(png)) as im:
        return np.asarray(im)


def unscaled(pixels: NDArray[np.uint8], k: int) -> NDArray[np.uint8]:
    """The image of which ``pixels`` is each pixel repeated k x k times (checked)."""
    small = pixels[::k, ::k]
    assert np.array_equal(np.repeat(np.repeat(small, k, axis=0), k, axis=1), pixels)
    return small


def occupancy(rows: int, cols: int, seed: int) -> NDArray[np.int8]:
    rng = np.random.default_rng(seed)
    return rng.choice(np.array([-1, 0, 100], np.int8), size=(rows, cols))


def test_a_20_by_20_map_is_scaled_to_at_least_600_pixels_wide() -> None:
    """It was 76 x 20 pixels: three panels of 20 and two gaps."""
    before, after = occupancy(20, 20, 0), occupancy(20, 20, 1)
    pixels = decoded(preview_png(before, after, occupancy=True))
    width = 3 * 20 + 2 * GAP
    k = -(-MIN_WIDTH // width)
    assert pixels.shape == (20 * k, width * k) and pixels.shape[1] >= MIN_WIDTH
    small = unscaled(pixels, k)
    assert np.array_equal(small[:, :20], np.maximum(trinary_shades(np.flipud(before)), 3))
    assert np.array_equal(
        small[:, 20 + GAP : 40 + GAP], np.maximum(trinary_shades(np.flipud(after)), 3)
    )


def test_one_small_panel_is_scaled_too() -> None:
    grid = occupancy(20, 30, 2)
    pixels = decoded(preview_png(grid, None, occupancy=True))
    k = -(-MIN_WIDTH // 30)
    assert pixels.shape == (20 * k, 30 * k)
    assert np.array_equal(unscaled(pixels, k), trinary_shades(np.flipud(grid)))


@pytest.mark.parametrize("shape", [(300, 300), (50, 600)])
def test_maps_wide_enough_are_not_scaled(shape: tuple[int, int]) -> None:
    grid = occupancy(*shape, 3)
    pixels = decoded(preview_png(grid, grid, occupancy=True))
    assert pixels.shape == (shape[0], 3 * shape[1] + 2 * GAP)
    one = decoded(preview_png(grid, None, occupancy=True))
    assert one.shape == (shape if shape[1] >= MIN_WIDTH else (2 * shape[0], 2 * shape[1]))


def test_a_tall_narrow_map_is_not_scaled_past_the_panel_cap() -> None:
    """2000 x 5 cells: a factor that makes it 600 pixels wide would make it 40,000 tall."""
    grid = occupancy(2000, 5, 4)
    pixels = decoded(preview_png(grid, grid, occupancy=True))
    assert pixels.shape == (2000, 3 * 5 + 2 * GAP)
    grid = occupancy(400, 5, 5)
    pixels = decoded(preview_png(grid, None, occupancy=True))
    assert pixels.shape == (400 * (MAX_PANEL // 400), 5 * (MAX_PANEL // 400))
