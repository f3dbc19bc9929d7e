"""merge_boxes: an exact, disjoint cover of the occupied cells by the fewest rectangles.

Exactness is checked cell by cell with a plain per-box painter (not the module's own rasteriser);
optimality against an exhaustive search on small grids; the box counts of the real maps against
the greedy row-run merge and the lower bounds. The fewest rectangles of any exact cover, overlaps
allowed (a set cover by the maximal rectangles, solved exactly with HiGHS), show what a partition
leaves on the table: on the real maps, almost nothing.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from numpy.typing import NDArray
from scipy import ndimage, sparse
from scipy.optimize import Bounds, LinearConstraint, milp

from scan2terrain import steps
from scan2terrain.config import Config
from scan2terrain.geometry.boxes import box_extents, merge_boxes, rasterize_boxes
from scan2terrain.readers import read_map_yaml
from tests.fixtures import MAPS


def painted(boxes: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """How many boxes cover each cell, one box at a time."""
    out = np.zeros(shape, dtype=np.int64)
    for r0, c0, nr, nc in boxes:
        assert nr >= 1 and nc >= 1 and r0 >= 0 and c0 >= 0
        assert r0 + nr <= shape[0] and c0 + nc <= shape[1]
        out[r0 : r0 + nr, c0 : c0 + nc] += 1
    return out


def assert_exact_cover(occ: np.ndarray, boxes: np.ndarray) -> None:
    assert boxes.dtype == np.int64 and boxes.ndim == 2 and boxes.shape[1] == 4
    cover = painted(boxes, occ.shape)
    assert cover.max(initial=0) <= 1, "boxes overlap"
    assert np.array_equal(cover == 1, occ), "boxes do not cover exactly the occupied cells"


def greedy_runs(occ: np.ndarray) -> int:
    """The simple merge: row runs grown downwards while the next row has the identical run."""
    boxes = 0
    open_runs: set[tuple[int, int]] = set()
    for row in occ:
        padded = np.concatenate([[0], row.astype(np.int8), [0]])
        starts = np.flatnonzero(np.diff(padded) == 1)
        stops = np.flatnonzero(np.diff(padded) == -1)
        runs = set(zip(starts.tolist(), stops.tolist(), strict=True))
        boxes += len(runs - open_runs)
        open_runs = runs
    return boxes


def fewest_rectangles(occ: np.ndarray) -> int:
    """Exhaustive minimum rectangle partition (small grids only).

    The first uncovered occupied cell in row-major order must be the first cell of its rectangle,
    so branching over that rectangle's width and height enumerates every partition once.
    """
    h, w = occ.shape
    best = [int(occ.sum())]

    def search(free: np.ndarray, used: int) -> None:
        if used >= best[0]:
            return
        cells = np.flatnonzero(free)
        if cells.size == 0:
            best[0] = used
            return
        r, c = divmod(int(cells[0]), w)
        width = 0
        while c + width < w and free[r, c + width]:
            width += 1
        for nc in range(width, 0, -1):
            nr = 1
            while r + nr < h and free[r + nr, c : c + nc].all():
                nr += 1
            for rows in range(nr, 0, -1):
                nxt = free.copy()
                nxt[r : r + rows, c : c + nc] = False
                search(nxt, used + 1)

    search(occ.copy(), 0)
    return best[0]


def maximal_rectangles(occ: np.ndarray) -> list[tuple[int, int, int, int]]:
    """Every maximal all-occupied rectangle ``(row0, col0, n_rows, n_cols)``: plain loops.

    Row by row, ``height[c]`` is how many occupied cells end at this row in column c. A rectangle
    whose last row is this row, over columns c0..c1, with the lowest of those heights, is maximal
    iff neither neighbouring column is that high and the next row is not occupied all along.
    """
    h, w = occ.shape
    height = np.zeros(w + 2, dtype=np.int64)  # padded by a zero column on each side
    above = np.zeros((h + 1, w + 2), dtype=bool)
    above[:h, 1:-1] = occ
    found = []
    for r in range(h):
        height[1:-1] = np.where(occ[r], height[1:-1] + 1, 0)
        hs, nxt = height.tolist(), above[r + 1].tolist()
        # Only a column higher than its left neighbour can be a maximal rectangle's first.
        for c0 in (np.flatnonzero(height[1:] > height[:-1]) + 1).tolist():
            low, upwards = h + 1, True
            for c1 in range(c0, w + 1):
                low, upwards = min(low, hs[c1]), upwards and nxt[c1]
                if hs[c0 - 1] >= low:
                    break
                if hs[c1 + 1] < low and not upwards:
                    found.append((r - low + 1, c0 - 1, low, c1 - c0 + 1))
    return found


def fewest_covering_rectangles(occ: np.ndarray) -> tuple[float, int]:
    """The fewest rectangles whose union is exactly the occupied cells, overlaps allowed.

    Any rectangle inside the cells grows to a maximal one, so the minimum is a set cover of the
    cells by the maximal rectangles. Returns (its LP relaxation, the integer optimum): the LP is
    a proven lower bound for every exact cover, and the optimum is certain when they round equal.
    """
    rects = maximal_rectangles(occ)
    if not rects:
        return 0.0, 0
    index = np.full(occ.shape, -1, dtype=np.int64)
    cells = np.flatnonzero(occ)
    index.flat[cells] = np.arange(cells.size)
    members = [index[r0 : r0 + nr, c0 : c0 + nc].ravel() for r0, c0, nr, nc in rects]
    which = np.repeat(np.arange(len(rects)), [m.size for m in members])
    a = sparse.csr_array(
        (np.ones(which.size), (np.concatenate(members), which)), shape=(cells.size, len(rects))
    )
    cover, cost, bounds = LinearConstraint(a, 1, np.inf), np.ones(len(rects)), Bounds(0, 1)
    relaxed = milp(cost, constraints=cover, bounds=bounds)
    exact = milp(cost, constraints=cover, bounds=bounds, integrality=np.ones(len(rects)))
    assert relaxed.status == 0 and exact.status == 0
    return float(relaxed.fun), round(exact.fun)


def filtered_map(name: str) -> np.ndarray:
    meta, grid = read_map_yaml(MAPS[name])
    trinary = steps.classify(grid, meta.mode, meta.occupied_thresh, meta.free_thresh)
    walls: NDArray[np.bool_] = steps.filter_occupancy(trinary, Config()) == 100
    return walls


# --- small hand-made grids ----------------------------------------------------------------------


def grid(text: str) -> np.ndarray:
    """Rows of '#' (occupied) and '.', written top row first like a picture."""
    rows = [line.strip() for line in text.strip().splitlines()]
    return np.flipud(np.array([[ch == "#" for ch in row] for row in rows]))


@pytest.mark.parametrize(
    ("picture", "fewest"),
    [
        ("#", 1),
        ("###\n###", 1),
        ("#..\n##.", 2),  # L
        ("###\n.#.\n###", 3),  # I: both chords used
        (".#.\n###\n.#.", 3),  # plus: the two chords cross, one is used
        ("###\n#.#\n###", 4),  # ring around a hole
        ("#.\n.#", 2),  # corner contact only: not one rectangle
        ("##..\n.##.\n..##", 3),  # staircase
        ("#####\n#...#\n#.#.#\n#...#\n#####", 5),  # ring with an island
    ],
)
def test_hand_made_shapes(picture: str, fewest: int) -> None:
    occ = grid(picture)
    boxes = merge_boxes(occ)
    assert_exact_cover(occ, boxes)
    assert len(boxes) == fewest == fewest_rectangles(occ)


def test_empty_and_degenerate_grids() -> None:
    for shape in [(0, 0), (0, 5), (5, 0), (3, 4)]:
        boxes = merge_boxes(np.zeros(shape, dtype=bool))
        assert boxes.shape == (0, 4) and boxes.dtype == np.int64
    assert merge_boxes(np.ones((1, 7), dtype=bool)).tolist() == [[0, 0, 1, 7]]
    assert merge_boxes(np.ones((7, 1), dtype=bool)).tolist() == [[0, 0, 7, 1]]
    with pytest.raises(ValueError, match="2D"):
        merge_boxes(np.ones(4, dtype=bool))


def test_boxes_are_sorted_and_deterministic() -> None:
    rng = np.random.default_rng(5)
    occ = rng.random((60, 80)) < 0.4
    boxes = merge_boxes(occ)
    assert np.array_equal(boxes, merge_boxes(occ.copy()))
    keys = boxes[:, 0] * 1000 + boxes[:, 1]
    assert np.all(np.diff(keys) > 0)


def test_non_bool_input_is_truthiness() -> None:
    occ = np.array([[0, 100, 100], [0, 0, 7]], dtype=np.int16)
    assert_exact_cover(occ != 0, merge_boxes(occ))  # type: ignore[arg-type]  # int16, on purpose


def test_rasterize_boxes_and_extents() -> None:
    boxes = np.array([[1, 2, 2, 3], [0, 0, 1, 1]], dtype=np.int64)
    counts = rasterize_boxes(boxes, (4, 6))
    assert np.array_equal(counts, painted(boxes, (4, 6)))
    with pytest.raises(ValueError, match="outside"):
        rasterize_boxes(boxes, (2, 6))
    ext = box_extents(boxes, 0.5, (10.0, -2.0))
    np.testing.assert_allclose(ext, [[11.0, -1.5, 12.5, -0.5], [10.0, -2.0, 10.5, -1.5]])


# --- invariants ---------------------------------------------------------------------------------


@settings(max_examples=300, deadline=None)
@given(arrays(np.bool_, st.tuples(st.integers(0, 24), st.integers(0, 24))))
def test_random_grids_are_covered_exactly(occ: np.ndarray) -> None:
    boxes = merge_boxes(occ)
    assert_exact_cover(occ, boxes)
    # Never worse than the simple merge, never fewer than the 4-connected pieces.
    assert len(boxes) <= greedy_runs(occ)
    assert len(boxes) >= ndimage.label(occ)[1]


@settings(max_examples=150, deadline=None)
@given(arrays(np.bool_, st.tuples(st.integers(1, 5), st.integers(1, 5))))
def test_random_small_grids_get_the_fewest_boxes(occ: np.ndarray) -> None:
    assert len(merge_boxes(occ)) == fewest_rectangles(occ)


@settings(max_examples=150, deadline=None)
@given(arrays(np.bool_, st.tuples(st.integers(0, 7), st.integers(0, 7))))
def test_maximal_rectangles_match_brute_force(occ: np.ndarray) -> None:
    """The test helper behind the overlapping-cover bounds, against every rectangle's check."""
    h, w = occ.shape

    def inside(r0: int, c0: int, r1: int, c1: int) -> bool:
        return min(r0, c0) >= 0 and r1 <= h and c1 <= w and bool(occ[r0:r1, c0:c1].all())

    def grown(r0: int, c0: int, r1: int, c1: int) -> list[tuple[int, int, int, int]]:
        return [
            (r0 - 1, c0, r1, c1),
            (r0, c0, r1 + 1, c1),
            (r0, c0 - 1, r1, c1),
            (r0, c0, r1, c1 + 1),
        ]

    expected = {
        (r0, c0, r1 - r0, c1 - c0)
        for r0 in range(h)
        for r1 in range(r0 + 1, h + 1)
        for c0 in range(w)
        for c1 in range(c0 + 1, w + 1)
        if inside(r0, c0, r1, c1) and not any(inside(*bigger) for bigger in grown(r0, c0, r1, c1))
    }
    found = maximal_rectangles(occ)
    assert len(found) == len(set(found))
    assert set(found) == expected


@settings(max_examples=100, deadline=None)
@given(arrays(np.bool_, st.tuples(st.integers(1, 12), st.integers(1, 12))))
def test_overlapping_covers_never_need_more_boxes(occ: np.ndarray) -> None:
    lp, fewest = fewest_covering_rectangles(occ)
    assert ndimage.label(occ)[1] <= fewest <= len(merge_boxes(occ))
    assert lp <= fewest + 1e-6


@settings(max_examples=100, deadline=None)
@given(
    arrays(np.bool_, st.tuples(st.integers(1, 40), st.integers(1, 40)), elements=st.just(True)),
    st.data(),
)
def test_thick_shapes_with_holes(full: np.ndarray, data: st.DataObject) -> None:
    """Blocky shapes (big rectangles minus rectangular holes), where chords matter most."""
    occ = full.copy()
    h, w = occ.shape
    for _ in range(data.draw(st.integers(0, 6))):
        r0, c0 = data.draw(st.integers(0, h - 1)), data.draw(st.integers(0, w - 1))
        r1, c1 = data.draw(st.integers(r0, h)), data.draw(st.integers(c0, w))
        occ[r0:r1, c0:c1] = False
    boxes = merge_boxes(occ)
    assert_exact_cover(occ, boxes)
    assert len(boxes) <= greedy_runs(occ)


# --- the real maps ------------------------------------------------------------------------------

#: Occupied cells and boxes of each real map after the default filter (regression: the partition
#: is a minimum, so these counts only change if the filter or the map does).
REAL_COUNTS = {
    "levine": (6836, 37),
    "tb3": (792, 202),
    "warehouse": (30679, 1500),
    "willow": (9211, 2549),
}
#: The fewest boxes of any exact cover of each real map when boxes may overlap (proven: the LP
#: bound rounds up to the integer optimum). Gazebo does not mind overlapping boxes in a static
#: model, but they would save 0.2 % (willow) to 14 % (levine) of the partition's boxes.
FEWEST_COVER = {"levine": 32, "tb3": 201, "warehouse": 1460, "willow": 2544}


@pytest.mark.parametrize("name", sorted(MAPS))
def test_real_maps_are_covered_exactly_by_few_boxes(name: str) -> None:
    occ = filtered_map(name)
    boxes = merge_boxes(occ)
    assert_exact_cover(occ, boxes)
    assert (int(occ.sum()), len(boxes)) == REAL_COUNTS[name]
    assert len(boxes) <= greedy_runs(occ)


def test_shapes_where_overlapping_boxes_help() -> None:
    """A plus needs three disjoint boxes but two overlapping ones; an I and an L gain nothing."""
    assert fewest_covering_rectangles(grid(".#.\n###\n.#."))[1] == 2
    assert fewest_covering_rectangles(grid("#####\n..#..\n..#..\n#####"))[1] == 3
    assert fewest_covering_rectangles(grid("#..\n##."))[1] == 2


@pytest.mark.parametrize("name", sorted(MAPS))
def test_real_maps_gain_little_from_overlapping_boxes(name: str) -> None:
    occ = filtered_map(name)
    lp, fewest = fewest_covering_rectangles(occ)
    assert np.ceil(lp - 1e-6) == fewest == FEWEST_COVER[name]
    assert fewest <= REAL_COUNTS[name][1]


def test_willow_boxes_versus_cells() -> None:
    """Willow Garage after the default filter: 9211 wall cells, 2549 boxes (3.6x fewer).

    2549 is the minimum for any exact, disjoint cover by rectangles: the filtered map falls into
    1729 separate 4-connected pieces (diagonal walls are chains of cells touching at corners),
    each needs at least one box, and the pieces' reflex corners need the rest. Letting boxes
    overlap does not rescue a 4x reduction (<= 2302 boxes) either: no exact cover, overlapping or
    not, has fewer than 2544 boxes (the LP bound of the set cover by the 2768 maximal rectangles,
    which the integer optimum attains). Only other cells (another filter) or other shapes than
    axis-aligned boxes covering exactly the cells could get there.
    """
    occ = filtered_map("willow")
    boxes = merge_boxes(occ)
    pieces = ndimage.label(occ)[1]
    assert pieces == 1729
    assert occ.sum() / len(boxes) > 3.6
    assert greedy_runs(occ) > len(boxes)
    lp, fewest = fewest_covering_rectangles(occ)
    assert len(maximal_rectangles(occ)) == 2768
    assert lp > occ.sum() / 4 and fewest == 2544
