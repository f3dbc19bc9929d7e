"""Occupancy grids back to map_server maps (YAML + PGM), as nav2's map_saver writes them."""

from __future__ import annotations

import io

import numpy as np
from numpy.typing import NDArray

from scan2terrain.types import FREE, OCCUPIED, OccupancyGrid

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
