"""Compiled per-point loops of the tiled column statistics (numba); see tiles.py.

A point's cell is ``(row, col) = (floor(y / r), floor(x / r))`` on the global lattice, computed as
the octree computes keys (``floor(coord * (1 / r))`` in double), so the columns are the octree's
voxel columns. Cells live in tiles of ``t x t``, t = 2^shift; tile ``(tr, tc) = (row >> shift,
col >> shift)`` (arithmetic shifts: floor division for negative cells too, at a third of its
cost).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

_JIT = {"nogil": True, "cache": True, "error_model": "numpy"}


@nb.njit(**_JIT)
def _usable(x: float, y: float, z: float, z_min: float, z_max: float) -> bool:
    return math.isfinite(x) and math.isfinite(y) and math.isfinite(z) and z_min <= z <= z_max


@nb.njit(**_JIT)
def extent(points, z_min, z_max):
    """(x_min, y_min, x_max, y_max, usable points) of the points in the z band."""
    x0 = y0 = np.inf
    x1 = y1 = -np.inf
    n = 0
    for i in range(points.shape[0]):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        if _usable(x, y, z, z_min, z_max):
            x0, x1 = min(x0, x), max(x1, x)
            y0, y1 = min(y0, y), max(y1, y)
            n += 1
    return x0, y0, x1, y1, n


@nb.njit(**_JIT)
def flag_tiles(points, inv_res, shift, z_min, z_max, tr0, tc0, flags):
    """flags[tr - tr0, tc - tc0] = 1 for every tile holding a usable point."""
    for i in range(points.shape[0]):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        if _usable(x, y, z, z_min, z_max):
            tr = np.int64(math.floor(y * inv_res)) >> shift
            tc = np.int64(math.floor(x * inv_res)) >> shift
            flags[tr - tr0, tc - tc0] = 1


@nb.njit(**_JIT)
def accumulate(points, inv_res, shift, z_min, z_max, sum_scale, tr0, tc0, slots, cells, cells32):
    """Add every usable point to its cell record ``cells[tile row, cell]``: count (int64 0),
    integer z sum (int64 1, ``floor(z * sum_scale + 0.5)``) and float32 min and max (float32
    words 4 and 5 of ``cells32``, the same memory). ``slots[tr - tr0, tc - tc0]`` is the row of
    the point's tile. min/max are only meaningful where count > 0: a cell's first point sets
    them, so the storage needs no fill. One 24-byte record per cell keeps a point's updates in
    one cache line (four separate arrays were 4x slower on unordered points)."""
    mask = (np.int64(1) << shift) - 1
    for i in range(points.shape[0]):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        if not _usable(x, y, z, z_min, z_max):
            continue
        row = np.int64(math.floor(y * inv_res))
        col = np.int64(math.floor(x * inv_res))
        s = slots[(row >> shift) - tr0, (col >> shift) - tc0]
        c = ((row & mask) << shift) | (col & mask)
        z32 = np.float32(z)
        n = cells[s, c, 0]
        if n == 0:
            cells32[s, c, 4] = z32
            cells32[s, c, 5] = z32
        else:
            if z32 < cells32[s, c, 4]:
                cells32[s, c, 4] = z32
            if z32 > cells32[s, c, 5]:
                cells32[s, c, 5] = z32
        cells[s, c, 0] = n + 1
        cells[s, c, 1] += np.int64(math.floor(z * sum_scale + 0.5))
