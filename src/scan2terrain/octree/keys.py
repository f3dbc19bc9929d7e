"""OctoMap's voxel keys: 16 bits per axis, ``key = floor(coord / resolution) + KEY_OFFSET``.

The one place the key convention is written down; the octree, ``.bt`` files, the grid projection
and the pipeline all use it. :func:`coord_cell` is the rule that puts a coordinate in a cell, for
every path (the octree's kernels, the streamed tiles' kernels).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

#: Key of the voxel holding coordinate 0 (OctoMap's tree_max_val): the map spans
#: +-KEY_OFFSET * resolution.
KEY_OFFSET = 32768


def key_to_coord(
    keys: NDArray[np.integer] | NDArray[np.floating], resolution: float
) -> NDArray[np.float64]:
    """Voxel centres of ``keys`` (any shape), metres: ``(key - KEY_OFFSET + 0.5) * resolution``."""
    return (np.asarray(keys, dtype=np.float64) - KEY_OFFSET + 0.5) * resolution


def coord_cell(coord: float, inv_res: float) -> int:
    """The cell of a coordinate (metres) on the lattice of ``1 / inv_res`` m cells, the key less
    KEY_OFFSET: OctoMap's ``coordToKey`` of a float ``point3d``, ``floor(double(float32(coord)) *
    (1.0 / resolution))`` (``inv_res`` must be computed as ``1.0 / resolution`` in double).

    The coordinate is rounded to float32 first, as the octree stores points, so a point within a
    float32 rounding of a cell edge lands where the octree puts it, on every path. Plain Python,
    also compiled into numba kernels (grids/_tile_kernels.py); the key range is not checked.
    """
    cell: int = math.floor(np.float64(np.float32(coord)) * inv_res)
    return cell


def in_key_range(points: NDArray[np.floating], resolution: float) -> NDArray[np.bool_]:
    """Which points (N, 3) the octree holds: every coordinate's cell (:func:`coord_cell`) within
    the key range, ``-KEY_OFFSET <= cell < KEY_OFFSET`` (OctoMap's ``coordToKeyChecked``);
    NaN and inf are not. bool (N,)."""
    with np.errstate(invalid="ignore", over="ignore"):
        cells = np.floor(
            np.asarray(points, dtype=np.float32).astype(np.float64) * (1.0 / resolution)
        )
        inside = (cells >= -KEY_OFFSET) & (cells < KEY_OFFSET)
    return np.asarray(inside.all(axis=1))
