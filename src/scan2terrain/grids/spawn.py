"""Where a robot can start in a world: a level spot with room for it, near a preferred point.

The ground is the world's own height field in the map frame (walls at their height, floor at
its own): a spot is *level* when the ground under a square of ``FOOTPRINT`` metres a side (room
for a 1 x 1 m robot at any heading, with a margin) rises by no more than ``LEVEL_SLOPE`` across
it, and *free* when, where the caller knows it, every cell under it is known free space. The
chosen spot is the free, level cell nearest the preferred point, else the level one nearest,
else the most level one; ``z`` is the highest ground under the footprint.

Pure array work (scipy's separable min/max filters); searched first within ``NEAR`` metres of the
preferred point, the whole grid only when nothing there will do.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from scan2terrain.types import Pose2D, Spawn

#: Side of the square that must be level (metres): a 1 x 1 m robot turned any way fits in a
#: circle of radius 0.71 m; 1.5 m leaves it 4 cm each side.
FOOTPRINT = 1.5
#: Largest ground slope across the footprint, as rise over run (tan 2 degrees), and the smallest
#: rise always accepted (metres): heightmap quantisation and sensor noise on a flat floor.
LEVEL_SLOPE = math.tan(math.radians(2.0))
LEVEL_RISE = 0.02
#: The first search looks this far (metres) from the preferred point.
NEAR = 25.0


def find_spawn(
    heights: NDArray[np.floating],
    resolution: float,
    origin: Pose2D,
    *,
    preferred: tuple[float, float] | None = None,
    yaw: float = 0.0,
    ground: NDArray[np.bool_] | None = None,
    free: NDArray[np.bool_] | None = None,
    why: str = "",
) -> Spawn:
    """The spawn spot of a height field (``heights`` (H, W) metres, grid order: row 0 = lowest
    y; every cell a height, as the world has it).

    ``preferred`` is a map-frame point (None: the map origin when it lies on the grid, else the
    grid's centre); ``ground`` marks the cells a robot may stand on (None: all; walls are not),
    ``free`` those known to be free space (preferred; None: all ground). ``yaw`` is
    passed through; ``why`` (how the preferred point was chosen) starts the spawn's ``why``.
    """
    h = np.asarray(heights, dtype=np.float64)
    if h.ndim != 2 or h.size == 0:
        raise ValueError(f"heights must be a non-empty 2D array, got shape {h.shape}")
    rows, cols = h.shape
    r = float(resolution)
    if preferred is None:
        preferred, why = _default_point(rows, cols, r, origin)
    row, col = _cell_of(preferred, r, origin)
    # Windows never larger than the grid: at absurdly fine cells (1e-12 m) the footprint in
    # cells would overflow the filters' sizes.
    limit = max(rows, cols)
    half = max(1, math.ceil(min(FOOTPRINT / 2 / r, limit) + 0.5) - 1)
    near = max(half + 1, math.ceil(min(NEAR / r, limit)))
    window = (
        slice(max(0, min(row, rows - 1) - near), min(rows, max(row, 0) + near + 1)),
        slice(max(0, min(col, cols - 1) - near), min(cols, max(col, 0) + near + 1)),
    )
    ok = np.ones(h.shape, dtype=bool) if ground is None else np.asarray(ground, dtype=bool)
    pref = ok if free is None else ok & free
    (pr, pc), z, how = _search(h, ok, pref, half=half, r=r, row=row, col=col, part=window)
    if how != "free" and window != (slice(0, rows), slice(0, cols)):
        better = _search(
            h, ok, pref, half=half, r=r, row=row, col=col, part=(slice(0, rows), slice(0, cols))
        )
        if _RANK[better[2]] < _RANK[how]:
            (pr, pc), z, how = better
    if r > FOOTPRINT / 4:  # coarse cells: the surface between samples, not their maximum
        z = ground_under(h, pr, pc, FOOTPRINT / 2 / r)
    x, y = origin.transform(np.array((pc + 0.5) * r), np.array((pr + 0.5) * r))
    where = f"{why}: " if why else ""
    return Spawn(float(x), float(y), z, float(yaw), f"{where}{_HOW[how]}")


_RANK = {"free": 0, "level": 1, "flattest": 2}
_HOW = {
    "free": "the nearest free, level spot with room for a 1 x 1 m robot",
    "level": "the nearest level spot with room for a 1 x 1 m robot (no known free space there)",
    "flattest": "no level spot has room for a 1 x 1 m robot: the flattest one",
}


def _default_point(
    rows: int, cols: int, r: float, origin: Pose2D
) -> tuple[tuple[float, float], str]:
    c, s = math.cos(origin.yaw), math.sin(origin.yaw)
    # The map origin in grid-local metres.
    u = c * -origin.x + s * -origin.y
    v = -s * -origin.x + c * -origin.y
    if 0 <= u <= cols * r and 0 <= v <= rows * r:
        return (0.0, 0.0), "near the map origin"
    x, y = origin.transform(np.array(cols * r / 2), np.array(rows * r / 2))
    return (float(x), float(y)), "near the map's centre (the origin is off the map)"


def _cell_of(point: tuple[float, float], r: float, origin: Pose2D) -> tuple[int, int]:
    c, s = math.cos(origin.yaw), math.sin(origin.yaw)
    dx, dy = point[0] - origin.x, point[1] - origin.y
    u, v = c * dx + s * dy, -s * dx + c * dy
    return math.floor(v / r), math.floor(u / r)


def _search(
    whole: NDArray[np.float64],
    whole_ground: NDArray[np.bool_],
    whole_free: NDArray[np.bool_],
    *,
    half: int,
    r: float,
    row: int,
    col: int,
    part: tuple[slice, slice],
) -> tuple[tuple[int, int], float, str]:
    """The best cell of one part of the grid: ((row, col) in the whole grid, z, how)."""
    h = whole[part]
    ground, free = whole_ground[part], whole_free[part]
    size = 2 * half + 1
    top = square_filter(h, half, np.maximum)
    relief = top - square_filter(h, half, np.minimum)
    # Room: the footprint lies on the grid (cells nearer the border than ``half`` do not).
    inside = np.zeros(h.shape, dtype=bool)
    if h.shape[0] > 2 * half and h.shape[1] > 2 * half:
        inside[half:-half, half:-half] = True
    level = inside & (relief <= max(LEVEL_RISE, LEVEL_SLOPE * size * r))
    r0, c0 = part[0].start, part[1].start
    rr, cc = np.indices(h.shape)
    dist2 = (rr + r0 - row) ** 2 + (cc + c0 - col) ** 2

    def room(cells: NDArray[np.bool_]) -> NDArray[np.bool_]:
        under: NDArray[np.bool_] = square_filter(cells.view(np.uint8), half, np.minimum) > 0
        return under

    on_ground = room(ground)
    choices = [("free", level & room(free)), ("level", level & on_ground)]
    for how, ok in choices:
        if ok.any():
            flat = np.where(ok, dist2, np.iinfo(np.int64).max)
            i = int(np.argmin(flat))
            pr, pc = divmod(i, h.shape[1])
            return (pr + r0, pc + c0), float(top[pr, pc]), how
    candidates = inside & on_ground
    if not candidates.any():
        candidates = inside if inside.any() else np.ones(h.shape, dtype=bool)
    # Nothing level: the flattest spot, nearest among equals.
    key = np.where(candidates, relief, np.inf)
    best = key == key.min()
    i = int(np.argmin(np.where(best, dist2, np.iinfo(np.int64).max)))
    pr, pc = divmod(i, h.shape[1])
    return (pr + r0, pc + c0), float(top[pr, pc]), "flattest"


def ground_under(
    samples: NDArray[np.generic],
    row: float,
    col: float,
    half: float,
    *,
    offset: float = 0.0,
    gain: float = 1.0,
) -> float:
    """The highest ground under a square of half-side ``half`` (in samples) centred on the
    fractional sample position (``row``, ``col``) of a height field whose samples are
    ``offset + gain * samples`` (metres), linear between them as Gazebo's triangles are: the
    samples inside the square, and the surface sampled along and across it. Only the samples
    near the square are read (a heightmap may hold 16 M of them)."""
    n_rows, n_cols = samples.shape
    r_lo = max(0, min(n_rows - 1, math.floor(row - half)))
    r_hi = max(0, min(n_rows - 1, math.ceil(row + half)))
    c_lo = max(0, min(n_cols - 1, math.floor(col - half)))
    c_hi = max(0, min(n_cols - 1, math.ceil(col + half)))
    z = offset + gain * np.asarray(samples[r_lo : r_hi + 1, c_lo : c_hi + 1], dtype=np.float64)
    u = np.linspace(-half, half, 9)
    fr = np.clip(row + u[:, None] + 0 * u[None, :], r_lo, r_hi) - r_lo
    fc = np.clip(col + u[None, :] + 0 * u[:, None], c_lo, c_hi) - c_lo
    r0 = np.minimum(np.floor(fr).astype(np.intp), max(z.shape[0] - 2, 0))
    c0 = np.minimum(np.floor(fc).astype(np.intp), max(z.shape[1] - 2, 0))
    r1, c1 = np.minimum(r0 + 1, z.shape[0] - 1), np.minimum(c0 + 1, z.shape[1] - 1)
    a, b = fr - r0, fc - c0
    lerp = (z[r0, c0] * (1 - b) + z[r0, c1] * b) * (1 - a) + (
        z[r1, c0] * (1 - b) + z[r1, c1] * b
    ) * a
    # Samples inside the square: the surface's peaks are there.
    i_lo, i_hi = math.ceil(row - half) - r_lo, math.floor(row + half) - r_lo
    j_lo, j_hi = math.ceil(col - half) - c_lo, math.floor(col + half) - c_lo
    inside = z[max(i_lo, 0) : max(i_hi + 1, 0), max(j_lo, 0) : max(j_hi + 1, 0)]
    return float(max(lerp.max(), inside.max(initial=-math.inf)))


def square_filter(a: NDArray[Any], half: int, op: np.ufunc) -> NDArray[Any]:
    """``op`` (np.maximum or np.minimum) over the (2 half + 1)^2 window centred on each cell,
    cells beyond the grid left out: scipy.ndimage's maximum/minimum_filter with mode
    'nearest', in O(1) a cell (van Herk / Gil-Werman, per axis), without importing scipy
    (0.3 s, most of a small map2world's run)."""
    out = a
    for axis in (0, 1):
        out = _running(out, half, axis, op)
    return out


def _running(a: NDArray[Any], half: int, axis: int, op: np.ufunc) -> NDArray[Any]:
    size = 2 * half + 1
    n = a.shape[axis]
    if half == 0 or n == 0:
        return a
    moved = np.moveaxis(a, axis, 0)
    # Edge values beyond both ends (they are in every window reaching there anyway), then
    # enough more to fill whole blocks of ``size``.
    blocks = -(-(n + 2 * half) // size)
    extra = blocks * size - (n + 2 * half)
    padded = np.concatenate(
        [np.repeat(moved[:1], half, 0), moved, np.repeat(moved[-1:], half + extra, 0)]
    )
    shaped = padded.reshape(blocks, size, *moved.shape[1:])
    forward = op.accumulate(shaped, axis=1).reshape(padded.shape)
    backward = op.accumulate(shaped[:, ::-1], axis=1)[:, ::-1].reshape(padded.shape)
    # The window starting at j spans j .. j + size - 1: the rest of j's block, then the start
    # of the next block up to j + size - 1.
    out = op(backward[:n], forward[size - 1 : size - 1 + n])
    return np.moveaxis(out, 0, axis)
