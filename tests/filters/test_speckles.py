"""Tests for remove_speckles."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from numpy.typing import NDArray

from scan2terrain.filters.speckle import remove_speckles
from scan2terrain.types import FREE, OCCUPIED, UNKNOWN


def grid(text: str) -> NDArray[np.int8]:
    """An int8 occupancy grid from rows of ``#`` (occupied), ``.`` (free) and ``?`` (unknown)."""
    codes = {"#": OCCUPIED, ".": FREE, "?": UNKNOWN}
    return np.array(
        [[codes[c] for c in line.split()] for line in text.strip().splitlines()], np.int8
    )


SPECKS = grid("""
    . . . . . .
    . # . . . .
    . . # . . .
    . . . . # #
    # . . . # #
""")


def test_eight_connectivity_joins_diagonal_neighbours() -> None:
    # The diagonal pair is one component of 2 cells; the corner cell is alone.
    expected = grid("""
        . . . . . .
        . # . . . .
        . . # . . .
        . . . . # #
        . . . . # #
    """)
    out = remove_speckles(SPECKS, value=OCCUPIED, min_cells=2, replace_with=FREE)
    np.testing.assert_array_equal(out, expected)


def test_four_connectivity_splits_diagonal_neighbours() -> None:
    expected = grid("""
        . . . . . .
        . . . . . .
        . . . . . .
        . . . . # #
        . . . . # #
    """)
    out = remove_speckles(SPECKS, value=OCCUPIED, min_cells=2, replace_with=FREE, connectivity=4)
    np.testing.assert_array_equal(out, expected)


def test_components_smaller_than_min_cells_only() -> None:
    # The 4-cell block survives min_cells=4 and falls to min_cells=5.
    out = remove_speckles(SPECKS, value=OCCUPIED, min_cells=4, replace_with=UNKNOWN)
    assert np.count_nonzero(out == OCCUPIED) == 4
    assert np.count_nonzero(out == UNKNOWN) == 3
    out = remove_speckles(SPECKS, value=OCCUPIED, min_cells=5, replace_with=FREE)
    np.testing.assert_array_equal(out, np.zeros_like(SPECKS))


def test_other_values_untouched() -> None:
    a = grid("""
        ? . ? ?
        . . . ?
        # . . .
    """)
    out = remove_speckles(a, value=UNKNOWN, min_cells=2, replace_with=FREE)
    np.testing.assert_array_equal(
        out,
        grid("""
        . . ? ?
        . . . ?
        # . . .
    """),
    )


@pytest.mark.parametrize("min_cells", [1, 0, -5])
def test_min_cells_up_to_one_is_a_no_op(min_cells: int) -> None:
    out = remove_speckles(SPECKS, value=OCCUPIED, min_cells=min_cells, replace_with=FREE)
    np.testing.assert_array_equal(out, SPECKS)
    assert out is not SPECKS


def test_components_are_cut_at_the_border() -> None:
    # Cells at opposite edges do not wrap around into one component.
    a = grid("""
        # . . #
        . . . .
    """)
    out = remove_speckles(a, value=OCCUPIED, min_cells=2, replace_with=FREE)
    np.testing.assert_array_equal(out, np.zeros_like(a))


@given(
    a=hnp.arrays(
        np.int8,
        hnp.array_shapes(min_dims=2, max_dims=2, min_side=1, max_side=12),
        elements=st.sampled_from([UNKNOWN, FREE, OCCUPIED]),
    ),
    min_cells=st.integers(0, 6),
    connectivity=st.sampled_from([4, 8]),
)
def test_properties(a: NDArray[np.int8], min_cells: int, connectivity: int) -> None:
    before = a.copy()
    out = remove_speckles(
        a, value=OCCUPIED, min_cells=min_cells, replace_with=FREE, connectivity=connectivity
    )
    np.testing.assert_array_equal(a, before)
    assert out.shape == a.shape
    assert out.dtype == a.dtype
    changed = out != a
    assert np.all(a[changed] == OCCUPIED)
    assert np.all(out[changed] == FREE)
    # Idempotent: what survives is made of components of at least min_cells cells.
    again = remove_speckles(
        out, value=OCCUPIED, min_cells=min_cells, replace_with=FREE, connectivity=connectivity
    )
    np.testing.assert_array_equal(again, out)


@pytest.mark.parametrize("connectivity", [6, 0, 1, True, "8"])
def test_bad_connectivity(connectivity: Any) -> None:
    with pytest.raises(ValueError, match="connectivity"):
        remove_speckles(
            SPECKS, value=OCCUPIED, min_cells=2, replace_with=FREE, connectivity=connectivity
        )


@pytest.mark.parametrize(
    ("name", "kwargs"),
    [
        ("replace_with", {"value": OCCUPIED, "replace_with": 300}),
        ("replace_with", {"value": OCCUPIED, "replace_with": 0.5}),
        ("value", {"value": -200, "replace_with": FREE}),
        ("value", {"value": None, "replace_with": FREE}),
    ],
)
def test_bad_labels(name: str, kwargs: dict[str, Any]) -> None:
    with pytest.raises(ValueError, match=name):
        remove_speckles(SPECKS, min_cells=2, **kwargs)


def test_bad_min_cells() -> None:
    with pytest.raises(ValueError, match="min_cells"):
        remove_speckles(SPECKS, value=OCCUPIED, min_cells=2.5, replace_with=FREE)  # type: ignore[arg-type]


@pytest.mark.parametrize("shape", [(5,), (2, 3, 4)])
def test_non_2d_input(shape: tuple[int, ...]) -> None:
    with pytest.raises(ValueError, match="2D"):
        remove_speckles(np.zeros(shape, np.int8), value=OCCUPIED, min_cells=2, replace_with=FREE)


def test_layout_does_not_matter() -> None:
    rng = np.random.default_rng(3)
    base = rng.choice(np.array([UNKNOWN, FREE, OCCUPIED], dtype=np.int8), (30, 40))
    options: dict[str, Any] = {"value": OCCUPIED, "min_cells": 3, "replace_with": FREE}
    expected = remove_speckles(base, **options)
    np.testing.assert_array_equal(remove_speckles(np.asfortranarray(base), **options), expected)
    np.testing.assert_array_equal(
        remove_speckles(base[::2, ::3], **options),
        remove_speckles(base[::2, ::3].copy(), **options),
    )
