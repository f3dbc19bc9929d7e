"""The boundary edges of trace() found from the occupied cells (issue 31): exactly the
whole-grid edges they were, in memory of about the edges."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest
from numpy.typing import NDArray

from scan2terrain.geometry.outlines import _boundary_edges, trace
from scan2terrain.types import Pose2D


def reference(occ: NDArray[np.bool_]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The whole-grid version _boundary_edges replaced: four masks of a padded copy."""
    h, w = occ.shape
    p = np.zeros((h + 2, w + 2), dtype=bool)
    p[1:-1, 1:-1] = occ
    below, above = p[:-1, 1:-1], p[1:, 1:-1]
    left, right = p[1:-1, :-1], p[1:-1, 1:]
    vids, dirs = [], []
    for mask, dx, dy, d in (
        (above & ~below, 0, 0, 0),
        (right & ~left, 0, 1, 3),
        (left & ~right, 0, 0, 1),
        (below & ~above, 1, 0, 2),
    ):
        y, x = np.nonzero(mask)
        vids.append((y + dy) * (w + 1) + (x + dx))
        dirs.append(np.full(len(y), d, dtype=np.int64))
    vid, di = np.concatenate(vids), np.concatenate(dirs)
    order = np.argsort(vid * 4 + di, kind="stable")
    return vid[order], di[order]


EDGE_CASES = {
    "empty": np.zeros((0, 4), bool),
    "no columns": np.zeros((4, 0), bool),
    "one cell": np.ones((1, 1), bool),
    "one free cell": np.zeros((1, 1), bool),
    "all occupied": np.ones((5, 7), bool),
    "none occupied": np.zeros((5, 7), bool),
    "border": np.pad(np.zeros((3, 4), bool), 1, constant_values=True),
    "diagonals": np.eye(5, dtype=bool) | np.eye(5, dtype=bool)[::-1],
    "one row": np.array([[1, 0, 1, 1, 0, 1]], bool),
    "one column": np.array([[1], [1], [0], [1]], bool),
}


def check(occ: NDArray[np.bool_]) -> None:
    vid, dirs = _boundary_edges(occ)
    ref_vid, ref_dirs = reference(occ)
    assert vid.dtype == ref_vid.dtype == np.int64
    assert dirs.dtype == np.int64
    np.testing.assert_array_equal(vid, ref_vid)
    np.testing.assert_array_equal(dirs, ref_dirs)


@pytest.mark.parametrize("name", sorted(EDGE_CASES))
def test_edge_cases_equal_the_whole_grid_version(name: str) -> None:
    check(EDGE_CASES[name])


@pytest.mark.parametrize("seed", range(300))
def test_random_grids_equal_the_whole_grid_version(seed: int) -> None:
    rng = np.random.default_rng(seed)
    shape = tuple(int(n) for n in rng.integers(1, 15, size=2))
    check(rng.random(shape) < rng.random())


def test_memory_follows_the_occupied_cells() -> None:
    """A large grid with few occupied cells: no copy of the grid, no whole-grid mask."""
    occ = np.zeros((2000, 2400), bool)
    occ[1000, 100:900] = True
    occ[100:600, 1500:1502] = True
    occ[0, :] = True
    tracemalloc.start()
    try:
        _boundary_edges(occ)
        peak = tracemalloc.get_traced_memory()[1]
        polygons = trace(occ, 0.05, Pose2D(0.0, 0.0, 0.0))
        peak_trace = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert len(polygons) == 3
    # A copy of the grid alone would be occ.size bytes; the edges here take about a tenth.
    assert peak < 0.25 * occ.size
    assert peak_trace < 0.5 * occ.size
    check(occ)
