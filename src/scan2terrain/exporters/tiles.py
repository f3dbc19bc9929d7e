"""Height grids too big for one heightmap: square 2^n+1 terrain tiles placed edge to edge.

Gazebo takes one square 2^n+1 image per heightmap, and big images are slow or refused (gz-sim's
ogre2 keeps the whole field on the GPU). A grid with more than ``max_side`` samples along an axis
is cut into tiles instead. With ``S = max_side``, tile ``(i, j)`` holds the grid samples
``[i (S - 1), i (S - 1) + S)`` along rows and ``[j (S - 1), j (S - 1) + S)`` along columns: a
stride of ``S - 1``, so neighbouring tiles share one row or column of samples, Gazebo's surfaces
meet on those samples and there is no seam. Tile row 0 is the lowest y (grid order, like the
grid's own rows), tile column 0 the lowest x.

The last tiles along an axis hold fewer samples; they are padded at the far side (beyond the
grid, where no other tile is) up to the smallest 2^n+1 square that holds them, at most ``S``.
Every tile is quantised with the same ``z_min`` and ``z_range`` (those of the whole grid), so a
shared sample has the same pixel value in both tiles. Gazebo scales each image to its own
brightest pixel, so each tile's ``size.z`` (:attr:`Heightmap.z_range`) is the height of that
pixel, and equal pixel values give equal heights in every tile. The two lowest levels (0 and 1)
are left unused, so that no tile holds a pixel of value 1, which gz-common mistakes for white
when it looks for the brightest pixel (see :func:`make_tiled_heightmap`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from scan2terrain.exporters.heightmap import Heightmap, height_scale, heightmap_side, quantise
from scan2terrain.types import HeightGrid, Pose2D


@dataclass(frozen=True)
class TileSpec:
    """Which grid samples one tile holds.

    ``row``, ``col``: the tile's index (row 0 = lowest y); ``r0``, ``c0``: its first grid sample
    (row, column); ``rows``, ``cols``: how many grid samples it holds; ``side``: its image side
    (2^n+1 >= rows, cols; the rest is padding beyond the grid).
    """

    row: int
    col: int
    r0: int
    c0: int
    rows: int
    cols: int
    side: int


def tile_counts(shape: tuple[int, int], max_side: int) -> tuple[int, int]:
    """Tiles along rows and columns for a grid of ``shape`` samples, ``max_side`` per tile."""
    _check_side(max_side)
    stride = max_side - 1
    return (
        max(1, math.ceil((shape[0] - 1) / stride)),
        max(1, math.ceil((shape[1] - 1) / stride)),
    )


def tile_specs(shape: tuple[int, int], max_side: int) -> list[TileSpec]:
    """Every tile of a grid of ``shape`` samples, row by row from the lowest y.

    Tile ``(i, j)`` starts at sample ``(i (S - 1), j (S - 1))`` and holds up to ``S`` samples
    each way, ``S = max_side`` (2^n+1): neighbours share their border samples.
    """
    n_rows, n_cols = tile_counts(shape, max_side)
    stride = max_side - 1
    specs = []
    for i in range(n_rows):
        for j in range(n_cols):
            r0, c0 = i * stride, j * stride
            rows = min(max_side, shape[0] - r0)
            cols = min(max_side, shape[1] - c0)
            specs.append(TileSpec(i, j, r0, c0, rows, cols, heightmap_side(rows, cols)))
    return specs


def _check_side(max_side: int) -> None:
    if max_side < 3 or (max_side - 1) & (max_side - 2) != 0:
        raise ValueError(f"max_side must be 2^n+1 >= 3, got {max_side}")


@dataclass(frozen=True)
class TiledHeightmap:
    """A height grid as terrain tiles sharing their border samples; :meth:`tiles` makes them.

    Attributes
    ----------
    heights : float32 array (H, W)
        Grid order (row 0 = lowest y), metres, every sample known (unknown ones already set to
        the padding height).
    resolution : float
        Metres between neighbouring samples.
    origin : Pose2D
        Lower-left corner of sample (0, 0), yaw 0 (rotate with ``grids.axis_align`` first).
    max_side : int
        ``terrain.max_side``: the largest tile side (2^n+1) and the stride plus one.
    bit_depth : int
        8 or 16.
    pad_height : float
        Height of the padding of the last tiles (beyond the grid), metres.
    z_min, z_range : float
        Height of a 0 pixel and of a full-scale one above it, for every tile, metres.
    span : float
        What one heightmap's ``size.z`` would be: the highest height minus ``min(0, lowest)``
        (1 when flat), metres; ``z_range`` adds the two unused levels below.
    z_offset : float
        Metres from ``heights`` to world heights: a sample of height h is placed at
        ``h + z_offset`` (``z_min`` is already a world height; dem2world gives heights above the
        lowest elevation and raises them by it with :meth:`raised`).
    """

    heights: NDArray[np.float32]
    resolution: float
    origin: Pose2D
    max_side: int
    bit_depth: int
    pad_height: float
    z_min: float
    z_range: float
    span: float
    z_offset: float = 0.0

    def raised(self, dz: float) -> TiledHeightmap:
        """The same tiles placed ``dz`` metres higher (pixels unchanged)."""
        return dataclasses.replace(self, z_min=self.z_min + dz, z_offset=self.z_offset + dz)

    @property
    def grid_shape(self) -> tuple[int, int]:
        return (int(self.heights.shape[0]), int(self.heights.shape[1]))

    @property
    def shape(self) -> tuple[int, int]:
        """Tiles along rows (y) and columns (x)."""
        return tile_counts(self.grid_shape, self.max_side)

    @property
    def side(self) -> int:
        """The largest tile side, pixels (``max_side`` unless every tile is smaller)."""
        return max(spec.side for spec in self.specs())

    def specs(self) -> list[TileSpec]:
        return tile_specs(self.grid_shape, self.max_side)

    def tile(self, spec: TileSpec) -> Heightmap:
        """One tile as a heightmap, placed so its pixel k is on grid sample ``(r0 + k, c0 + k)``.

        ``centre`` is the map-frame position of its pixel ``(side - 1) / 2``; ``z_range`` is the
        height of its brightest pixel above ``z_min`` (the whole terrain's range when the tile
        is flat at ``z_min``).
        """
        n = spec.side
        canvas = np.full((n, n), self.pad_height, dtype=np.float32)
        canvas[: spec.rows, : spec.cols] = self.heights[
            spec.r0 : spec.r0 + spec.rows, spec.c0 : spec.c0 + spec.cols
        ]
        pixels = quantise(canvas, self.z_min - self.z_offset, self.z_range, self.bit_depth)
        brightest = int(pixels.max())
        full = (1 << self.bit_depth) - 1
        size_z = self.z_range * brightest / full if brightest > 0 else self.z_range
        r, mid = self.resolution, (n - 1) // 2
        cx, cy = self.origin.transform(
            np.array((spec.c0 + mid + 0.5) * r), np.array((spec.r0 + mid + 0.5) * r)
        )
        return Heightmap(
            pixels, r, (float(cx), float(cy)), self.z_min, size_z, (0, 0), (spec.rows, spec.cols)
        )

    def tiles(self) -> Iterator[tuple[TileSpec, Heightmap]]:
        """Every tile, row by row from the lowest y, built one at a time (memory: one tile)."""
        for spec in self.specs():
            yield spec, self.tile(spec)


def make_tiled_heightmap(
    grid: HeightGrid, *, max_side: int, bit_depth: int = 8, pad_height: float = 0.0
) -> TiledHeightmap:
    """Cut ``grid`` (yaw 0) into terrain tiles of at most ``max_side`` samples a side.

    Unknown cells of ``grid`` and the padding of the last tiles get ``pad_height``. Full scale
    is the highest height, the padding included, as in :func:`.heightmap.make_heightmap`, and
    ``min(0, lowest)`` is level 2 (not 0: levels 0 and 1 are left unused), unless every height
    is that one (then every pixel is 0 and ``z_range`` is 1).
    """
    if grid.origin.yaw != 0.0:
        raise ValueError("grid must be axis-aligned (yaw 0); rotate it with grids.axis_align")
    if bit_depth not in (8, 16):
        raise ValueError(f"bit_depth must be 8 or 16, got {bit_depth}")
    _check_side(max_side)
    heights = grid.heights.astype(np.float32, copy=False)
    if not bool(grid.known.all()):
        heights = np.where(grid.known, heights, np.float32(pad_height)).astype(np.float32)
    lowest, highest = float(heights.min()), float(heights.max())
    if any(s.side > s.rows or s.side > s.cols for s in tile_specs(grid.shape, max_side)):
        pad = float(np.float32(pad_height))
        lowest, highest = min(lowest, pad), max(highest, pad)
    z_min, z_range = height_scale(lowest, highest)
    span = z_range
    if highest > z_min:
        # Levels 0 and 1 stay unused (every sample is at level >= 2). Gazebo finds a tile's
        # brightest pixel with gz-common's Image::MaxColor, which stores a grey byte v as
        # Color(v, v, v), and gz-math's Color scales a value above 1 by 1/255 but keeps a 1 as
        # 1.0 (white): a tile holding a pixel of value 1 would be scaled as if its brightest
        # pixel were full scale (seen with Debian's gz-common 4.5.1 through the test harness).
        # Without 0s and 1s every reading of a tile's brightest pixel agrees. Cost: the levels
        # are (range / (full - 2)) apart instead of (range / full).
        full = (1 << bit_depth) - 1
        step = z_range / (full - 2)
        z_min, z_range = z_min - 2 * step, z_range + 2 * step
    return TiledHeightmap(
        heights, grid.resolution, grid.origin, max_side, bit_depth, pad_height, z_min, z_range, span
    )


#: The ground of a heightmap world: one heightmap, or tiles when the grid is too big for one.
Terrain = Heightmap | TiledHeightmap
