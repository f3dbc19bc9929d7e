"""Tests for majority_filter, median_filter, paper_median_filter and thin_wall_median_filter."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any
from unittest import mock

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from numpy.typing import NDArray
from scipy import ndimage

from scan2terrain.filters import median as median_module
from scan2terrain.filters.majority import majority_filter
from scan2terrain.filters.median import (
    median_filter,
    paper_median_filter,
    protected_mask,
    thin_wall_median_filter,
)
from scan2terrain.types import FREE, OCCUPIED, UNKNOWN

Array = NDArray[Any]


def grid(text: str) -> NDArray[np.int8]:
    """An int8 occupancy grid from rows of ``#`` (occupied), ``.`` (free) and ``?`` (unknown)."""
    codes = {"#": OCCUPIED, ".": FREE, "?": UNKNOWN}
    return np.array(
        [[codes[c] for c in line.split()] for line in text.strip().splitlines()], np.int8
    )


# --- slow, obviously correct references (plain loops over cells) --------------------------------


def slow_majority(a: Array, size: int = 3) -> Array:
    r = size // 2
    out = np.empty_like(a)
    for i in range(a.shape[0]):
        for j in range(a.shape[1]):
            window = a[max(i - r, 0) : i + r + 1, max(j - r, 0) : j + r + 1]
            counts = Counter(window.ravel().tolist())
            top = max(counts.values())
            tied = [value for value, count in counts.items() if count == top]
            out[i, j] = a[i, j] if a[i, j] in tied else max(tied)
    return out


def slow_median_3x3(a: Array) -> Array:
    padded = np.pad(a, 1, mode="edge")
    out = np.empty_like(a)
    for i in range(a.shape[0]):
        for j in range(a.shape[1]):
            out[i, j] = sorted(padded[i : i + 3, j : j + 3].ravel().tolist())[4]
    return out


def slow_protected(a: Array, *, diagonals: bool) -> NDArray[np.bool_]:
    directions = [(0, 1), (1, 0)] + ([(1, 1), (1, -1)] if diagonals else [])
    height, width = a.shape
    keep = np.zeros(a.shape, dtype=bool)
    for i in range(height):
        for j in range(width):
            for dy, dx in directions:
                for first in (-2, -1, 0):  # the cell is the start, middle or end of the run
                    run = [(i + (first + k) * dy, j + (first + k) * dx) for k in range(3)]
                    if all(0 <= y < height and 0 <= x < width for y, x in run) and all(
                        a[y, x] == a[i, j] for y, x in run
                    ):
                        keep[i, j] = True
    return keep


def slow_run_protected(a: Array, *, diagonals: bool, fallback: str) -> Array:
    smoothed = slow_majority(a) if fallback == "majority" else slow_median_3x3(a)
    return np.where(slow_protected(a, diagonals=diagonals), a, smoothed)


@contextmanager
def sparse_share(share: float) -> Iterator[None]:
    """Force the run-protected filters' dense (share 0) or sparse (share 1) fallback path."""
    with mock.patch.object(median_module, "_SPARSE_SHARE", {"majority": share, "median": share}):
        yield


# --- strategies --------------------------------------------------------------------------------

shapes = hnp.array_shapes(min_dims=2, max_dims=2, min_side=1, max_side=9)
trinary = hnp.arrays(np.int8, shapes, elements=st.sampled_from([UNKNOWN, FREE, OCCUPIED]))
small_labels = hnp.arrays(np.int16, shapes, elements=st.integers(-3, 3))
grey = hnp.arrays(np.uint8, shapes, elements=st.integers(0, 255))
any_labels = st.one_of(
    trinary,
    small_labels,
    grey,
    hnp.arrays(np.int64, shapes, elements=st.sampled_from([-(2**40), 7, 2**40])),
    hnp.arrays(np.bool_, shapes),
)

LabelFilter = Callable[[Array], Array]
label_filters: list[LabelFilter] = [
    majority_filter,
    paper_median_filter,
    thin_wall_median_filter,
    lambda a: majority_filter(a, size=5),
    lambda a: paper_median_filter(a, fallback="median"),
    lambda a: thin_wall_median_filter(a, fallback="median"),
]
filter_ids = ["majority3", "paper", "thin_wall", "majority5", "paper_median", "thin_wall_median"]


# --- hand-made examples --------------------------------------------------------------------------


def test_majority_removes_isolated_speck() -> None:
    a = grid("""
        . . . . .
        . . . . .
        . . # . .
        . . . . .
        . . . . .
    """)
    np.testing.assert_array_equal(majority_filter(a), np.zeros_like(a))


def test_straight_one_cell_walls_kept_by_paper_filter_eroded_by_majority() -> None:
    a = grid("""
        . . . . . . .
        # # # # # . .
        . . . . . . .
        . . . . . # .
        . . . . . # .
        . . . . . # .
        . . . . . # .
    """)
    np.testing.assert_array_equal(paper_median_filter(a), a)
    np.testing.assert_array_equal(majority_filter(a), np.zeros_like(a))


def test_run_end_cells_are_kept() -> None:
    # The ends see 2 wall cells of 9, the middle 3: the majority alone erases the whole wall.
    a = grid("""
        . . . . . . .
        . . . . . . .
        . . # # # . .
        . . . . . . .
        . . . . . . .
    """)
    np.testing.assert_array_equal(paper_median_filter(a), a)
    np.testing.assert_array_equal(paper_median_filter(a.T), a.T)
    np.testing.assert_array_equal(majority_filter(a), np.zeros_like(a))


def test_diagonal_wall_eroded_by_paper_filter_kept_by_thin_wall() -> None:
    a = grid("""
        . . . . . .
        # . . . . .
        . # . . . .
        . . # . . .
        . . . # . .
        . . . . # .
    """)
    np.testing.assert_array_equal(paper_median_filter(a), np.zeros_like(a))
    np.testing.assert_array_equal(thin_wall_median_filter(a), a)
    anti = a[:, ::-1]
    np.testing.assert_array_equal(paper_median_filter(anti), np.zeros_like(a))
    np.testing.assert_array_equal(thin_wall_median_filter(anti), anti)


def test_short_runs_do_not_protect() -> None:
    # Two equal cells are not a run; both fall to the majority of their neighbourhood.
    a = grid("""
        . . . . .
        . # # . .
        . . . . .
        . . . . .
    """)
    np.testing.assert_array_equal(thin_wall_median_filter(a), np.zeros_like(a))


def test_tie_keeps_centre_label() -> None:
    # Every cell's window is the whole array, two cells of each label: all keep their own.
    a = grid("""
        . #
        # .
    """)
    np.testing.assert_array_equal(majority_filter(a), a)


def test_tie_without_centre_goes_to_largest_label() -> None:
    a = grid("""
        ? ? #
        ? . #
        ? # #
    """)
    assert majority_filter(a)[1, 1] == OCCUPIED  # 4 unknown, 4 occupied: occupied > unknown
    b = grid("""
        . . ?
        . # ?
        . ? ?
    """)
    assert majority_filter(b)[1, 1] == FREE  # 4 free, 4 unknown: free > unknown
    c = np.array([[5, 5, 3], [5, 9, 3], [5, 3, 3]], dtype=np.int16)
    assert majority_filter(c)[1, 1] == 5  # by value, not by first seen


def test_windows_are_clipped_at_the_border() -> None:
    # In one row a 3 x 3 window holds 3 cells, 2 at the ends; the end cells tie and keep theirs.
    row = np.array([[100, 0, 100, 0, 0, 100]], dtype=np.int8)
    np.testing.assert_array_equal(majority_filter(row), [[100, 100, 0, 0, 0, 100]])
    # Cell (0, 1) votes among all 6 cells, 3 free and 3 occupied: a tie, it stays free. With the
    # edge repeated instead (mode="nearest") the occupied cells of row 0 would count twice.
    a = grid("""
        # . #
        # . .
    """)
    assert majority_filter(a)[0, 1] == FREE
    assert median_filter(a)[0, 1] == OCCUPIED


def test_runs_are_only_looked_for_inside_the_array() -> None:
    # The 2-cell stubs at the border are not runs: nothing outside the array extends them.
    a = grid("""
        . . . . .
        # . . . #
        # . . . #
        . . . . .
        . . . . .
    """)
    np.testing.assert_array_equal(paper_median_filter(a), np.zeros_like(a))


def test_paper_filter_median_fallback_on_grey_image() -> None:
    image = np.array(
        [
            [10, 20, 30, 40, 50],
            [60, 70, 255, 90, 15],
            [25, 35, 45, 55, 65],
            [200, 200, 200, 5, 95],
        ],
        dtype=np.uint8,
    )
    expected = ndimage.median_filter(image, size=3, mode="nearest")
    expected[3, :3] = 200  # a horizontal run of three, kept
    np.testing.assert_array_equal(paper_median_filter(image, fallback="median"), expected)


def test_median_filter_is_scipy_nearest() -> None:
    rng = np.random.default_rng(1)
    image = rng.integers(0, 256, (17, 23)).astype(np.uint16)
    for size in (3, 5):
        expected = ndimage.median_filter(image, size=size, mode="nearest")
        np.testing.assert_array_equal(median_filter(image, size=size), expected)
    floats = rng.random((6, 7)).astype(np.float32)
    assert median_filter(floats).dtype == np.float32


def test_majority_size_5() -> None:
    a = np.zeros((7, 7), dtype=np.int8)
    a[2:5, 2:5] = OCCUPIED  # 9 cells: the centre's 5 x 5 window holds 9 of 25
    a[0, 0] = UNKNOWN
    np.testing.assert_array_equal(majority_filter(a, size=5), np.zeros_like(a))


@pytest.mark.parametrize("share", [0.0, 1.0], ids=["dense", "sparse"])
def test_input_is_not_modified_and_layout_does_not_matter(share: float) -> None:
    rng = np.random.default_rng(2)
    base = rng.choice(np.array([UNKNOWN, FREE, OCCUPIED], dtype=np.int8), (30, 40))
    strided, fortran = base[::2, ::3], np.asfortranarray(base)
    before = base.copy()
    with sparse_share(share):
        for function in label_filters:
            np.testing.assert_array_equal(function(strided), function(base[::2, ::3].copy()))
            np.testing.assert_array_equal(function(fortran), function(base))
    np.testing.assert_array_equal(base, before)


@pytest.mark.parametrize("function", label_filters, ids=filter_ids)
def test_empty_array(function: LabelFilter) -> None:
    a = np.zeros((0, 4), dtype=np.int8)
    out = function(a)
    assert out.shape == (0, 4)
    assert out.dtype == np.int8


# --- cross-checks against the slow references ----------------------------------------------------


@given(a=st.one_of(trinary, small_labels))
def test_majority_matches_reference(a: Array) -> None:
    np.testing.assert_array_equal(majority_filter(a), slow_majority(a))


@given(a=small_labels)
@settings(max_examples=40)
def test_majority_size_5_matches_reference(a: Array) -> None:
    np.testing.assert_array_equal(majority_filter(a, size=5), slow_majority(a, size=5))


@pytest.mark.parametrize("share", [0.0, 1.0], ids=["dense", "sparse"])
@pytest.mark.parametrize("diagonals", [False, True], ids=["paper", "thin_wall"])
@given(a=st.one_of(trinary, small_labels))
def test_run_protected_filters_match_reference(a: Array, diagonals: bool, share: float) -> None:
    function = thin_wall_median_filter if diagonals else paper_median_filter
    with sparse_share(share):
        for fallback in ("majority", "median"):
            expected = slow_run_protected(a, diagonals=diagonals, fallback=fallback)
            np.testing.assert_array_equal(function(a, fallback=fallback), expected)


@given(a=grey)
def test_median_fallback_matches_reference_on_grey(a: Array) -> None:
    with sparse_share(1.0):
        sparse = paper_median_filter(a, fallback="median")
    expected = slow_run_protected(a, diagonals=False, fallback="median")
    np.testing.assert_array_equal(sparse, expected)
    np.testing.assert_array_equal(paper_median_filter(a, fallback="median"), expected)


@given(a=st.one_of(trinary, small_labels))
def test_protected_mask_matches_reference(a: Array) -> None:
    for diagonals in (False, True):
        expected = slow_protected(a, diagonals=diagonals)
        np.testing.assert_array_equal(protected_mask(a, diagonals=diagonals), expected)


# --- properties ----------------------------------------------------------------------------------


@pytest.mark.parametrize("function", label_filters, ids=filter_ids)
@given(a=any_labels)
def test_output_values_come_from_input(function: LabelFilter, a: Array) -> None:
    out = function(a)
    assert out.shape == a.shape
    assert out.dtype == a.dtype
    assert set(np.unique(out).tolist()) <= set(np.unique(a).tolist())


@pytest.mark.parametrize("function", [*label_filters, median_filter], ids=[*filter_ids, "median"])
@given(shape=shapes, value=st.sampled_from([UNKNOWN, FREE, OCCUPIED]))
def test_constant_arrays_are_unchanged(function: LabelFilter, shape: Any, value: int) -> None:
    a = np.full(shape, value, dtype=np.int8)
    np.testing.assert_array_equal(function(a), a)


@given(a=st.one_of(trinary, small_labels, grey))
def test_thin_wall_keeps_what_paper_keeps(a: Array) -> None:
    paper_keep = protected_mask(a, diagonals=False)
    thin_keep = protected_mask(a, diagonals=True)
    assert np.all(thin_keep[paper_keep])
    np.testing.assert_array_equal(thin_wall_median_filter(a)[paper_keep], a[paper_keep])


@pytest.mark.parametrize("size", [3, 5])
@given(a=hnp.arrays(np.uint8, shapes, elements=st.integers(0, 1)))
def test_majority_equals_median_on_binary_arrays(size: int, a: Array) -> None:
    # With size**2 (odd) cells the majority of 0/1 is the median. Only the interior is compared:
    # at the border majority clips its windows, median_filter repeats the edge.
    r = size // 2
    interior = (slice(r, a.shape[0] - r), slice(r, a.shape[1] - r))
    np.testing.assert_array_equal(
        majority_filter(a, size=size)[interior], median_filter(a, size=size)[interior]
    )


# --- argument validation -------------------------------------------------------------------------


@pytest.mark.parametrize("size", [1, 2, 4, 0, -3, 3.0, True, "3"])
def test_bad_size(size: Any) -> None:
    a = np.zeros((4, 4), dtype=np.int8)
    with pytest.raises(ValueError, match="size"):
        majority_filter(a, size=size)
    with pytest.raises(ValueError, match="size"):
        median_filter(a, size=size)


@pytest.mark.parametrize("function", [paper_median_filter, thin_wall_median_filter])
@pytest.mark.parametrize("fallback", ["mean", "Majority", None])
def test_bad_fallback(function: Callable[..., Array], fallback: Any) -> None:
    with pytest.raises(ValueError, match="fallback"):
        function(np.zeros((4, 4), dtype=np.int8), fallback=fallback)


@pytest.mark.parametrize("shape", [(5,), (2, 3, 4), ()])
@pytest.mark.parametrize("function", [*label_filters, median_filter], ids=[*filter_ids, "median"])
def test_non_2d_input(function: LabelFilter, shape: tuple[int, ...]) -> None:
    with pytest.raises(ValueError, match="2D"):
        function(np.zeros(shape, dtype=np.int8))


@pytest.mark.parametrize("function", label_filters, ids=filter_ids)
def test_float_labels_rejected(function: LabelFilter) -> None:
    with pytest.raises(ValueError, match="labels must have an integer dtype"):
        function(np.zeros((3, 3), dtype=np.float32))
