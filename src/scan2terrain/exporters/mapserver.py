"""Occupancy grids back to map_server maps (YAML + PGM), as nav2's map_saver writes them.

A map wider or taller than ``output.map_max_side`` cells is written as tiles (:func:`map_tiles`):
they partition the cells (no overlap), and each tile's YAML origin is the map-frame pose of its
own lower-left cell, so map_server places every tile exactly where its cells were.
"""

from __future__ import annotations

import io

import numpy as np
from numpy.typing import NDArray

from scan2terrain.types import FREE, OCCUPIED, OccupancyGrid, Pose2D

#: map_saver's trinary shades.
SHADE_FREE, SHADE_OCCUPIED, SHADE_UNKNOWN = 254, 0, 205


def map_pgm(grid: OccupancyGrid) -> bytes:
    """The grid as a binary PGM in map_saver's trinary shades (free 254, occupied 0, unknown 205).

    Values strictly between free and occupied are written as unknown, as map_saver does with its
    default thresholds.
    """
    from PIL import Image

    shades = trinary_shades(grid.data)
    buf = io.BytesIO()
    Image.fromarray(np.flipud(shades)).save(buf, format="PPM")  # mode L -> P5 PGM
    return buf.getvalue()


def trinary_shades(data: NDArray[np.int8]) -> NDArray[np.uint8]:
    shades = np.full(data.shape, SHADE_UNKNOWN, dtype=np.uint8)
    shades[data == FREE] = SHADE_FREE
    shades[data == OCCUPIED] = SHADE_OCCUPIED
    return shades


def map_yaml(grid: OccupancyGrid, image_name: str, *, comment: str = "") -> bytes:
    """A map_server YAML for ``image_name`` written by :func:`map_pgm`.

    The thresholds are ROS1 map_saver's 0.65/0.196, not nav2's 0.65/0.25: with 0.25, map_server
    reads the unknown shade 205 (occupancy 0.196) back as free.
    """
    o = grid.origin
    lines = [f"# {line}" for line in comment.splitlines()] + [
        f"image: {image_name}",
        "mode: trinary",
        f"resolution: {grid.resolution!r}",
        f"origin: [{round(o.x, 9)!r}, {round(o.y, 9)!r}, {round(o.yaw, 9)!r}]",
        "negate: 0",
        "occupied_thresh: 0.65",
        "free_thresh: 0.196",
    ]
    return ("\n".join(lines) + "\n").encode()


def map_tiles(grid: OccupancyGrid, max_side: int) -> list[tuple[int, int, OccupancyGrid]]:
    """``grid`` cut into tiles of at most ``max_side`` x ``max_side`` cells: ``(row, col, tile)``.

    Tile ``(i, j)`` holds rows ``[i M, (i + 1) M)`` and columns ``[j M, (j + 1) M)`` (``M =
    max_side``, the last ones fewer); row 0 is the lowest y, as in the grid. Each tile's origin
    is the pose of its cell (0, 0)'s lower-left corner: the grid's origin moved along the grid's
    own axes (its yaw kept). A grid that fits is one tile ``(0, 0, grid)``.
    """
    if max_side < 1:
        raise ValueError(f"max_side must be >= 1, got {max_side}")
    rows, cols = grid.shape
    if rows <= max_side and cols <= max_side:
        return [(0, 0, grid)]
    r, o = grid.resolution, grid.origin
    out = []
    for i in range(-(-rows // max_side)):
        for j in range(-(-cols // max_side)):
            r0, c0 = i * max_side, j * max_side
            x, y = o.transform(np.array(c0 * r), np.array(r0 * r))
            data = np.ascontiguousarray(grid.data[r0 : r0 + max_side, c0 : c0 + max_side])
            out.append((i, j, grid.with_data(data, Pose2D(float(x), float(y), o.yaw))))
    return out
