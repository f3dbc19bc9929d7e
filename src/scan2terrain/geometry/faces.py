"""Where a wall's faces go: on the cell boundaries (the grid is the truth: a map), or where a
scan's end points lie (``faces_at_hits``).

A wall cell of a grid made from scans holds the end points of the beams that stopped in it,
spread over the cell; the face they saw lies, on average, half a cell behind the cell's front
boundary. So on a grid of half the cell size, each wall cell's half that faces observed free
space is left out where the wall goes on behind it (a half cell of wall, then no free cell):
a wall seen from one side (a building's outer wall) keeps half a cell, a thicker wall loses
half a cell on each observed side, and a wall one cell thick seen from both sides (the hits of
both faces share its cells) and a lone post keep their cells. The replay (commands/replay.py)
measured the gain: on a synthetic room at 0.05 m the share of beams within 5 cm rose from
90.7% to 99.9%.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


def faces_at_hits(walls: NDArray[np.bool_], free: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """The wall cells of a (H, W) grid on a (2H, 2W) grid of half their size, each face toward
    known-free cells moved half a cell into the wall where the wall goes on behind it."""
    w: NDArray[np.bool_] = np.repeat(np.repeat(walls, 2, axis=0), 2, axis=1)
    f: NDArray[np.bool_] = np.repeat(np.repeat(free, 2, axis=0), 2, axis=1)
    keep: NDArray[np.bool_] = w.copy()
    for axis in (0, 1):
        for step in (1, -1):
            in_front = _shifted(f, step, axis)  # free at c - step
            behind = _shifted(w, -step, axis)  # wall at c + step
            beyond = _shifted(f, -2 * step, axis)  # free at c + 2 step: a wall seen from both
            keep &= ~(w & in_front & behind & ~beyond)
    return keep


def _shifted(a: NDArray[np.bool_], step: int, axis: int) -> NDArray[np.bool_]:
    """``out[c] = a[c - step]`` along ``axis``, False beyond the edge."""
    out = np.zeros_like(a)
    n = a.shape[axis]
    if abs(step) >= n:
        return out
    src = [slice(None)] * a.ndim
    dst = [slice(None)] * a.ndim
    if step > 0:
        src[axis], dst[axis] = slice(0, n - step), slice(step, n)
    else:
        src[axis], dst[axis] = slice(-step, n), slice(0, n + step)
    out[tuple(dst)] = a[tuple(src)]
    return out
