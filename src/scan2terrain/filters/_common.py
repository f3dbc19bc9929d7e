"""Argument checks and array helpers shared by the filters.

Every check raises :class:`ValueError` naming the offending parameter, as the filters promise.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

#: Fallback rules accepted by the run-protected median filters.
FALLBACKS = ("majority", "median")

# Cells per np.bincount call when listing the values of a 1- or 2-byte array: bincount widens its
# input to intp, so chunks keep that temporary in cache instead of allocating 8 bytes per cell.
_BINCOUNT_CHUNK = 1 << 18


def check_2d(array: Any, name: str, *, allow_float: bool = False) -> NDArray[Any]:
    """Return ``array`` as a 2D ndarray of integer (or bool, or if allowed float) dtype."""
    arr = np.asarray(array)
    if arr.ndim != 2:
        raise ValueError(f"{name} must be a 2D array, got {arr.ndim} dimension(s)")
    kinds, wanted = ("biuf", "a real") if allow_float else ("biu", "an integer")
    if arr.dtype.kind not in kinds:
        raise ValueError(f"{name} must have {wanted} dtype, got {arr.dtype}")
    return arr


def check_size(size: Any) -> int:
    """Return ``size`` as an int, or raise if it is not an odd integer >= 3."""
    is_int = isinstance(size, (int, np.integer)) and not isinstance(size, bool)
    if not is_int or size < 3 or size % 2 == 0:
        raise ValueError(f"size must be an odd integer >= 3, got {size!r}")
    return int(size)


def check_fallback(fallback: Any) -> str:
    """Return ``fallback``, or raise if it is not one of :data:`FALLBACKS`."""
    if fallback not in FALLBACKS:
        raise ValueError(f"fallback must be one of {FALLBACKS}, got {fallback!r}")
    return str(fallback)


def distinct_values(arr: NDArray[Any]) -> NDArray[Any]:
    """The distinct values of ``arr``, ascending, in ``arr``'s dtype."""
    if arr.dtype.itemsize > 2:
        return np.unique(arr)
    # A histogram of the raw bytes is several times faster than np.unique's sort on large maps.
    codes_dtype = np.dtype(np.uint8) if arr.dtype.itemsize == 1 else np.dtype(np.uint16)
    codes = np.ascontiguousarray(arr).view(codes_dtype).reshape(-1)
    present = np.zeros(256**arr.dtype.itemsize, dtype=bool)
    for start in range(0, codes.size, _BINCOUNT_CHUNK):
        chunk = codes[start : start + _BINCOUNT_CHUNK]
        present |= np.bincount(chunk, minlength=present.size) > 0
    values = np.flatnonzero(present).astype(codes_dtype).view(arr.dtype)
    return np.sort(values)


#: The offsets (row, column) of a 3 x 3 window, in the order of the rows of windows_3x3's result.
OFFSETS_3X3 = tuple((dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1))


def windows_3x3(arr: NDArray[Any], cells: NDArray[np.intp]) -> NDArray[Any]:
    """The 3 x 3 windows of ``arr`` around the cells with flat (C order) indices ``cells``.

    Returns an array of shape (9, len(cells)) in ``arr``'s dtype: row k holds the cells at offset
    ``OFFSETS_3X3[k]`` (row 4 is the centre). Offsets outside ``arr`` repeat the nearest edge cell.
    """
    width = arr.shape[1]
    stride = width + 2
    padded = np.pad(arr, 1, mode="edge").reshape(-1)
    # Cell (r, c) sits at (r + 1) * stride + (c + 1) in the padded array.
    centres = cells + 2 * (cells // width) + (stride + 1)
    values = np.empty((9, cells.size), dtype=arr.dtype)
    for k, (dy, dx) in enumerate(OFFSETS_3X3):
        np.take(padded, centres + (dy * stride + dx), out=values[k])
    return values


def inside_3x3(shape: tuple[int, ...], cells: NDArray[np.intp]) -> NDArray[np.bool_]:
    """Which offsets of the :func:`windows_3x3` of ``cells`` lie inside an array of ``shape``.

    Returns a bool array of shape (9, len(cells)), for filters whose windows are clipped.
    """
    height, width = shape
    rows, cols = np.divmod(cells, width)
    everywhere = np.ones(cells.size, dtype=bool)
    row_inside = {-1: rows > 0, 0: everywhere, 1: rows < height - 1}
    col_inside = {-1: cols > 0, 0: everywhere, 1: cols < width - 1}
    inside = np.empty((9, cells.size), dtype=bool)
    for k, (dy, dx) in enumerate(OFFSETS_3X3):
        np.logical_and(row_inside[dy], col_inside[dx], out=inside[k])
    return inside
