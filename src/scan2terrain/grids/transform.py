"""Geometric operations on grid-ordered arrays (row 0 = lowest y), keeping georeferencing.

Each takes an array, its resolution and origin pose and returns the new array and origin, so the
same operations serve occupancy grids, height grids and grey images.
"""

from __future__ import annotations

import math
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from scan2terrain.types import Pose2D

A = TypeVar("A", bound=np.generic)


def canvas(
    data: NDArray[A],
    origin: Pose2D,
    resolution: float,
    *,
    width: int | None = None,
    height: int | None = None,
    offset_x: int = 0,
    offset_y: int = 0,
    fill: float | int = 0,
) -> tuple[NDArray[A], Pose2D]:
    """Crop or extend ``data`` to ``height x width`` cells, its cell (0, 0) at (offset_y, offset_x).

    Cells outside the input get ``fill``. The returned origin keeps every input cell at the same
    map-frame position (the paper's tool lost this).
    """
    h, w = data.shape
    out_w = w + offset_x if width is None else width
    out_h = h + offset_y if height is None else height
    if out_w <= 0 or out_h <= 0:
        raise ValueError(f"canvas of {out_w}x{out_h} cells is empty")
    out = np.full((out_h, out_w), fill, dtype=data.dtype)
    # Overlap of the input, placed at (offset_y, offset_x), with the canvas.
    r0, c0 = max(offset_y, 0), max(offset_x, 0)
    r1, c1 = min(offset_y + h, out_h), min(offset_x + w, out_w)
    if r1 > r0 and c1 > c0:
        out[r0:r1, c0:c1] = data[r0 - offset_y : r1 - offset_y, c0 - offset_x : c1 - offset_x]
    ox, oy = origin.transform(
        np.array(-offset_x * resolution, dtype=np.float64),
        np.array(-offset_y * resolution, dtype=np.float64),
    )
    return out, Pose2D(float(ox), float(oy), origin.yaw)


def axis_align(
    data: NDArray[A], origin: Pose2D, resolution: float, *, fill: float | int = 0
) -> tuple[NDArray[A], Pose2D]:
    """Resample a grid whose origin has a yaw onto a grid aligned with the map axes (yaw 0).

    Output cells take the value of the input cell under their centre (nearest neighbour); cells
    outside the input get ``fill``. For yaws that are multiples of 90 degrees this is an exact
    permutation of the cells; other yaws resample (each output cell is at most half a cell
    diagonal from the input cell whose value it takes).
    """
    if origin.yaw == 0.0:
        return data, origin
    h, w = data.shape
    c, s = math.cos(origin.yaw), math.sin(origin.yaw)
    # Snap tiny cos/sin so that multiples of 90 degrees give exact bounding boxes.
    c = 0.0 if abs(c) < 1e-12 else c
    s = 0.0 if abs(s) < 1e-12 else s
    cu = np.array([0.0, w, 0.0, w]) * resolution
    cv = np.array([0.0, 0.0, h, h]) * resolution
    xs = origin.x + c * cu - s * cv
    ys = origin.y + s * cu + c * cv
    x0, y0 = float(xs.min()), float(ys.min())
    out_w = max(1, round((float(xs.max()) - x0) / resolution))
    out_h = max(1, round((float(ys.max()) - y0) / resolution))
    # Cell centres of the output, back into the input's local frame.
    px = x0 + (np.arange(out_w) + 0.5) * resolution - origin.x
    py = y0 + (np.arange(out_h) + 0.5) * resolution - origin.y
    u = c * px[None, :] + s * py[:, None]
    v = -s * px[None, :] + c * py[:, None]
    col = np.floor(u / resolution).astype(np.int64)
    row = np.floor(v / resolution).astype(np.int64)
    inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
    out = np.full((out_h, out_w), fill, dtype=data.dtype)
    out[inside] = data[row[inside], col[inside]]
    return out, Pose2D(x0, y0, 0.0)


def upsample(data: NDArray[A], resolution: float, factor: int) -> tuple[NDArray[A], float]:
    """Each cell becomes ``factor x factor`` cells; returns the array and the new resolution."""
    if factor < 1:
        raise ValueError(f"factor must be >= 1, got {factor}")
    if factor == 1:
        return data, resolution
    return np.repeat(np.repeat(data, factor, axis=0), factor, axis=1), resolution / factor
