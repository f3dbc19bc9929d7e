"""Height grids to Gazebo heightmap images: square 2^n+1, padded (never stretched), scaled so the
brightest pixel is full scale, and placed so every pixel lands on its cell centre.

How Gazebo reads the image (../shared/REFERENCE.md): a pixel's height is ``v / v_max * size.z``
with ``v_max`` the brightest pixel, image row 0 at +y, the field centred on its frame. So we pad
the grid into an N x N canvas (N = 2^n + 1), put the lowest height at 0 and the highest at full
scale, and report ``size.z`` as exactly that height range.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from scan2terrain.grids.spawn import ground_under
from scan2terrain.types import HeightGrid

#: The simulators we place terrain for.
GZ = "gz"
CLASSIC = "classic"


@dataclass(frozen=True)
class Heightmap:
    """A heightmap image and where it belongs.

    Attributes
    ----------
    pixels : uint8 or uint16 array (N, N), image order (row 0 = largest y)
    resolution : float
        Metres between neighbouring pixels, the grid's cell size.
    centre : (float, float)
        Map-frame x, y of the centre pixel ``(N - 1) / 2``.
    z_min : float
        Height of a 0 pixel, metres.
    z_range : float
        SDF ``size.z``: the height above ``z_min`` of the image's brightest pixel, metres
        (Gazebo scales every pixel to it, ``v / v_max * size.z``). In one heightmap the
        brightest pixel is full scale; a terrain tile (:mod:`.tiles`) keeps the quantisation of
        the whole terrain, so its brightest pixel may be darker and its ``z_range`` smaller.
    pad : (int, int)
        Columns of padding left of and rows below the grid inside the canvas.
    grid_shape : (int, int)
        Rows and columns of the grid before padding.
    """

    pixels: NDArray[np.uint8] | NDArray[np.uint16]
    resolution: float
    centre: tuple[float, float]
    z_min: float
    z_range: float
    pad: tuple[int, int]
    grid_shape: tuple[int, int]

    @property
    def side(self) -> int:
        return int(self.pixels.shape[0])

    @property
    def bit_depth(self) -> int:
        return 16 if self.pixels.dtype == np.uint16 else 8

    def size_xy(self, simulator: str, sampling: int) -> float:
        """The SDF ``size.x`` (= ``size.y``) that puts neighbouring pixels ``resolution`` apart.

        gz-sim (DART, gz-physics ``CustomHeightmapShape.cc``): vertex spacing is
        ``size / vertSize`` with ``vertSize = N * s - s + 1`` and pixel k at vertex ``k * s``.
        Gazebo Classic (ODE): ``size`` spans the first to the last vertex, ``size / (N - 1)`` per
        pixel, whatever the sampling.
        """
        n = self.side
        if simulator == GZ:
            vert = n * sampling - sampling + 1
            return self.resolution * vert / sampling
        if simulator == CLASSIC:
            return self.resolution * (n - 1)
        raise ValueError(f"simulator must be {GZ!r} or {CLASSIC!r}, got {simulator!r}")

    def ground_max(self, x: float, y: float, half: float) -> float:
        """The highest ground Gazebo builds from this image under the square of half-side
        ``half`` metres centred on map point (x, y): pixels scaled as Gazebo scales them
        (``v / v_max * z_range`` above ``z_min``), linear between pixel centres (metres)."""

        top = float(self.pixels.max())
        mid = (self.side - 1) / 2
        # Image order: column j at x = cx + (j - mid) r, row i at y = cy + (mid - i) r.
        row = mid - (y - self.centre[1]) / self.resolution
        col = (x - self.centre[0]) / self.resolution + mid
        gain = self.z_range / top if top > 0 else 0.0
        return ground_under(
            self.pixels, row, col, half / self.resolution, offset=self.z_min, gain=gain
        )

    def png(self) -> bytes:
        """The image as PNG bytes (8-bit or 16-bit greyscale), deterministic."""
        from PIL import Image

        buf = io.BytesIO()
        Image.fromarray(self.pixels).save(buf, format="PNG", compress_level=6)
        return buf.getvalue()


def heightmap_side(rows: int, cols: int) -> int:
    """The smallest 2^n + 1 (n >= 1) that holds ``rows x cols`` cells."""
    side = max(rows, cols, 2)
    return (1 << max(1, math.ceil(math.log2(side - 1)))) + 1


def make_heightmap(grid: HeightGrid, *, bit_depth: int = 8, pad_height: float = 0.0) -> Heightmap:
    """Pad ``grid`` (yaw 0) to a square 2^n + 1 canvas and quantise its heights.

    Unknown cells of ``grid`` (``known == False``) and the padding get ``pad_height``.
    """
    if grid.origin.yaw != 0.0:
        raise ValueError("grid must be axis-aligned (yaw 0); rotate it with grids.axis_align")
    if bit_depth not in (8, 16):
        raise ValueError(f"bit_depth must be 8 or 16, got {bit_depth}")
    rows, cols = grid.shape
    n = heightmap_side(rows, cols)
    left, bottom = (n - cols) // 2, (n - rows) // 2
    canvas = np.full((n, n), pad_height, dtype=np.float32)
    canvas[bottom : bottom + rows, left : left + cols] = np.where(
        grid.known, grid.heights, pad_height
    )

    z_min, z_range = height_scale(float(canvas.min()), float(canvas.max()))
    pixels = quantise(canvas, z_min, z_range, bit_depth)

    r = grid.resolution
    mid = (n - 1) // 2
    cx, cy = grid.origin.transform(
        np.array((mid - left + 0.5) * r), np.array((mid - bottom + 0.5) * r)
    )
    return Heightmap(
        pixels,
        r,
        (float(cx), float(cy)),
        z_min,
        z_range,
        (left, bottom),
        (rows, cols),
    )


def height_scale(lowest: float, highest: float) -> tuple[float, float]:
    """``(z_min, z_range)`` for heights in ``[lowest, highest]`` metres: 0 is at most the ground
    (``min(0, lowest)``) and full scale is ``highest``; a flat field gets a range of 1."""
    z_min = min(0.0, lowest)
    return z_min, (highest - z_min if highest > z_min else 1.0)


def quantise(
    canvas: NDArray[np.float32], z_min: float, z_range: float, bit_depth: int
) -> NDArray[np.uint8] | NDArray[np.uint16]:
    """Heights (metres, grid order) to pixel values in image order (row 0 = largest y).

    ``z_min`` becomes 0 and ``z_min + z_range`` full scale (255 or 65535), rounded to the
    nearest level. The same heights, ``z_min`` and ``z_range`` always give the same pixels, so
    samples shared by terrain tiles quantise alike.
    """
    # A flat field (every height at z_min, z_range 1) gets 0 everywhere: Gazebo then falls back
    # to a scale of 1 and the ground is at z_min.
    full = (1 << bit_depth) - 1
    levels = np.rint((canvas - np.float32(z_min)) * np.float32(full / z_range))
    dtype = np.uint16 if bit_depth == 16 else np.uint8
    return np.ascontiguousarray(np.flipud(levels).astype(dtype))
