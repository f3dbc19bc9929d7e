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
    known-free cells moved half a cell into the wall where the wall goes on behind it.

    Worked out per wall cell (memory: the output and a few arrays per wall cell, not copies of
    the fine grid): a fine cell's test looks at most two fine cells, so one coarse cell, away.
    """
    walls = np.asarray(walls, dtype=bool)
    free = np.asarray(free, dtype=bool)
    h, w = walls.shape
    out = np.zeros((2 * h, 2 * w), dtype=bool)
    rows, cols = np.nonzero(walls)

    def at(grid: NDArray[np.bool_], dr: int, dc: int) -> NDArray[np.bool_]:
        """``grid`` at each wall cell's neighbour (dr, dc), False beyond the edge."""
        r, c = rows + dr, cols + dc
        inside = (r >= 0) & (r < h) & (c >= 0) & (c < w)
        got = np.zeros(len(rows), dtype=bool)
        got[inside] = grid[r[inside], c[inside]]
        return got

    for a in (0, 1):  # the fine cell (2 row + a, 2 col + b) of each wall cell
        for b in (0, 1):
            keep = np.ones(len(rows), dtype=bool)
            for axis, sub in ((0, a), (1, b)):
                for step in (1, -1):
                    # The fine cells -step (in front), +step (behind) and +2 step (beyond)
                    # away along ``axis`` lie in the coarse cells (sub + k) // 2 away.
                    d_front, d_behind, d_beyond = ((sub + k) // 2 for k in (-step, step, 2 * step))
                    in_front = at(free, *_along(axis, d_front))
                    behind = at(walls, *_along(axis, d_behind))
                    beyond = at(free, *_along(axis, d_beyond))
                    keep &= ~(in_front & behind & ~beyond)
            out[2 * rows[keep] + a, 2 * cols[keep] + b] = True
    return out


def _along(axis: int, d: int) -> tuple[int, int]:
    """The (row, column) offset of ``d`` cells along ``axis``."""
    return (d, 0) if axis == 0 else (0, d)
