"""find_spawn searches band by band, the ground around the grid read where needed (issue 31):
exactly the spots of the whole-grid search, in memory of a band, not of copies of the grid."""

from __future__ import annotations

import math
import tracemalloc
from typing import NamedTuple

import numpy as np
import pytest
from numpy.typing import NDArray

from scan2terrain.grids import spawn as sp
from scan2terrain.grids.spawn import Around, find_spawn, ground_under, square_filter
from scan2terrain.types import Pose2D, Spawn


def old_search(
    h: NDArray[np.float64],
    ground: NDArray[np.bool_],
    free: NDArray[np.bool_],
    half: int,
    r: float,
    row: int,
    col: int,
    part: tuple[slice, slice],
) -> tuple[tuple[int, int], float, str]:
    """The whole-part search find_spawn had (filters over the part at once)."""
    h, ground, free = h[part], ground[part], free[part]
    top = square_filter(h, half, np.maximum)
    relief = top - square_filter(h, half, np.minimum)
    inside = np.zeros(h.shape, dtype=bool)
    if h.shape[0] > 2 * half and h.shape[1] > 2 * half:
        inside[half:-half, half:-half] = True
    level = inside & (relief <= max(sp.LEVEL_RISE, sp.LEVEL_SLOPE * (2 * half + 1) * r))
    rr, cc = np.indices(h.shape)
    dist2 = (rr + part[0].start - row) ** 2 + (cc + part[1].start - col) ** 2

    def room(cells: NDArray[np.bool_]) -> NDArray[np.bool_]:
        out: NDArray[np.bool_] = square_filter(cells.view(np.uint8), half, np.minimum) > 0
        return out

    big = np.iinfo(np.int64).max
    for how, ok in (("free", level & room(free)), ("level", level & room(ground))):
        if ok.any():
            pr, pc = divmod(int(np.argmin(np.where(ok, dist2, big))), h.shape[1])
            return (pr + part[0].start, pc + part[1].start), float(top[pr, pc]), how
    cands, how = inside & room(ground), "flattest"
    if not cands.any():
        cands, how = (inside, "walled") if inside.any() else (np.ones(h.shape, bool), "small")
    key = np.where(cands, relief, np.inf)
    i = int(np.argmin(np.where(key == key.min(), dist2, big)))
    pr, pc = divmod(i, h.shape[1])
    return (pr + part[0].start, pc + part[1].start), float(top[pr, pc]), how


def old_find_spawn(
    heights: NDArray[np.float64],
    r: float,
    origin: Pose2D,
    preferred: tuple[float, float] | None,
    ground: NDArray[np.bool_] | None,
    free: NDArray[np.bool_] | None,
    samples: bool,
    around: Around | None,
) -> Spawn:
    """find_spawn as it was: the grid widened by np.pad, each part searched whole."""
    h = np.asarray(heights, dtype=np.float64)
    why = ""
    if preferred is None:
        preferred, why = sp._default_point(h.shape[0], h.shape[1], r, origin)
    ok = np.ones(h.shape, bool) if ground is None else np.asarray(ground, bool)
    pref = ok if free is None else ok & free
    if around is not None:
        around = Around(tuple(min(max(n, 0), sp.AROUND_MAX) for n in around.cells), around.height)  # type: ignore[arg-type]
    limit = max(h.shape) + (0 if around is None else 2 * max(around.cells))
    reach = min(sp.FOOTPRINT / 2 / r, limit)
    half = max(1, math.ceil(reach) if samples else math.ceil(reach + 0.5) - 1)
    row, col = sp._cell_of(preferred, r, origin)
    core = (slice(0, h.shape[0]), slice(0, h.shape[1]))
    if around is not None:
        rows, cols = h.shape
        beyond = (-col, -row, col - cols + 1, row - rows + 1)
        left, bottom, right, top = (
            max(0, min(n, 2 * half + 2 + max(0, b)))
            for n, b in zip(around.cells, beyond, strict=True)
        )
        width = ((bottom, top), (left, right))
        x0, y0 = origin.transform(np.array(-left * r), np.array(-bottom * r))
        h = np.pad(h, width, constant_values=around.height)
        ok, pref = (
            np.pad(ok, width, constant_values=True),
            np.pad(pref, width, constant_values=False),
        )
        origin = Pose2D(float(x0), float(y0), origin.yaw)
        core = (slice(bottom, bottom + rows), slice(left, left + cols))
        row, col = row + bottom, col + left
    rows, cols = h.shape
    near = max(half + 1, math.ceil(min(sp.NEAR / r, max(rows, cols))))
    window = (
        slice(max(0, min(row, rows - 1) - near), min(rows, max(row, 0) + near + 1)),
        slice(max(0, min(col, cols - 1) - near), min(cols, max(col, 0) + near + 1)),
    )
    (pr, pc), z, how = old_search(h, ok, pref, half, r, row, col, window)
    whole = (slice(0, rows), slice(0, cols))
    if how != "free" and window != whole:
        better = old_search(h, ok, pref, half, r, row, col, whole)
        if sp._RANK[better[2]] < sp._RANK[how]:
            (pr, pc), z, how = better
    if r > sp.FOOTPRINT / 4:
        z = ground_under(h, pr, pc, sp.FOOTPRINT / 2 / r)
    x, y = origin.transform(np.array((pc + 0.5) * r), np.array((pr + 0.5) * r))
    on_grid = all(
        c.start <= i - half and i + half < c.stop for i, c in zip((pr, pc), core, strict=True)
    )
    if how in sp._HOW:
        text = sp._BESIDE if how == "level" and not on_grid else sp._HOW[how]
    else:
        text = sp._none(how, h.shape, r, samples)
    return Spawn(
        float(x), float(y), z, 0.0, f"{why}: {text}" if why else text, ground=how in sp._GROUND
    )


def random_case(seed: int) -> Case:
    rng = np.random.default_rng(seed)
    shape = (int(rng.integers(1, 60)), int(rng.integers(1, 60)))
    r = float(rng.choice([0.05, 0.1, 0.3, 0.5, 2.0]))
    kind = seed % 3
    if kind == 0:  # walls on a floor
        walls = rng.random(shape) < rng.random() * 0.5
        heights = np.where(walls, 2.0, 0.0)
        ground, free = ~walls, (~walls) & (rng.random(shape) < 0.9)
    elif kind == 1:  # rough terrain, quantised so ties happen
        heights = np.round(rng.normal(0, 0.02, shape).cumsum(axis=0), 2)
        ground, free = None, None
    else:  # a few levels, ground where low
        heights = rng.choice([0.0, 0.01, 0.5], size=shape)
        ground, free = heights < 0.4, None
    origin = Pose2D(
        float(rng.uniform(-3, 3)), float(rng.uniform(-3, 3)), float(rng.uniform(-1, 1)) * (seed % 2)
    )
    preferred = (
        None if rng.random() < 0.3 else (float(rng.uniform(-5, 5)), float(rng.uniform(-5, 5)))
    )
    cells = tuple(int(n) for n in rng.integers(0, 40, 4))
    around = None if rng.random() < 0.4 else Around(cells, float(rng.choice([0.0, 0.3])))  # type: ignore[arg-type]
    samples = bool(rng.random() < 0.5)
    return Case(heights, r, origin, preferred, ground, free, samples, around)


class Case(NamedTuple):
    heights: NDArray[np.float64]
    r: float
    origin: Pose2D
    preferred: tuple[float, float] | None
    ground: NDArray[np.bool_] | None
    free: NDArray[np.bool_] | None
    samples: bool
    around: Around | None


def check(case: Case) -> None:
    got = find_spawn(
        case.heights, case.r, case.origin, preferred=case.preferred, ground=case.ground,
        free=case.free, samples=case.samples, around=case.around,
    )  # fmt: skip
    want = old_find_spawn(*case)
    assert repr(got) == repr(want)  # NaN heights give a NaN z on both


@pytest.mark.parametrize("seed", range(150))
def test_random_grids_give_the_whole_grid_spot(seed: int, monkeypatch: pytest.MonkeyPatch) -> None:
    case = random_case(seed)
    check(case)
    # Bands of a few rows: many band edges, halos cut at the part's edges.
    monkeypatch.setattr(sp, "BAND_CELLS", 1)
    check(case)


EDGES = {
    "one cell": np.zeros((1, 1)),
    "one row": np.zeros((1, 50)),
    "all walls": np.full((40, 40), 2.0),
    "walls at the border": np.pad(np.zeros((36, 36)), 2, constant_values=2.0),
    "flat": np.zeros((45, 31)),
    "nan": np.where(np.eye(40, dtype=bool), np.nan, 0.3 * (np.arange(40) % 3)),
}


@pytest.mark.parametrize("name", sorted(EDGES))
@pytest.mark.parametrize("around", [None, Around((3, 0, 50, 2), 0.0)])
@pytest.mark.parametrize("samples", [False, True])
def test_edge_cases_give_the_whole_grid_spot(
    name: str, around: Around | None, samples: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    heights = EDGES[name]
    walls = heights > 1.0
    for band in (sp.BAND_CELLS, 1):
        monkeypatch.setattr(sp, "BAND_CELLS", band)
        for ground, free in ((None, None), (~walls, ~walls), (~walls, np.zeros_like(walls))):
            check(Case(heights, 0.1, Pose2D(-1.0, -1.0), None, ground, free, samples, around))


def test_memory_is_a_band_not_the_grid() -> None:
    """A 2000 x 2400 walls grid (the world's slab around it): the search holds a few bands, not
    a dozen float64 copies of the grid (each 38 MB)."""
    walls = np.zeros((2000, 2400), bool)
    walls[::50, :] = True
    walls[:, ::50] = True
    heights = np.where(walls, 2.0, 0.0)
    free = ~walls
    tracemalloc.start()
    try:
        s = find_spawn(
            heights,
            0.05,
            Pose2D(-50.0, -50.0),
            ground=~walls,
            free=free,
            around=Around((200,) * 4, 0.0),
        )
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert s.ground
    assert peak < 0.5 * heights.nbytes
