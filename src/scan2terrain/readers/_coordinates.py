"""The coordinates a text or PCD cloud holds, against the physical world (``_limits.py``).

A finite coordinate is 0 or of a size within MIN_COORDINATE_M..MAX_COORDINATE_M: 1e300 or 1e17 m
cannot be represented in metres (a world 1e300 m wide, or every point in one cell after the
local origin), and a denormal is a damaged number, not a distance. NaN and infinity are the
formats' marks of no return (PCL's organised clouds write NaN), dropped by
:func:`~scan2terrain.readers.cloudfile.read_cloud` as before. :func:`check_coordinates`
refuses the first offending coordinate in one line naming the file, where it is (the line of a
text file, the point of a binary one), the axis and the value.
"""

from __future__ import annotations

import io
import itertools
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from scan2terrain.readers._limits import MAX_COORDINATE_M, MIN_COORDINATE_M, within

_AXES = "xyz"


def check_coordinates(
    path: Path, points: NDArray[np.floating], where: Callable[[int], str]
) -> None:
    """Refuse ``points`` (N, 3) holding a finite coordinate beyond the limits: InputError naming
    ``path``, ``where(row)`` (``"line 6"``, ``"point 3"``), the axis and the value.

    Two reductions over the points in the usual case; the mask that finds the row only when one
    of them says some coordinate is out of bounds (or infinite)."""
    size = np.abs(points)
    with np.errstate(invalid="ignore"):
        top = float(np.fmax.reduce(size, axis=None, initial=0.0))  # NaN ignored
        tiny = np.count_nonzero(size < MIN_COORDINATE_M) != np.count_nonzero(size == 0)
    if top <= MAX_COORDINATE_M and not tiny:
        return
    with np.errstate(invalid="ignore"):
        bad = ((size > MAX_COORDINATE_M) & np.isfinite(size)) | (
            (size < MIN_COORDINATE_M) & (size > 0)
        )
    flat = np.flatnonzero(bad)
    if not len(flat):
        return  # infinite coordinates only: no-return marks
    row, axis = divmod(int(flat[0]), points.shape[1])
    value = float(points[row, axis])
    within(
        path, f"{where(row)}: {_AXES[axis]}", value, lo=MIN_COORDINATE_M, hi=MAX_COORDINATE_M,
        unit="m",
    )  # fmt: skip


def data_line(source: Path | io.StringIO, skip: int, row: int, first: int = 1) -> int:
    """The number of the line holding data row ``row`` (0-based) of a table ``numpy.loadtxt``
    read with ``skiprows=skip`` and ``#`` comments: the lines after the first ``skip`` that hold
    something before any ``#``; ``first`` is the number of the source's first line. Read only
    to name a refused row, up to that row."""
    if isinstance(source, Path):
        with source.open(encoding="utf-8", newline=None) as text:
            return _nth_data_line(text, skip, row, first)
    return _nth_data_line(source, skip, row, first)


def _nth_data_line(lines: Iterable[str], skip: int, row: int, first: int) -> int:
    numbered = itertools.islice(enumerate(lines, start=first), skip, None)
    data = (n for n, line in numbered if line.split("#", 1)[0].strip())
    found = next(itertools.islice(data, row, None), None)
    return first + skip + row if found is None else found
