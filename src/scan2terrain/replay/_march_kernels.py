"""Beams marched through a 2D occupancy grid (numba): the distance to the first occupied cell."""

from __future__ import annotations

import numpy as np

from scan2terrain._numba import numba as nb


@nb.njit(cache=True, nogil=True)
def first_hits(
    occupied: np.ndarray,  # bool (H, W)
    ox: np.ndarray,  # float64 (N,) beam origins, cells
    oy: np.ndarray,
    dx: np.ndarray,  # unit directions
    dy: np.ndarray,
    reach: np.ndarray,  # cells: march no farther
    step: float,  # cells per sample
) -> np.ndarray:
    """Distance (cells) along each beam to the first occupied cell, -1 when none within
    ``reach``. The beam's first cell (the sensor's) is skipped."""
    h, w = occupied.shape
    out = np.full(ox.size, -1.0)
    for i in range(ox.size):
        start_x, start_y = int(np.floor(ox[i])), int(np.floor(oy[i]))
        d = step
        while d <= reach[i]:
            x = int(np.floor(ox[i] + dx[i] * d))
            y = int(np.floor(oy[i] + dy[i] * d))
            if not (0 <= x < w and 0 <= y < h):
                break
            if (x != start_x or y != start_y) and occupied[y, x]:
                out[i] = d
                break
            d += step
    return out
