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
        Height of a full-scale pixel above ``z_min`` (SDF ``size.z``), metres.
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

    z_min = min(0.0, float(canvas.min()))
    z_max = float(canvas.max())
    full = (1 << bit_depth) - 1
    if z_max > z_min:
        z_range = z_max - z_min
        levels = np.rint((canvas - np.float32(z_min)) * np.float32(full / z_range))
    else:  # flat: every pixel 0, Gazebo falls back to a scale of 1 and the ground is at z_min
        z_range = 1.0
        levels = np.zeros_like(canvas)
    pixels = np.flipud(levels).astype(np.uint16 if bit_depth == 16 else np.uint8)

    r = grid.resolution
    mid = (n - 1) // 2
    cx, cy = grid.origin.transform(
        np.array((mid - left + 0.5) * r), np.array((mid - bottom + 0.5) * r)
    )
    return Heightmap(
        np.ascontiguousarray(pixels),
        r,
        (float(cx), float(cy)),
        z_min,
        z_range,
        (left, bottom),
        (rows, cols),
    )
