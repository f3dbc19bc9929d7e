"""Where a robot can start in a world: a level spot with room for it, near a preferred point.

The ground is the world's own height field in the map frame (walls at their height, floor at
its own): a spot is *level* when the ground under a square of ``FOOTPRINT`` metres a side (room
for a 1 x 1 m robot at any heading, with a margin) rises by no more than ``LEVEL_SLOPE`` across
it, and *free* when, where the caller knows it, every cell under it is known free space. The
chosen spot is the free, level cell nearest the preferred point, else the level one nearest
(on the ground the world has around the grid too, :class:`Around`: a walls world's slab, a
heightmap's padding), else the most level spot of ground; ``z`` is the highest ground under the
footprint. Where no ground has room at all (a grid smaller than the robot, or all walls), the
spot is the flattest one anyway and its ``why`` says there is no ground and why
(``Spawn.ground`` is False).

Cells or samples: a walls world's cell is a flat square, so the square may reach the edge of
a wall cell; a heightmap's cell is a sample Gazebo interpolates to its neighbours, so a wall
sample raises the ground up to the next sample, and the square must keep off that slope
(``samples=True``: the samples under the square reach one more sample out when the square
ends between two).

Pure array work (separable min/max filters); searched first within ``NEAR`` metres of the
preferred point, the whole grid only when nothing there will do.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
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
#: At most this many cells of the ground around a grid are searched each side (enough for the
#: footprint down to 1.5 mm cells; finer grids are searched on themselves only).
AROUND_MAX = 1024


@dataclass(frozen=True)
class Around:
    """Level ground the world has beyond the grid, at ``height`` metres: ``cells`` of it
    (left, bottom, right, top: columns before column 0, rows before row 0, columns after the
    last, rows after the last), in the grid's own axes and cells. Never known free space."""

    cells: tuple[int, int, int, int]
    height: float


def find_spawn(  # noqa: PLR0913 (the height grid's layers, each an argument)
    heights: NDArray[np.floating],
    resolution: float,
    origin: Pose2D,
    *,
    preferred: tuple[float, float] | None = None,
    yaw: float = 0.0,
    ground: NDArray[np.bool_] | None = None,
    free: NDArray[np.bool_] | None = None,
    why: str = "",
    samples: bool = False,
    around: Around | None = None,
) -> Spawn:
    """The spawn spot of a height field (``heights`` (H, W) metres, grid order: row 0 = lowest
    y; every cell a height, as the world has it).

    ``preferred`` is a map-frame point (None: the map origin when it lies on the grid, else the
    grid's centre); ``ground`` marks the cells a robot may stand on (None: all; walls are not),
    ``free`` those known to be free space (preferred; None: all ground). ``yaw`` is
    passed through; ``why`` (how the preferred point was chosen) starts the spawn's ``why``.
    ``samples``: the heights are samples Gazebo interpolates between (a heightmap), not flat
    cells (see the module docstring). ``around``: the ground beyond the grid, searched too.
    """
    h = np.asarray(heights, dtype=np.float64)
    if h.ndim != 2 or h.size == 0:
        raise ValueError(f"heights must be a non-empty 2D array, got shape {h.shape}")
    r = float(resolution)
    if preferred is None:
        preferred, why = _default_point(h.shape[0], h.shape[1], r, origin)
    ok = np.ones(h.shape, dtype=bool) if ground is None else np.asarray(ground, dtype=bool)
    pref = ok if free is None else ok & free
    if around is not None:
        left, bottom, right, top = (min(max(n, 0), AROUND_MAX) for n in around.cells)
        around = Around((left, bottom, right, top), around.height)
    # Windows never larger than the grid (and the ground around it): at absurdly fine cells
    # (1e-12 m) the footprint in cells would overflow the filters' sizes.
    limit = max(h.shape) + (0 if around is None else 2 * max(around.cells))
    reach = min(FOOTPRINT / 2 / r, limit)
    half = max(1, math.ceil(reach) if samples else math.ceil(reach + 0.5) - 1)
    row, col = _cell_of(preferred, r, origin)
    core = (slice(0, h.shape[0]), slice(0, h.shape[1]))  # the grid itself
    if around is not None:
        h, ok, pref, origin, core = _widen(
            h, ok=ok, pref=pref, origin=origin, r=r, around=around, half=half, cell=(row, col)
        )
        row, col = row + core[0].start, col + core[1].start
    rows, cols = h.shape
    near = max(half + 1, math.ceil(min(NEAR / r, max(rows, cols))))
    window = (
        slice(max(0, min(row, rows - 1) - near), min(rows, max(row, 0) + near + 1)),
        slice(max(0, min(col, cols - 1) - near), min(cols, max(col, 0) + near + 1)),
    )
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
    on_grid = all(
        c.start <= i - half and i + half < c.stop for i, c in zip((pr, pc), core, strict=True)
    )
    if how in _HOW:
        text = _BESIDE if how == "level" and not on_grid else _HOW[how]
    else:
        text = _none(how, h.shape, r, samples)
    where = f"{why}: " if why else ""
    return Spawn(float(x), float(y), z, float(yaw), f"{where}{text}", ground=how in _GROUND)


def _widen(
    h: NDArray[np.float64],
    *,
    ok: NDArray[np.bool_],
    pref: NDArray[np.bool_],
    origin: Pose2D,
    r: float,
    around: Around,
    half: int,
    cell: tuple[int, int],
) -> tuple[NDArray[np.float64], NDArray[np.bool_], NDArray[np.bool_], Pose2D, tuple[slice, slice]]:
    """The grid with the ground around it (level, ground, never known free), its origin, and
    where the grid lies in it. Only as much of that ground as a spot can need: a square just
    off the edge (2 half + 1 cells), or out to the preferred ``cell`` (row, column of the grid)
    when that lies beyond it."""
    row, col = cell
    rows, cols = h.shape
    beyond = (-col, -row, col - cols + 1, row - rows + 1)  # how far out the point lies
    left, bottom, right, top = (
        max(0, min(n, 2 * half + 2 + max(0, b))) for n, b in zip(around.cells, beyond, strict=True)
    )
    width = ((bottom, top), (left, right))
    x0, y0 = origin.transform(np.array(-left * r), np.array(-bottom * r))
    return (
        np.pad(h, width, constant_values=around.height),
        np.pad(ok, width, constant_values=True),
        np.pad(pref, width, constant_values=False),
        Pose2D(float(x0), float(y0), origin.yaw),
        (slice(bottom, bottom + rows), slice(left, left + cols)),
    )


_RANK = {"free": 0, "level": 1, "flattest": 2, "walled": 3, "small": 4}
#: The ranks that stand on ground (not on a wall or an obstacle).
_GROUND = ("free", "level", "flattest")
_HOW = {
    "free": "the nearest free, level spot with room for a 1 x 1 m robot",
    "level": "the nearest level spot with room for a 1 x 1 m robot (no known free space there)",
    "flattest": "no level spot has room for a 1 x 1 m robot: the flattest one",
}
_BESIDE = (
    "no free, level spot on the map has room for a 1 x 1 m robot: the nearest level spot"
    " reaching beyond its edge, on the ground the world has around it"
)


def _none(how: str, shape: tuple[int, int], r: float, samples: bool) -> str:
    """Why no ground has room for the robot ("small": no square fits; "walled": each touches
    an obstacle), and where the spot is instead."""
    if how == "small":
        size = f"{shape[1] * r:g} x {shape[0] * r:g} m"
        because = (
            f"the world's ground is {size}, smaller than the {FOOTPRINT:g} m square a robot"
            " needs, with no ground around it"
        )
    else:
        because = (
            f"every {FOOTPRINT:g} m square of the world touches something above its floor (a"
            " wall, an obstacle, raised unknown ground)"
        )
        if samples:
            because += ", or the slope Gazebo makes up to one, a sample wide"
    return (
        f"no ground has room for a 1 x 1 m robot: {because}; this is the flattest spot, on"
        " an obstacle"
    )


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
    candidates, how = inside & on_ground, "flattest"
    if not candidates.any():
        candidates, how = (inside, "walled") if inside.any() else (np.ones(h.shape, bool), "small")
    # Nothing level: the flattest spot, nearest among equals.
    key = np.where(candidates, relief, np.inf)
    best = key == key.min()
    i = int(np.argmin(np.where(best, dist2, np.iinfo(np.int64).max)))
    pr, pc = divmod(i, h.shape[1])
    return (pr + r0, pc + c0), float(top[pr, pc]), how


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
