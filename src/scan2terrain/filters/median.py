"""Median filters: plain, the paper's run-protected rule, and its thin-wall-preserving variant.

The run-protected filters follow Lavrenov, Zakiev and Magid, "Tool for 3D Gazebo map construction
from arbitrary images and laser scans": a cell that lies on a straight run of at least three equal
cells keeps its value, every other cell is smoothed over its 3 x 3 neighbourhood.
"""

from __future__ import annotations

from typing import Any, Literal, TypeVar

import numpy as np
from numpy.typing import NDArray

from scan2terrain.filters._common import check_2d, check_fallback, check_size, windows_3x3
from scan2terrain.filters.majority import majority, majority_3x3_at

__all__ = ["median_filter", "paper_median_filter", "thin_wall_median_filter"]

ScalarT = TypeVar("ScalarT", bound=np.generic)

Fallback = Literal["majority", "median"]

# Run directions as (row step, column step).
_STRAIGHT = ((0, 1), (1, 0))
_DIAGONAL = ((1, 1), (1, -1))

# Above this share of unprotected cells the fallback is computed for the whole array; below it,
# gathering the 3 x 3 windows of just those cells is faster. Measured on 4096 x 4096 int8 maps:
# the dense majority costs about the same at any share, scipy's median grows with the number of
# distinct values and stays slower than the gathered one up to about half the cells.
_SPARSE_SHARE = {"majority": 0.1, "median": 0.5}


def median_filter(image: NDArray[ScalarT], *, size: int = 3) -> NDArray[ScalarT]:
    """Plain ``size`` x ``size`` median, for grey images.

    Parameters
    ----------
    image : integer, bool or float array, shape (H, W)
    size : int
        Window side in pixels, odd and >= 3.

    Returns
    -------
    array, shape (H, W), same dtype as ``image``

    Notes
    -----
    Borders repeat the edge pixel (``scipy.ndimage.median_filter`` with ``mode="nearest"``), so
    every window holds ``size**2`` values and the median is always one of them. This differs from
    the clipped windows of :func:`scan2terrain.filters.majority_filter`, at the border only.

    Raises
    ------
    ValueError
        If ``image`` is not a 2D real array or ``size`` is not an odd integer >= 3.
    """
    arr = check_2d(image, "image", allow_float=True)
    from scipy import ndimage  # deferred: importing scipy.ndimage costs ~1 s of start-up

    filtered: NDArray[ScalarT] = ndimage.median_filter(arr, size=check_size(size), mode="nearest")
    return filtered


def paper_median_filter(
    labels: NDArray[ScalarT], *, fallback: Fallback = "majority"
) -> NDArray[ScalarT]:
    """The paper's modified median filter: cells on horizontal or vertical runs of 3 are kept.

    The rule from Lavrenov, Zakiev and Magid: a cell keeps its value when it is one of 3
    consecutive equal cells in its row or in its column (at the start, middle or end of the run);
    any other cell takes the 3 x 3 ``fallback`` of its neighbourhood. Walls one cell thick survive
    when straight, but diagonal runs do not protect a cell, so a 1-cell diagonal wall is eroded
    (see :func:`thin_wall_median_filter`). ``#`` is occupied (100), ``.`` free (0)::

        input            majority_filter  paper_median_filter
        . . . . . . .    . . . . . . .    . . . . . . .
        # # # . . # .    . . . . . . .    # # # . . # .
        . . . . . # .    . . . . . . .    . . . . . # .
        . # . . . # .    . . . . . . .    . . . . . # .
        . . # . . . .    . . . . . . .    . . . . . . .
        . . . # . . #    . . . . . . .    . . . . . . .

    The row and column walls keep every cell, their ends too; the diagonal wall and the lone
    speck in the corner fall to the 3 x 3 majority, as everything does under plain majority.

    Parameters
    ----------
    labels : integer or bool array, shape (H, W)
        An int8 occupancy grid (-1/0/100), any other label map, or a grey image.
    fallback : {"majority", "median"}
        What unprotected cells become: ``"majority"`` takes the most frequent label of the clipped
        3 x 3 window with the tie rule of :func:`scan2terrain.filters.majority_filter` (for label
        maps); ``"median"`` takes the 3 x 3 median with edge pixels repeated, as
        :func:`median_filter` (for grey images).

    Returns
    -------
    array, shape (H, W), same dtype as ``labels``
        A new array. Runs are only looked for inside the array.

    Raises
    ------
    ValueError
        If ``labels`` is not a 2D integer array or ``fallback`` is unknown.
    """
    return _run_protected(labels, fallback=fallback, diagonals=False)


def thin_wall_median_filter(
    labels: NDArray[ScalarT], *, fallback: Fallback = "majority"
) -> NDArray[ScalarT]:
    """:func:`paper_median_filter` with diagonal runs too, so 1-cell diagonal walls survive.

    A cell keeps its value when it is one of 3 consecutive equal cells along its row, its column or
    either diagonal; any other cell takes the 3 x 3 ``fallback``. Every cell the paper's filter
    keeps is kept here too::

        input        paper_median_filter   thin_wall_median_filter
        . . . . .    . . . . .             . . . . .
        # . . . .    . . . . .             # . . . .
        . # . . .    . . . . .             . # . . .
        . . # . .    . . . . .             . . # . .
        . . . # .    . . . . .             . . . # .

    Parameters and return value as :func:`paper_median_filter`.
    """
    return _run_protected(labels, fallback=fallback, diagonals=True)


def _run_protected(labels: NDArray[ScalarT], *, fallback: str, diagonals: bool) -> NDArray[ScalarT]:
    arr = check_2d(labels, "labels")
    fallback = check_fallback(fallback)
    keep = protected_mask(arr, diagonals=diagonals)
    cells = np.flatnonzero(~keep)
    if cells.size == 0:
        unchanged: NDArray[ScalarT] = arr.copy()
        return unchanged
    if cells.size > arr.size * _SPARSE_SHARE[fallback]:
        # Many cells to smooth (noise, grey images): filter the whole array at once.
        out = majority(arr, radius=1) if fallback == "majority" else _median_3x3(arr)
        np.copyto(out, arr, where=keep)
        return out
    # Typical maps: long runs protect nearly every cell, so only the few others are filtered.
    out = np.array(arr, order="C")
    if fallback == "majority":
        out.reshape(-1)[cells] = majority_3x3_at(arr, cells)
    else:
        out.reshape(-1)[cells] = _median_3x3_at(arr, cells)
    return out


def protected_mask(arr: NDArray[Any], *, diagonals: bool) -> NDArray[np.bool_]:
    """Cells lying on a run of >= 3 equal cells along a row, a column and, if asked, a diagonal."""
    keep = np.zeros(arr.shape, dtype=bool)
    height, width = arr.shape
    for dy, dx in _STRAIGHT + _DIAGONAL if diagonals else _STRAIGHT:
        # Runs of 3 starting at cells (r, c) with (r, c) + 2 * (dy, dx) still inside the array:
        # views[k] is the block of their k-th cells, so one comparison covers every run at once.
        rows, cols = height - 2 * abs(dy), width - 2 * abs(dx)
        if rows <= 0 or cols <= 0:
            continue
        row0, col0 = 2 * max(-dy, 0), 2 * max(-dx, 0)
        views = [
            (slice(row0 + k * dy, row0 + k * dy + rows), slice(col0 + k * dx, col0 + k * dx + cols))
            for k in range(3)
        ]
        run = arr[views[0]] == arr[views[1]]
        run &= arr[views[1]] == arr[views[2]]
        for view in views:
            keep[view] |= run
    return keep


def _median_3x3(arr: NDArray[Any]) -> NDArray[Any]:
    from scipy import ndimage  # deferred: importing scipy.ndimage costs ~1 s of start-up

    filtered: NDArray[Any] = ndimage.median_filter(arr, size=3, mode="nearest")
    return filtered


def _median_3x3_at(arr: NDArray[Any], cells: NDArray[np.intp]) -> NDArray[Any]:
    """The 3 x 3 median (edge cells repeated) of ``arr`` at the flat indices ``cells`` only."""
    windows = windows_3x3(arr, cells)
    windows.partition(4, axis=0)
    median: NDArray[Any] = windows[4]
    return median
