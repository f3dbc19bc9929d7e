# numba kernels take their arrays and scalars positionally (as octree/_kernels.py does).
"""Compiled loops of outline simplification (numba), imported only by ``simplify.py``.

Coordinates are in half cells of the grid (``2 * grid units``), so every outline point (cell
corner or cell-edge midpoint) has integer coordinates and every cell centre odd ones; all
predicates below (orientation, point on segment, crossing parity) are exact in float64.

A ring's outline points occupy ``x[lo:lo + n]``; ``sel`` marks those that may become vertices of
the simplified ring. A span ``(i, j)`` with ``i < j`` (ring-local, taken modulo ``n``) is the path
``i, i + 1, ..., j`` that one segment from ``i`` to ``j`` would replace. A span is *acceptable*
when every point on it lies within the tolerance of that segment, the region between path and
segment (its pocket, even-odd) holds no cell centre, and the segment passes no cell centre closer
than ``CLEARANCE_CELLS``: then no cell centre changes side, and walls and gaps one cell wide keep
at least twice that.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, TypeVar, cast

import numpy as np
from numpy.typing import NDArray

from scan2terrain._numba import numba as nb

F = TypeVar("F", bound=Callable[..., Any])

#: Distance, in cells, that a new segment keeps from every cell centre, so that no wall or gap
#: one cell wide becomes thinner than 0.3 cell (without it the Douglas-Peucker edges of the
#: fixture maps pass as close as 0.0003 cell to a centre, and walls taper to slivers).
CLEARANCE_CELLS = 0.15
#: The same, squared, in half cells.
CLEARANCE2 = (2.0 * CLEARANCE_CELLS) ** 2


def _jit(function: F) -> F:
    return cast(F, nb.njit(nogil=True, cache=True, error_model="numpy")(function))


@_jit
def _seg_dist2(px: float, py: float, ax: float, ay: float, bx: float, by: float) -> float:
    """Squared distance from point p to segment ab."""
    dx, dy = bx - ax, by - ay
    qx, qy = px - ax, py - ay
    ll = dx * dx + dy * dy
    if ll == 0.0:
        return qx * qx + qy * qy
    t = (qx * dx + qy * dy) / ll
    if t <= 0.0:
        return qx * qx + qy * qy
    if t >= 1.0:
        rx, ry = px - bx, py - by
        return rx * rx + ry * ry
    cr = qx * dy - qy * dx
    return cr * cr / ll


@_jit
def _farthest(
    x: NDArray[np.float64],
    y: NDArray[np.float64],
    sel: NDArray[np.bool_],
    lo: int,
    n: int,
    i: int,
    j: int,
) -> tuple[float, int]:
    """Largest squared distance of the points ``i + 1 .. j - 1`` from segment i-j, and the
    ring-local index of the farthest selectable one (-1 when there is none)."""
    ax, ay = x[lo + i % n], y[lo + i % n]
    bx, by = x[lo + j % n], y[lo + j % n]
    worst, best, best_d = 0.0, -1, -1.0
    for t in range(i + 1, j):
        k = lo + t % n
        d = _seg_dist2(x[k], y[k], ax, ay, bx, by)
        worst = max(worst, d)
        if sel[k] and d > best_d:
            best, best_d = t, d
    return worst, best


@_jit
def _in_closed_polygon(
    x: NDArray[np.float64],
    y: NDArray[np.float64],
    lo: int,
    n: int,
    i: int,
    j: int,
    cx: float,
    cy: float,
) -> bool:
    """Whether (cx, cy) lies inside (even-odd) or on the polygon of path i..j closed by j->i."""
    inside = False
    for t in range(i, j + 1):
        k0 = lo + t % n
        k1 = lo + (t + 1) % n if t < j else lo + i % n
        x0, y0, x1, y1 = x[k0], y[k0], x[k1], y[k1]
        num = (x0 - cx) * (y1 - y0) + (cy - y0) * (x1 - x0)
        if num == 0.0 and min(x0, x1) <= cx <= max(x0, x1) and min(y0, y1) <= cy <= max(y0, y1):
            return True
        if (y0 > cy) != (y1 > cy) and num * (y1 - y0) > 0.0:
            inside = not inside
    return inside


@_jit
def _too_close(cx: float, cy: float, ax: float, ay: float, bx: float, by: float) -> bool:
    """Whether (cx, cy) lies closer than the clearance (squared: ``CLEARANCE2``) to segment ab,
    exactly: integer coordinates, and the products stay far below 2**53 for the centres
    tested (those within a few units of the segment)."""
    dx, dy = bx - ax, by - ay
    qx, qy = cx - ax, cy - ay
    along = qx * dx + qy * dy
    ll = dx * dx + dy * dy
    if along <= 0.0:
        return qx * qx + qy * qy < CLEARANCE2
    if along >= ll:
        rx, ry = cx - bx, cy - by
        return rx * rx + ry * ry < CLEARANCE2
    cr = qx * dy - qy * dx
    return cr * cr < CLEARANCE2 * ll


@_jit
def _centre_conflict(
    x: NDArray[np.float64], y: NDArray[np.float64], lo: int, n: int, i: int, j: int, tol: float
) -> bool:
    """Whether the segment from i to j would bring a cell centre (odd, odd) closer than the
    clearance, or leave one inside the pocket between it and the path i..j.

    Every path point is within ``tol`` of the segment, so the pocket lies in the band of half
    width ``tol`` around the segment's line and in the path's bounding box: only the centres
    there (and near the segment) are tested.
    """
    ax, ay = x[lo + i % n], y[lo + i % n]
    bx, by = x[lo + j % n], y[lo + j % n]
    xmin, xmax, ymin, ymax = ax, ax, ay, ay
    for t in range(i + 1, j + 1):
        k = lo + t % n
        xmin, xmax = min(xmin, x[k]), max(xmax, x[k])
        ymin, ymax = min(ymin, y[k]), max(ymax, y[k])
    xmin, xmax, ymin, ymax = xmin - 1.0, xmax + 1.0, ymin - 1.0, ymax + 1.0
    dx, dy = bx - ax, by - ay
    reach = (max(tol, math.sqrt(CLEARANCE2)) + 1e-6) * math.sqrt(dx * dx + dy * dy)
    cy = 2.0 * math.floor((ymin - 1.0) / 2.0) + 1.0  # first odd value >= ymin
    if cy < ymin:
        cy += 2.0
    while cy <= ymax:
        lo_x, hi_x = xmin, xmax
        if dy != 0.0:
            # |dx (cy - ay) - dy (cx - ax)| <= reach, solved for cx.
            c0 = ax + (dx * (cy - ay) - reach) / dy
            c1 = ax + (dx * (cy - ay) + reach) / dy
            lo_x, hi_x = max(lo_x, min(c0, c1)), min(hi_x, max(c0, c1))
        cx = 2.0 * math.floor((lo_x - 1.0) / 2.0) + 1.0
        if cx < lo_x:
            cx += 2.0
        while cx <= hi_x:
            if _too_close(cx, cy, ax, ay, bx, by) or _in_closed_polygon(x, y, lo, n, i, j, cx, cy):
                return True
            cx += 2.0
        cy += 2.0
    return False


@_jit
def _acceptable(
    x: NDArray[np.float64],
    y: NDArray[np.float64],
    sel: NDArray[np.bool_],
    lo: int,
    n: int,
    i: int,
    j: int,
    tol: float,
) -> tuple[bool, int]:
    """(span i..j may become one segment, its farthest selectable point or -1 if none)."""
    if j - i < 2:
        return True, -1
    d2, k = _farthest(x, y, sel, lo, n, i, j)
    if d2 > tol * tol or _centre_conflict(x, y, lo, n, i, j, tol):
        return False, k
    return True, k


@_jit
def _refine(
    x: NDArray[np.float64],
    y: NDArray[np.float64],
    sel: NDArray[np.bool_],
    lo: int,
    n: int,
    i: int,
    j: int,
    keep: NDArray[np.bool_],
    tol: float,
    force: bool,
    stack: NDArray[np.int64],
) -> bool:
    """Douglas-Peucker on span i..j: mark kept points in ``keep`` (global indices).

    With ``force`` the span is split at its farthest selectable point even when it is
    acceptable. Returns False when a span had to be split but held no selectable point.
    """
    stack[0], stack[1] = i, j
    top = 1
    first = True
    complete = True
    while top > 0:
        top -= 1
        a, b = stack[2 * top], stack[2 * top + 1]
        ok, k = _acceptable(x, y, sel, lo, n, a, b, tol)
        split = (force and first) or not ok
        first = False
        if not split:
            continue
        if k < 0:
            complete = False
            continue
        keep[lo + k % n] = True
        stack[2 * top], stack[2 * top + 1] = a, k
        stack[2 * top + 2], stack[2 * top + 3] = k, b
        top += 2
    return complete


@_jit
def simplify_rings(
    x: NDArray[np.float64],
    y: NDArray[np.float64],
    sel: NDArray[np.bool_],
    start: NDArray[np.int64],
    keep: NDArray[np.bool_],
    tol: float,
) -> NDArray[np.bool_]:
    """Douglas-Peucker on every ring over its selectable points: anchors at the first
    selectable point and the selectable point farthest from it, then each anchor is dropped
    again when its two neighbouring spans join acceptably. Returns, per ring, whether every span
    could be made acceptable (not so only for input that is no outline on the grid)."""
    stack = np.empty(2 * (int(np.max(np.diff(start))) + 4), dtype=np.int64)
    complete = np.ones(len(start) - 1, dtype=np.bool_)
    for r in range(len(start) - 1):
        lo, n = start[r], start[r + 1] - start[r]
        a = 0
        while a < n and not sel[lo + a]:
            a += 1
        if a == n:
            complete[r] = False
            continue
        f, best = a, -1.0
        for t in range(a + 1, a + n):
            k = lo + t % n
            d = (x[k] - x[lo + a]) ** 2 + (y[k] - y[lo + a]) ** 2
            if sel[k] and d > best:
                f, best = t, d
        keep[lo + a] = True
        keep[lo + f % n] = True
        done_a = _refine(x, y, sel, lo, n, a, f, keep, tol, False, stack)
        done_b = _refine(x, y, sel, lo, n, f, a + n, keep, tol, False, stack)
        complete[r] = done_a and done_b
        for anchor in (a, f):
            p = anchor - 1
            while not keep[lo + p % n]:
                p -= 1
            q = anchor + 1
            while not keep[lo + q % n]:
                q += 1
            if p < 0:
                p, q = p + n, q + n
            kept = 0
            for t in range(n):
                kept += keep[lo + t]
            if q - p >= n or kept <= 3:
                continue  # the ring would be left with fewer than three vertices
            ok, _ = _acceptable(x, y, sel, lo, n, p, q, tol)
            if ok:
                keep[lo + anchor % n] = False
    return complete


@_jit
def split_segments(
    x: NDArray[np.float64],
    y: NDArray[np.float64],
    sel: NDArray[np.bool_],
    start: NDArray[np.int64],
    seg_ring: NDArray[np.int64],
    seg_a: NDArray[np.int64],
    seg_b: NDArray[np.int64],
    bad: NDArray[np.bool_],
    keep: NDArray[np.bool_],
    tol: float,
) -> int:
    """Split every bad segment at its farthest selectable point and refine both halves;
    returns how many could be split (a bad segment with no selectable point inside cannot)."""
    stack = np.empty(2 * (int(np.max(np.diff(start))) + 4), dtype=np.int64)
    done = 0
    for s in range(len(seg_a)):
        if not bad[s]:
            continue
        r = seg_ring[s]
        lo, n = start[r], start[r + 1] - start[r]
        i = seg_a[s] - lo
        j = seg_b[s] - lo
        if j <= i:
            j += n
        _, k = _farthest(x, y, sel, lo, n, i, j)
        if k < 0:
            continue
        _refine(x, y, sel, lo, n, i, j, keep, tol, True, stack)
        done += 1
    return done


@_jit
def _orient(ax: float, ay: float, bx: float, by: float, cx: float, cy: float) -> int:
    v = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
    return 1 if v > 0.0 else (-1 if v < 0.0 else 0)


@_jit
def _on_segment(ax: float, ay: float, bx: float, by: float, px: float, py: float) -> bool:
    """p, known collinear with ab, lies on the closed segment ab."""
    return min(ax, bx) <= px <= max(ax, bx) and min(ay, by) <= py <= max(ay, by)


@_jit
def contact(
    ax: float, ay: float, bx: float, by: float, cx: float, cy: float, dx: float, dy: float
) -> int:
    """How segments ab and cd meet: 0 not at all, 1 only at one endpoint they share, 2 any
    other way (crossing, overlap, or an endpoint on the other's interior)."""
    o1 = _orient(ax, ay, bx, by, cx, cy)
    o2 = _orient(ax, ay, bx, by, dx, dy)
    o3 = _orient(cx, cy, dx, dy, ax, ay)
    o4 = _orient(cx, cy, dx, dy, bx, by)
    if o1 * o2 > 0 or o3 * o4 > 0:
        return 0
    if o1 == 0 and o2 == 0:
        # Collinear: project on the longer axis of ab.
        if abs(bx - ax) >= abs(by - ay):
            p0, p1, q0, q1 = min(ax, bx), max(ax, bx), min(cx, dx), max(cx, dx)
        else:
            p0, p1, q0, q1 = min(ay, by), max(ay, by), min(cy, dy), max(cy, dy)
        lo, hi = max(p0, q0), min(p1, q1)
        if lo > hi:
            return 0
        if lo < hi:
            return 2
    elif o1 != 0 and o2 != 0 and o3 != 0 and o4 != 0:
        return 2
    elif not (
        (o1 == 0 and _on_segment(ax, ay, bx, by, cx, cy))
        or (o2 == 0 and _on_segment(ax, ay, bx, by, dx, dy))
        or (o3 == 0 and _on_segment(cx, cy, dx, dy, ax, ay))
        or (o4 == 0 and _on_segment(cx, cy, dx, dy, bx, by))
    ):
        return 0
    # They meet in exactly one point: allowed only when it is an endpoint of both.
    shared = (
        (ax == cx and ay == cy)
        or (ax == dx and ay == dy)
        or (bx == cx and by == cy)
        or (bx == dx and by == dy)
    )
    return 1 if shared else 2


@_jit
def bad_segments(
    x0: NDArray[np.float64],
    y0: NDArray[np.float64],
    x1: NDArray[np.float64],
    y1: NDArray[np.float64],
    ring: NDArray[np.int64],
    nxt: NDArray[np.int64],
    bucket: float,
) -> NDArray[np.bool_]:
    """Segments that cross, overlap or touch another segment other than at a shared endpoint
    of different rings (consecutive segments of a ring must only share their endpoint).

    Candidate pairs come from a uniform grid of ``bucket`` units: every segment is entered in
    each bucket its bounding box covers.
    """
    m = len(x0)
    bad = np.zeros(m, dtype=np.bool_)
    if m == 0:
        return bad
    gx0 = np.floor(np.minimum(x0, x1) / bucket).astype(np.int64)
    gx1 = np.floor(np.maximum(x0, x1) / bucket).astype(np.int64)
    gy0 = np.floor(np.minimum(y0, y1) / bucket).astype(np.int64)
    gy1 = np.floor(np.maximum(y0, y1) / bucket).astype(np.int64)
    bx0, by0 = gx0.min(), gy0.min()
    width = gx1.max() - bx0 + 1
    count = 0
    for s in range(m):
        count += (gx1[s] - gx0[s] + 1) * (gy1[s] - gy0[s] + 1)
    keys = np.empty(count, dtype=np.int64)
    segs = np.empty(count, dtype=np.int64)
    e = 0
    for s in range(m):
        for gy in range(gy0[s], gy1[s] + 1):
            for gx in range(gx0[s], gx1[s] + 1):
                keys[e] = (gy - by0) * width + (gx - bx0)
                segs[e] = s
                e += 1
    order = np.argsort(keys, kind="mergesort")
    keys, segs = keys[order], segs[order]
    g = 0
    while g < count:
        h = g
        while h < count and keys[h] == keys[g]:
            h += 1
        for u in range(g, h):
            s = segs[u]
            for v in range(u + 1, h):
                t = segs[v]
                c = contact(x0[s], y0[s], x1[s], y1[s], x0[t], y0[t], x1[t], y1[t])
                if c == 0:
                    continue
                if ring[s] == ring[t]:
                    adjacent = nxt[s] == t or nxt[t] == s
                    if c == 2 or not adjacent:
                        bad[s] = True
                        bad[t] = True
                elif c == 2:
                    bad[s] = True
                    bad[t] = True
        g = h
    return bad
