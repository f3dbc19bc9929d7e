"""Majority (mode) filter for label maps such as trinary occupancy grids."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from scan2terrain.filters._common import (
    check_2d,
    check_size,
    distinct_values,
    inside_3x3,
    windows_3x3,
)

__all__ = ["majority_filter"]

ScalarT = TypeVar("ScalarT", bound=np.generic)


def majority_filter(labels: NDArray[ScalarT], *, size: int = 3) -> NDArray[ScalarT]:
    """Replace every cell by the most frequent label in its ``size`` x ``size`` window.

    Parameters
    ----------
    labels : integer or bool array, shape (H, W)
        Label map, e.g. an int8 occupancy grid (-1 unknown, 0 free, 100 occupied).
    size : int
        Window side in cells, odd and >= 3.

    Returns
    -------
    array, shape (H, W), same dtype as ``labels``
        A new array; every value in it occurs in ``labels``.

    Notes
    -----
    Ties: a cell keeps its own label when that label is among the most frequent in its window;
    otherwise it takes the largest of the tied labels (for occupancy: occupied > free > unknown).

    Borders: windows are clipped at the array edge, so cells outside the array are not counted
    (a corner cell of a 3 x 3 filter votes among 4 cells).

    Cost grows with the number of distinct labels (one pass of box sums per label), which suits
    label maps; for grey images use :func:`scan2terrain.filters.median_filter`.

    Raises
    ------
    ValueError
        If ``labels`` is not a 2D integer array or ``size`` is not an odd integer >= 3.
    """
    arr = check_2d(labels, "labels")
    return majority(arr, radius=check_size(size) // 2)


def majority(arr: NDArray[Any], *, radius: int) -> NDArray[Any]:
    """:func:`majority_filter` without argument checks; ``radius`` = (size - 1) / 2."""
    values = distinct_values(arr)
    if values.size <= 1:
        unchanged: NDArray[Any] = arr.copy()
        return unchanged
    score_dtype = np.min_scalar_type(2 * (2 * radius + 1) ** 2 + 1)

    def score(value: Any) -> NDArray[Any]:
        is_value = arr == value
        counts = box_count(is_value, radius=radius, dtype=score_dtype)
        np.add(counts, counts, out=counts)
        np.add(counts, is_value, out=counts)
        return counts

    return _elect(values, score, shape=arr.shape, dtype=arr.dtype, score_dtype=score_dtype)


def majority_3x3_at(arr: NDArray[Any], cells: NDArray[np.intp]) -> NDArray[Any]:
    """The 3 x 3 :func:`majority_filter` of ``arr`` at the flat indices ``cells`` only.

    Cheaper than filtering the whole array when ``cells`` are a small share of it.
    """
    windows = windows_3x3(arr, cells)
    inside = inside_3x3(arr.shape, cells)
    centre = windows[4]
    score_dtype = np.dtype(np.uint8)

    def score(value: Any) -> NDArray[Any]:
        counts: NDArray[Any] = np.logical_and(windows == value, inside).sum(
            axis=0, dtype=score_dtype
        )
        np.add(counts, counts, out=counts)
        np.add(counts, centre == value, out=counts)
        return counts

    return _elect(
        distinct_values(windows), score, shape=cells.shape, dtype=arr.dtype, score_dtype=score_dtype
    )


def _elect(
    values: NDArray[Any],
    score: Callable[[Any], NDArray[Any]],
    *,
    shape: tuple[int, ...],
    dtype: np.dtype[Any],
    score_dtype: np.dtype[Any],
) -> NDArray[Any]:
    """Per cell, the value with the highest ``score(value)``; equal scores go to the larger value.

    ``values`` must be ascending. A value scores 2 * (its count in the window) + (1 if it is the
    centre's value): the centre's value then wins ties on count but loses to any larger count, and
    as later (larger) values take over on equal score, the largest tied value wins otherwise.
    """
    winner = np.empty(shape, dtype=dtype)
    best = np.zeros(shape, dtype=score_dtype)
    takes_over = np.empty(shape, dtype=bool)
    for value in values:
        value_score = score(value)
        np.greater_equal(value_score, best, out=takes_over)
        np.copyto(winner, value, where=takes_over)
        np.maximum(best, value_score, out=best)
    return winner


def box_count(mask: NDArray[np.bool_], *, radius: int, dtype: np.dtype[Any]) -> NDArray[Any]:
    """Number of True cells in each (2 * radius + 1)-square window, clipped at the array edge.

    Separable sums of shifted slices (2 * radius additions per axis): no padding, no floats.
    """
    rows = _shifted_sum(mask.view(np.uint8), radius=radius, axis=1, dtype=dtype)
    return _shifted_sum(rows, radius=radius, axis=0, dtype=dtype)


def _shifted_sum(
    values: NDArray[Any], *, radius: int, axis: int, dtype: np.dtype[Any]
) -> NDArray[Any]:
    """Sum of ``values`` over offsets -radius..radius along ``axis``, offsets outside left out."""

    def part(start: int | None, stop: int | None) -> tuple[slice, ...]:
        return (slice(None), slice(start, stop)) if axis == 1 else (slice(start, stop),)

    total = np.empty(values.shape, dtype=dtype)
    if values.shape[axis] < 2:
        total[...] = values
        return total
    # Offset +-1 first, written straight into `total` to save the pass a copy would cost.
    np.add(values[part(1, None)], values[part(None, -1)], out=total[part(1, None)])
    total[part(None, 1)] = values[part(None, 1)]
    np.add(total[part(None, -1)], values[part(1, None)], out=total[part(None, -1)])
    for d in range(2, min(radius, values.shape[axis] - 1) + 1):
        np.add(total[part(d, None)], values[part(None, -d)], out=total[part(d, None)])
        np.add(total[part(None, -d)], values[part(d, None)], out=total[part(None, -d)])
    return total
