"""Occupied cells as few axis-aligned boxes: the walls of a box world.

One box per occupied cell, as the paper's tool did, hits Gazebo's object limit on real maps.
:func:`merge_boxes` returns the *fewest* disjoint rectangles whose union is exactly the occupied
cells: the minimum rectangle partition of a rectilinear region with holes, by the classical
construction (Lipski et al. 1979, Ohtsuki 1982; see Eppstein, "Graph-theoretic solutions to
computational geometry problems", 2010, section 3):

* a *reflex* corner is a lattice point with exactly three of its four cells occupied. Cutting from
  each reflex corner to the boundary leaves ``reflex + chi`` rectangles, ``chi`` being the Euler
  characteristic of the region (4-connected pieces minus holes);
* a *chord* joins two reflex corners through the interior along a grid line, and one cut along it
  serves both. Chords that cross or share a corner cannot both be used, so the best is a maximum
  independent set of the bipartite "crosses" graph between horizontal and vertical chords (Koenig:
  chords minus a maximum matching);
* the minimum is ``reflex - chosen chords + chi``. After cutting along the chosen chords, every
  other reflex corner is cut horizontally up to the boundary or a chosen vertical chord, and the
  pieces, all rectangles, are read off.

Vectorised over the lattice, looking at the insides of walls only where it can (no loop per cell);
the matching is Hopcroft-Karp on the chords only. On the real maps this gives 3-12 % fewer boxes
than the greedy merge (grow each row run downwards while the next row has the identical run).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["box_extents", "merge_boxes", "rasterize_boxes"]

Array = NDArray[np.int64]


def merge_boxes(occupied: NDArray[np.bool_]) -> NDArray[np.int64]:
    """The fewest disjoint axis-aligned rectangles that cover exactly the occupied cells.

    Parameters
    ----------
    occupied : bool array, shape (H, W)
        Grid order (row 0 at the lowest y, as :class:`~scan2terrain.types.OccupancyGrid`).
        Cells that touch only at a corner are not connected (a rectangle never spans them).

    Returns
    -------
    int64 array, shape (K, 4)
        One row per box: ``[row0, col0, n_rows, n_cols]`` in cells, covering rows
        ``row0 .. row0 + n_rows - 1`` and columns ``col0 .. col0 + n_cols - 1``. Boxes never
        overlap, their union is exactly the occupied cells, and no partition into rectangles has
        fewer. Sorted by (row0, col0); K = 0 for a grid with no occupied cell. Deterministic.

    Raises
    ------
    ValueError
        If ``occupied`` is not a 2D array.
    """
    occ = np.asarray(occupied)
    if occ.ndim != 2:
        raise ValueError(f"occupied must be a 2D array, got shape {occ.shape}")
    occ = occ.astype(bool, copy=False)
    rows, cols = np.flatnonzero(occ.any(axis=1)), np.flatnonzero(occ.any(axis=0))
    if rows.size == 0:
        return np.zeros((0, 4), dtype=np.int64)
    # Work on the occupied bounding box only (maps often have wide empty margins).
    r_lo, c_lo = int(rows[0]), int(cols[0])
    boxes = _partition(occ[r_lo : rows[-1] + 1, c_lo : cols[-1] + 1])
    boxes[:, 0] += r_lo
    boxes[:, 1] += c_lo
    return boxes


def _partition(occ: NDArray[np.bool_]) -> Array:
    """:func:`merge_boxes` on a grid with at least one occupied cell."""
    h, w = occ.shape

    # Lattice point (i, j), 0 <= i <= H, 0 <= j <= W, is the corner between cell rows i-1, i and
    # cell columns j-1, j. Its four cells: lower-left, lower-right, upper-left, upper-right.
    padded = np.zeros((h + 2, w + 2), dtype=bool)
    padded[1:-1, 1:-1] = occ
    ll, lr, ul, ur = padded[:-1, :-1], padded[:-1, 1:], padded[1:, :-1], padded[1:, 1:]
    n = ll.astype(np.int8) + lr + ul + ur
    reflex = n == 3
    interior = n == 4
    # A reflex corner's cut runs away from its free cell: rightwards if that cell is on the left.
    goes_right = reflex & ~(ll & ul)
    goes_left = reflex & ~(lr & ur)
    goes_up = reflex & ~(ll & lr)
    goes_down = reflex & ~(ul & ur)

    horizontal = _chords(interior, goes_right, goes_left)  # (line i, j0, j1)
    vertical = _chords(interior.T, goes_up.T, goes_down.T)  # (line j, i0, i1)
    keep_h, keep_v = _independent_chords(horizontal, vertical)
    horizontal, vertical = horizontal[keep_h], vertical[keep_v]

    # Reflex corners that no chosen chord ends at are cut horizontally, up to the boundary or to
    # a chosen vertical chord (which passes through interior lattice points only).
    resolved = np.zeros_like(reflex)
    resolved[horizontal[:, 0], horizontal[:, 1]] = True
    resolved[horizontal[:, 0], horizontal[:, 2]] = True
    resolved[vertical[:, 1], vertical[:, 0]] = True
    resolved[vertical[:, 2], vertical[:, 0]] = True
    crossed = _marked_ranges(vertical, shape=(w + 1, h + 1), exclusive=True).T
    stop = ~interior | crossed
    extensions = _extensions(reflex & ~resolved, goes_right, stop)

    # Cuts as walls between cells: hwall[i, c] separates cells (i-1, c) and (i, c);
    # vwall[r, j] separates cells (r, j-1) and (r, j).
    hwall = _marked_ranges(np.concatenate([horizontal, extensions]), shape=(h + 1, w))
    vwall = _marked_ranges(vertical, shape=(w + 1, h)).T
    return _pieces(occ, hwall, vwall)


def _chords(interior: NDArray[np.bool_], start: NDArray[np.bool_], end: NDArray[np.bool_]) -> Array:
    """Chords along the first axis' lines: from a ``start`` corner forwards (+ along axis 1) over
    interior lattice points to an ``end`` corner. Rows ``(line, from, to)``, from < to."""
    li, pj = np.nonzero(start)
    # The first non-interior point after pj (a start corner has occupied cells ahead, so pj + 1
    # is on the lattice): a chord iff it is an end corner.
    to = _stop_at(~interior, li, pj + 1, forward=True)
    ok = end[li, to]
    return np.stack([li[ok], pj[ok], to[ok]], axis=1).astype(np.int64).reshape(-1, 3)


def _stop_at(stop: NDArray[np.bool_], li: Array, pj: Array, *, forward: bool) -> Array:
    """For each query point (li, pj): the first index k >= pj (``forward``) or the last k <= pj
    with ``stop[li, k]``. Every line must start and end with a stop point (lattice and cell lines
    of a padded grid do), so runs of non-stop points never cross lines. Works on the non-stop
    points only, which are few (the insides of walls), not on the whole grid."""
    points = stop.shape[1]
    li = np.asarray(li, dtype=np.int64)
    pj = np.asarray(pj, dtype=np.int64)
    runs = np.flatnonzero(~stop)  # sorted flat indices of non-stop points
    if runs.size == 0 or pj.size == 0:
        same: Array = pj.copy()
        return same
    flat = li * points + pj
    pos = np.minimum(np.searchsorted(runs, flat), runs.size - 1)
    inside = runs[pos] == flat
    heads = np.flatnonzero(np.diff(runs, prepend=runs[0] - 2) != 1)  # first element of each run
    run = np.searchsorted(heads, pos, side="right") - 1
    if forward:
        tails = np.append(heads[1:], runs.size) - 1
        found = runs[tails[run]] + 1
    else:
        found = runs[heads[run]] - 1
    out: Array = np.where(inside, found - li * points, pj)
    return out


def _independent_chords(horizontal: Array, vertical: Array) -> tuple[Array, Array]:
    """Indices of a largest set of chords no two of which cross or share a corner (Koenig)."""
    nh, nv = len(horizontal), len(vertical)
    all_h, all_v = np.arange(nh), np.arange(nv)
    if nh == 0 or nv == 0:
        return all_h, all_v
    # Crossing pairs: a vertical chord's line within the horizontal chord's span, and back.
    order = np.argsort(vertical[:, 0], kind="stable")
    vline = vertical[order, 0]
    lo = np.searchsorted(vline, horizontal[:, 1], side="left")
    hi = np.searchsorted(vline, horizontal[:, 2], side="right")
    counts = hi - lo
    hidx = np.repeat(all_h, counts)
    starts = np.repeat(lo - np.cumsum(counts) + counts, counts)
    vidx = order[starts + np.arange(hidx.size)]
    row = horizontal[hidx, 0]
    cross = (vertical[vidx, 1] <= row) & (row <= vertical[vidx, 2])
    hidx, vidx = hidx[cross], vidx[cross]
    if hidx.size == 0:
        return all_h, all_v

    # Adjacency lists of the (small, sparse) crossing graph, horizontal -> vertical.
    order = np.argsort(hidx, kind="stable")
    bounds = np.searchsorted(hidx[order], np.arange(nh + 1)).tolist()
    targets = vidx[order].tolist()
    adjacency = [targets[bounds[i] : bounds[i + 1]] for i in range(nh)]
    match_h, match_v = _max_matching(adjacency, nv)
    # Koenig: Z = everything reachable from unmatched horizontal chords along alternating paths
    # (h -> v by any edge, v -> h by its matching edge). A largest independent set is
    # (horizontal in Z) + (vertical not in Z).
    reached_h = [m == -1 for m in match_h]
    reached_v = [False] * nv
    queue = [u for u in range(nh) if reached_h[u]]
    for u in queue:  # grows while walking
        for v in adjacency[u]:
            if not reached_v[v]:
                reached_v[v] = True
                w = match_v[v]  # matched: else there would be an augmenting path
                if not reached_h[w]:
                    reached_h[w] = True
                    queue.append(w)
    return np.flatnonzero(reached_h), np.flatnonzero(np.logical_not(reached_v))


def _max_matching(adjacency: list[list[int]], n_right: int) -> tuple[list[int], list[int]]:
    """Hopcroft-Karp maximum matching of a bipartite graph given as left -> right adjacency
    lists; returns (right of each left vertex, left of each right vertex), -1 if unmatched.

    Plain Python over the chords (a few hundred to thousands of vertices): cheaper than importing
    scipy.sparse for it, and O(E sqrt(V)) like scipy's."""
    n_left = len(adjacency)
    match_l = [-1] * n_left
    match_r = [-1] * n_right
    while True:
        # Layers by BFS from the free left vertices, over alternating paths.
        dist = [-1] * n_left
        queue = [u for u in range(n_left) if match_l[u] == -1]
        for u in queue:
            dist[u] = 0
        found = False
        for u in queue:  # grows while walking
            for v in adjacency[u]:
                w = match_r[v]
                if w == -1:
                    found = True
                elif dist[w] == -1:
                    dist[w] = dist[u] + 1
                    queue.append(w)
        if not found:
            return match_l, match_r
        # Vertex-disjoint shortest augmenting paths, by iterative DFS along the layers.
        ptr = [0] * n_left
        for root in range(n_left):
            if match_l[root] != -1:
                continue
            stack, via = [root], []
            while stack:
                u = stack[-1]
                step = False
                while ptr[u] < len(adjacency[u]):
                    v = adjacency[u][ptr[u]]
                    ptr[u] += 1
                    w = match_r[v]
                    if w == -1:
                        via.append(v)
                        for a, b in zip(stack, via, strict=True):
                            match_l[a], match_r[b] = b, a
                        stack = []
                        step = True
                        break
                    if dist[w] == dist[u] + 1:
                        via.append(v)
                        stack.append(w)
                        step = True
                        break
                if not step:  # dead end: out of the layered graph for this phase
                    dist[u] = -2
                    stack.pop()
                    if via:
                        via.pop()


def _marked_ranges(
    segments: Array, *, shape: tuple[int, int], exclusive: bool = False
) -> NDArray[np.bool_]:
    """Boolean (lines, positions) array, True on ``[a, b)`` of each ``(line, a, b)`` segment, or
    on the open range ``(a, b)`` when ``exclusive``."""
    out = np.zeros((shape[0], shape[1] + 1), dtype=np.int64)
    seg = segments.reshape(-1, 3)
    a = seg[:, 1] + (1 if exclusive else 0)
    np.add.at(out, (seg[:, 0], a), 1)
    np.add.at(out, (seg[:, 0], seg[:, 2]), -1)
    marked: NDArray[np.bool_] = out.cumsum(axis=1)[:, : shape[1]] > 0
    return marked


def _extensions(
    corners: NDArray[np.bool_], goes_right: NDArray[np.bool_], stop: NDArray[np.bool_]
) -> Array:
    """Horizontal cuts from ``corners`` to the first ``stop`` point in their direction, as
    ``(line i, j0, j1)`` segments of cell columns ``j0 .. j1 - 1``."""
    ci, cj = np.nonzero(corners)
    right = goes_right[ci, cj]
    # Corners are stop points themselves: look from the next point on. A corner has occupied
    # cells on the side it cuts towards, so that next point is on the lattice.
    to_right = _stop_at(stop, ci[right], cj[right] + 1, forward=True)
    to_left = _stop_at(stop, ci[~right], cj[~right] - 1, forward=False)
    segs = np.concatenate(
        [
            np.stack([ci[right], cj[right], to_right], axis=1),
            np.stack([ci[~right], to_left, cj[~right]], axis=1),
        ]
    )
    return segs.astype(np.int64).reshape(-1, 3)


def _pieces(occ: NDArray[np.bool_], hwall: NDArray[np.bool_], vwall: NDArray[np.bool_]) -> Array:
    """The rectangles left between the walls: each starts at a cell with a wall (or nothing)
    on its left and below, and runs right and up to the next wall."""
    h, w = occ.shape
    # Breaks between neighbours: before column j (j = 0 .. W), before row i (i = 0 .. H).
    pad_c = np.zeros((h, w + 2), dtype=bool)
    pad_c[:, 1:-1] = occ
    col_break = ~(pad_c[:, :-1] & pad_c[:, 1:]) | vwall  # (H, W + 1)
    pad_r = np.zeros((h + 2, w), dtype=bool)
    pad_r[1:-1] = occ
    row_break = ~(pad_r[:-1] & pad_r[1:]) | hwall  # (H + 1, W)
    start = occ & col_break[:, :-1] & row_break[:-1]
    r0, c0 = np.nonzero(start)
    n_cols = _stop_at(col_break, r0, c0 + 1, forward=True) - c0
    n_rows = _stop_at(np.ascontiguousarray(row_break.T), c0, r0 + 1, forward=True) - r0
    return np.stack([r0, c0, n_rows, n_cols], axis=1).astype(np.int64).reshape(-1, 4)


def rasterize_boxes(boxes: NDArray[np.int64], shape: tuple[int, int]) -> NDArray[np.int64]:
    """How many boxes cover each cell: the inverse of :func:`merge_boxes`, for checks.

    Parameters
    ----------
    boxes : int array, shape (K, 4)
        ``[row0, col0, n_rows, n_cols]`` in cells, as :func:`merge_boxes` returns.
    shape : (H, W)
        Grid shape.

    Returns
    -------
    int64 array, shape (H, W)
        Per cell, the number of boxes covering it (an exact, disjoint cover gives 0 and 1 only).

    Raises
    ------
    ValueError
        If a box is empty or reaches outside the grid.
    """
    h, w = shape
    b = np.asarray(boxes, dtype=np.int64).reshape(-1, 4)
    r0, c0, r1, c1 = b[:, 0], b[:, 1], b[:, 0] + b[:, 2], b[:, 1] + b[:, 3]
    if b.size and (b[:, 2:].min() < 1 or r0.min() < 0 or c0.min() < 0):
        raise ValueError("boxes must have positive sizes and non-negative corners")
    if b.size and (r1.max() > h or c1.max() > w):
        raise ValueError(f"boxes reach outside a grid of shape {shape}")
    # 2D difference array: +1 at the first corner, -1 past each edge, +1 past both.
    diff = np.zeros((h + 1, w + 1), dtype=np.int64)
    np.add.at(diff, (r0, c0), 1)
    np.add.at(diff, (r0, c1), -1)
    np.add.at(diff, (r1, c0), -1)
    np.add.at(diff, (r1, c1), 1)
    counts: NDArray[np.int64] = diff.cumsum(axis=0).cumsum(axis=1)[:h, :w]
    return counts


def box_extents(
    boxes: NDArray[np.int64], resolution: float, origin_xy: tuple[float, float]
) -> NDArray[np.float64]:
    """Boxes in cells to their extents in metres: ``[x_min, y_min, x_max, y_max]`` per box.

    Parameters
    ----------
    boxes : int array, shape (K, 4)
        ``[row0, col0, n_rows, n_cols]``, as :func:`merge_boxes` returns.
    resolution : float
        Cell side, metres.
    origin_xy : (x, y)
        Map-frame position (metres) of the lower-left corner of cell (0, 0) of a grid whose axes
        are the map's axes (no yaw: rotate the grid first, see ``grids.axis_align``).

    Returns
    -------
    float64 array, shape (K, 4)
        Map-frame extents in metres.
    """
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    ox, oy = origin_xy
    x0 = ox + b[:, 1] * resolution
    y0 = oy + b[:, 0] * resolution
    x1 = ox + (b[:, 1] + b[:, 3]) * resolution
    y1 = oy + (b[:, 0] + b[:, 2]) * resolution
    return np.stack([x0, y0, x1, y1], axis=1)
