"""faces_at_hits works from the wall cells (issue 31): exactly the whole-grid result it had, in
memory of about its output."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest
from numpy.typing import NDArray

from scan2terrain.geometry.faces import faces_at_hits


def reference(walls: NDArray[np.bool_], free: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """The whole-grid version faces_at_hits replaced (shifted copies of the (2H, 2W) grids)."""
    w = np.repeat(np.repeat(walls, 2, axis=0), 2, axis=1)
    f = np.repeat(np.repeat(free, 2, axis=0), 2, axis=1)

    def shifted(a: NDArray[np.bool_], step: int, axis: int) -> NDArray[np.bool_]:
        out = np.zeros_like(a)
        n = a.shape[axis]
        if abs(step) < n:
            src = [slice(None)] * 2
            dst = [slice(None)] * 2
            src[axis] = slice(max(0, -step), n - max(0, step))
            dst[axis] = slice(max(0, step), n - max(0, -step))
            out[tuple(dst)] = a[tuple(src)]
        return out

    keep = w.copy()
    for axis in (0, 1):
        for step in (1, -1):
            a, b, c = shifted(f, step, axis), shifted(w, -step, axis), shifted(f, -2 * step, axis)
            keep &= ~(w & a & b & ~c)
    out: NDArray[np.bool_] = keep
    return out


def random_grids(seed: int) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    rng = np.random.default_rng(seed)
    shape = tuple(int(n) for n in rng.integers(1, 12, size=2))
    cells = rng.choice(3, size=shape, p=rng.dirichlet(np.ones(3)))
    return cells == 0, cells == 1


EDGE_CASES = {
    "empty": (np.zeros((0, 5), bool), np.zeros((0, 5), bool)),
    "no columns": (np.zeros((3, 0), bool), np.zeros((3, 0), bool)),
    "one wall": (np.ones((1, 1), bool), np.zeros((1, 1), bool)),
    "one free": (np.zeros((1, 1), bool), np.ones((1, 1), bool)),
    "all walls": (np.ones((4, 6), bool), np.zeros((4, 6), bool)),
    "all free": (np.zeros((4, 6), bool), np.ones((4, 6), bool)),
    "walls at the border": (
        np.pad(np.zeros((3, 4), bool), 1, constant_values=True),
        np.pad(np.ones((3, 4), bool), 1, constant_values=False),
    ),
    "one row": (np.array([[1, 0, 1, 1, 0, 1]], bool), np.array([[0, 1, 0, 0, 1, 0]], bool)),
    "one column": (np.array([[1], [0], [1], [1]], bool), np.array([[0], [1], [0], [0]], bool)),
    # Not a grid's walls and free space (they overlap), but the function is defined there too.
    "overlapping": (np.ones((3, 3), bool), np.ones((3, 3), bool)),
}


@pytest.mark.parametrize("name", sorted(EDGE_CASES))
def test_edge_cases_equal_the_whole_grid_version(name: str) -> None:
    walls, free = EDGE_CASES[name]
    got = faces_at_hits(walls, free)
    assert got.dtype == bool
    np.testing.assert_array_equal(got, reference(walls, free))
    assert got.shape == (2 * walls.shape[0], 2 * walls.shape[1])


@pytest.mark.parametrize("seed", range(300))
def test_random_grids_equal_the_whole_grid_version(seed: int) -> None:
    walls, free = random_grids(seed)
    np.testing.assert_array_equal(faces_at_hits(walls, free), reference(walls, free))
    rng = np.random.default_rng(seed)
    overlapping = rng.random(walls.shape) < 0.5, rng.random(walls.shape) < 0.5
    np.testing.assert_array_equal(faces_at_hits(*overlapping), reference(*overlapping))


def test_memory_is_the_output_and_the_wall_cells() -> None:
    """A large grid with few walls: the output (2H, 2W) and little more, not a dozen of them."""
    walls = np.zeros((1000, 1200), bool)
    walls[500, 100:400] = True
    walls[100:300, 700] = True
    free = ~walls
    tracemalloc.start()
    try:
        out = faces_at_hits(walls, free)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1.2 * out.nbytes
    np.testing.assert_array_equal(out, reference(walls, free))
