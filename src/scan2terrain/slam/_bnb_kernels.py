"""Branch and bound over a correlative search window (numba): the best placement of a scan's
points on a likelihood grid, exactly, without scoring every placement.

The idea is Olson's and Cartographer's (``FastCorrelativeScanMatcher2D``, Hess et al. 2016):
``bounds[d]`` holds, for each cell, the largest grid value in the ``2**d`` x ``2**d`` cells from
it, so a placement scored at depth ``d`` bounds the score of every placement in the square of
offsets it stands for. Depth-first, best child first: a square is opened only when its bound
beats the best score found so far, so the answer is the exhaustive search's.
"""

from __future__ import annotations

import numpy as np

from scan2terrain._numba import numba as nb


@nb.njit(cache=True, nogil=True)
def _score(grid: np.ndarray, cx: np.ndarray, cy: np.ndarray, ox: int, oy: int, width: int) -> float:
    """Mean of ``grid`` at the points moved by (ox, oy). ``grid`` holds maxima over
    ``width`` x ``width`` cells from each cell: a square that starts below the grid but
    reaches into it is bounded by the first cell's (a square from there covers it)."""
    h, w = grid.shape
    total = 0.0
    for i in range(cx.size):
        x = cx[i] + ox
        y = cy[i] + oy
        if x < 0:
            if x + width <= 0:
                continue
            x = 0
        if y < 0:
            if y + width <= 0:
                continue
            y = 0
        if x < w and y < h:
            total += grid[y, x]
    return total / max(cx.size, 1)


@nb.njit(cache=True, nogil=True)
def branch_and_bound(
    bounds: np.ndarray,  # float32 (D + 1, H, W): bounds[0] is the grid itself
    cells_x: np.ndarray,  # int32 (R, N): each rotation's points, cells at offset 0
    cells_y: np.ndarray,
    span: int,  # offsets 0 .. span - 1 in x and in y
    min_score: float,
) -> tuple[float, int, int, int]:
    """(score, rotation, x offset, y offset) of the best placement scoring above
    ``min_score`` (score -1 when none does)."""
    depth = bounds.shape[0] - 1
    step = 1 << depth
    n_top = ((span + step - 1) // step) ** 2 * cells_x.shape[0]
    cap = n_top + 8 * (depth + 1)
    st_s = np.empty(cap, np.float64)
    st_r = np.empty(cap, np.int64)
    st_x = np.empty(cap, np.int64)
    st_y = np.empty(cap, np.int64)
    st_d = np.empty(cap, np.int64)
    # The top level, pushed worst first so that the best is opened first.
    top_s = np.empty(n_top, np.float64)
    top_r = np.empty(n_top, np.int64)
    top_x = np.empty(n_top, np.int64)
    top_y = np.empty(n_top, np.int64)
    k = 0
    for r in range(cells_x.shape[0]):
        for ox in range(0, span, step):
            for oy in range(0, span, step):
                top_s[k] = _score(bounds[depth], cells_x[r], cells_y[r], ox, oy, step)
                top_r[k] = r
                top_x[k] = ox
                top_y[k] = oy
                k += 1
    order = np.argsort(top_s[:k], kind="mergesort")
    n = 0
    for i in order:
        st_s[n] = top_s[i]
        st_r[n] = top_r[i]
        st_x[n] = top_x[i]
        st_y[n] = top_y[i]
        st_d[n] = depth
        n += 1
    best, best_r, best_x, best_y = min_score, -1, 0, 0
    cs = np.empty(4, np.float64)
    cx = np.empty(4, np.int64)
    cy = np.empty(4, np.int64)
    while n > 0:
        n -= 1
        s, r, ox, oy, d = st_s[n], st_r[n], st_x[n], st_y[n], st_d[n]
        if s <= best:
            continue
        if d == 0:
            best, best_r, best_x, best_y = s, r, ox, oy
            continue
        half = 1 << (d - 1)
        m = 0
        for dx in (0, half):
            for dy in (0, half):
                x, y = ox + dx, oy + dy
                if x < span and y < span:
                    cs[m] = _score(bounds[d - 1], cells_x[r], cells_y[r], x, y, half)
                    cx[m] = x
                    cy[m] = y
                    m += 1
        # Children pushed worst first (ties in a fixed order: the same answer every run).
        idx = np.argsort(cs[:m], kind="mergesort")
        for j in idx:
            if cs[j] > best:
                st_s[n] = cs[j]
                st_r[n] = r
                st_x[n] = cx[j]
                st_y[n] = cy[j]
                st_d[n] = d - 1
                n += 1
    if best_r < 0:
        return -1.0, -1, 0, 0
    return best, best_r, best_x, best_y
