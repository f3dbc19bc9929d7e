"""Exact outlines of the occupied cells of a grid, and rasterising back (simplification is
:mod:`scan2terrain.geometry.simplify`).

Frames and units: polygons are in the MAP frame, metres. Internally the outlines are traced on the
grid's vertex lattice: lattice point (x, y) (integers, x along columns, y along rows, 0 at the
grid's lower-left corner) is the map point ``origin.transform(x * resolution, y * resolution)``.

Tracing (:func:`trace`)
    Every cell edge between an occupied and a free cell (outside the grid counts as free) is a
    directed boundary edge with the occupied cell on its LEFT, so exteriors run counter-clockwise
    and holes clockwise. The edges are built with numpy and linked into rings by a successor
    permutation; rings are the cycles of that permutation, found by pointer doubling (labels and
    positions in O(E log E) array operations, no Python loop per edge or per ring).

Diagonal contacts
    Where two occupied cells touch only at a corner (and the other two cells there are free) the
    vertex has two incoming and two outgoing edges. Occupied cells are treated as 4-connected:
    the outline turns left there, staying with its own cell, so the two cells belong to
    different polygons that touch at that point. When both corners belong to the same ring (a
    free pocket whose only way out is the diagonal) the ring is split there, into the exterior
    and a clockwise hole touching it at that one point. So every ring is simple (no vertex
    twice, no crossing), rings touch only at such points, and every polygon is a valid OGC
    polygon with a 4-connected interior. The mesh (:mod:`scan2terrain.geometry.mesh`) gives
    each side of such a point its own vertex, which keeps it 2-manifold.

Rasterising (:func:`rasterize`)
    A crossing-number scanline over all ring edges at once: for each edge the rows whose centre
    line it crosses, the crossing columns toggled with ``bincount``, then a cumulative parity
    along each row.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from scan2terrain.types import Pose2D

__all__ = ["Polygon", "rasterize", "ring_area2", "trace"]


# Distance, in half cells, from a cell corner to the chamfer joining the cell-edge midpoints
# half a cell away on either side; from this tolerance up, chamfers replace corners.
CHAMFER = math.sqrt(0.5)


# Directions, counter-clockwise: +x, +y, -x, -y.
_DX = np.array([1, 0, -1, 0], dtype=np.int64)


_DY = np.array([0, 1, 0, -1], dtype=np.int64)


@dataclass(frozen=True)
class Polygon:
    """A polygon with holes in the map frame.

    Attributes
    ----------
    exterior : float64 array, shape (N, 2), N >= 3
        Vertices in metres, map frame, counter-clockwise, not closed (the first vertex is not
        repeated). Only corners: no vertex lies on the straight line through its neighbours.
    holes : tuple of float64 arrays, each shape (M, 2)
        Clockwise rings in metres, map frame, not closed, inside ``exterior``. A hole may touch
        the exterior or another hole at one vertex (a diagonal contact of two cells), never
        along an edge.
    """

    exterior: NDArray[np.float64]
    holes: tuple[NDArray[np.float64], ...] = ()

    def rings(self) -> tuple[NDArray[np.float64], ...]:
        """The exterior then the holes."""
        return (self.exterior, *self.holes)

    def area(self) -> float:
        """Area in square metres: exterior minus holes."""
        return sum(_signed_area(r) for r in self.rings())


def _signed_area(ring: NDArray[np.float64]) -> float:
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


@dataclass(frozen=True)
class _Rings:
    """Rings as one vertex array: ring k holds ``xy[start[k]:start[k + 1]]``."""

    xy: NDArray[np.float64]  #: (N, 2)
    start: NDArray[np.int64]  #: (R + 1,)
    owner: NDArray[np.int64]  #: (R,) polygon index of each ring
    is_hole: NDArray[np.bool_]  #: (R,)

    @property
    def count(self) -> int:
        return len(self.start) - 1

    def next_vertex(self) -> NDArray[np.int64]:
        """Index of each vertex's successor in its ring."""
        nxt = np.arange(1, len(self.xy) + 1, dtype=np.int64)
        nxt[self.start[1:] - 1] = self.start[:-1]
        return nxt


def flatten(polygons: list[Polygon]) -> _Rings:
    rings: list[NDArray[np.float64]] = []
    owner: list[int] = []
    hole: list[bool] = []
    for k, poly in enumerate(polygons):
        for j, ring in enumerate(poly.rings()):
            arr = np.asarray(ring, dtype=np.float64)
            if arr.ndim != 2 or arr.shape[1] != 2 or len(arr) < 3:
                raise ValueError(
                    f"polygon {k}: rings must be (N, 2) arrays with N >= 3, got {arr.shape}"
                )
            if not np.isfinite(arr).all():
                raise ValueError(f"polygon {k}: ring coordinates must be finite")
            rings.append(arr)
            owner.append(k)
            hole.append(j > 0)
    lengths = np.array([len(r) for r in rings], dtype=np.int64)
    start = np.zeros(len(rings) + 1, dtype=np.int64)
    np.cumsum(lengths, out=start[1:])
    xy = np.concatenate(rings) if rings else np.zeros((0, 2))
    return _Rings(
        xy, start, np.array(owner, dtype=np.int64), np.array(hole, dtype=bool).reshape(-1)
    )


def unflatten(rings: _Rings, keep: NDArray[np.bool_] | None = None) -> list[Polygon]:
    """Polygons from flat rings, in owner order; ``keep`` selects rings."""
    out: list[Polygon] = []
    current: list[NDArray[np.float64]] = []
    current_owner = -1
    for k in range(rings.count):
        if keep is not None and not keep[k]:
            continue
        ring = rings.xy[rings.start[k] : rings.start[k + 1]].copy()
        if not rings.is_hole[k]:
            if current:
                out.append(Polygon(current[0], tuple(current[1:])))
            current = [ring]
            current_owner = int(rings.owner[k])
        elif int(rings.owner[k]) == current_owner:
            current.append(ring)
    if current:
        out.append(Polygon(current[0], tuple(current[1:])))
    return out


def trace(occupied: NDArray[np.bool_], resolution: float, origin: Pose2D) -> list[Polygon]:
    """The exact outlines of the occupied cells: cell edges, holes included.

    Parameters
    ----------
    occupied : bool array, shape (H, W)
        Grid order (row 0 = lowest y), True for cells to outline.
    resolution : float
        Cell side, metres.
    origin : Pose2D
        Pose of the grid's lower-left corner in the map frame (metres, radians).

    Returns
    -------
    list of Polygon
        One polygon per 4-connected group of occupied cells, ordered by the lowest, then
        leftmost, corner of the group in grid coordinates; holes likewise. Each ring starts at
        its lowest-leftmost corner (grid coordinates). Cells touching only at a corner belong to
        different polygons (or a hole touching its exterior): see the module docstring.
        ``rasterize(trace(occ, r, o), occ.shape, r, o)`` equals ``occ`` exactly.

    Raises
    ------
    ValueError
        If ``occupied`` is not 2D or ``resolution`` is not a positive number.
    """
    occ = np.asarray(occupied)
    if occ.ndim != 2:
        raise ValueError(f"occupied must be a 2D array, got shape {occ.shape}")
    check_resolution(resolution)
    rings = _trace_lattice(occ.astype(bool, copy=False))
    if rings.count == 0:
        return []
    u = rings.xy[:, 0] * resolution
    v = rings.xy[:, 1] * resolution
    x, y = origin.transform(u, v)
    xy = np.stack([x, y], axis=1)
    return unflatten(_Rings(xy, rings.start, rings.owner, rings.is_hole))


def check_resolution(resolution: float) -> None:
    if not (resolution > 0 and math.isfinite(resolution)):
        raise ValueError(f"resolution must be a positive number, got {resolution}")


def _boundary_edges(occ: NDArray[np.bool_]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Directed boundary edges (occupied on the left), sorted by start vertex then direction.

    Returns the start vertex ids ``y * (W + 1) + x`` and the directions (0..3, see ``_DX``).
    Found from the occupied cells and their four neighbours (memory follows the occupied cells,
    not the grid: a fine wall grid is mostly free).
    """
    h, w = occ.shape
    stride = w + 1
    rows, cols = np.nonzero(occ)

    def free(dr: int, dc: int) -> NDArray[np.bool_]:
        """Whether each occupied cell's neighbour (dr, dc) is free (outside the grid is)."""
        r, c = rows + dr, cols + dc
        inside = (r >= 0) & (r < h) & (c >= 0) & (c < w)
        out: NDArray[np.bool_] = ~inside
        out[inside] = ~occ[r[inside], c[inside]]
        return out

    parts_v: list[NDArray[np.int64]] = []
    parts_d: list[NDArray[np.int64]] = []
    for (dr, dc), (dy, dx), d in (
        ((-1, 0), (0, 0), 0),  # free below: +x along row line y, from (x, y)
        ((0, -1), (1, 0), 3),  # free to the left: -y along column line x, from (x, y + 1)
        ((0, 1), (0, 1), 1),  # free to the right: +y along column line x + 1, from (x + 1, y)
        ((1, 0), (1, 1), 2),  # free above: -x along row line y + 1, from (x + 1, y + 1)
    ):
        edge = free(dr, dc)
        parts_v.append((rows[edge] + dy) * stride + (cols[edge] + dx))
        parts_d.append(np.full(int(edge.sum()), d, dtype=np.int64))
    vid = np.concatenate(parts_v).astype(np.int64, copy=False)
    dirs = np.concatenate(parts_d)
    # Keys are unique (one edge per start vertex and direction).
    order = np.argsort(vid * 4 + dirs)
    return vid[order], dirs[order]


def _cycles(nxt: NDArray[np.int64]) -> NDArray[np.int64]:
    """Label of each element of permutation ``nxt``: the smallest index of its cycle."""
    label = np.arange(len(nxt), dtype=np.int64)
    jump = nxt.copy()
    while True:
        new = np.minimum(label, label[jump])
        # Unchanged after doubling the window means every window already spans its cycle.
        if np.array_equal(new, label):
            return label
        label = new
        jump = jump[jump]


def _positions(nxt: NDArray[np.int64], label: NDArray[np.int64]) -> NDArray[np.int64]:
    """Steps from each cycle's head (its label) to each element, by list ranking."""
    n = len(nxt)
    pred = np.empty(n, dtype=np.int64)
    pred[nxt] = np.arange(n, dtype=np.int64)
    idx = np.arange(n, dtype=np.int64)
    head = label == idx
    pred[head] = idx[head]
    rank: NDArray[np.int64] = (~head).astype(np.int64)
    while True:
        step = rank[pred]
        if not step.any():
            return rank
        rank = rank + step
        pred = pred[pred]


def _trace_lattice(occ: NDArray[np.bool_]) -> _Rings:
    """Rings on the vertex lattice (float64 integer coordinates), ordered as :func:`trace`."""
    stride = occ.shape[1] + 1
    vid, dirs = _boundary_edges(occ)
    n = len(vid)
    if n == 0:
        empty = np.zeros(0, dtype=np.int64)
        return _Rings(np.zeros((0, 2)), np.zeros(1, dtype=np.int64), empty, empty.astype(bool))
    key = vid * 4 + dirs
    end = vid + _DY[dirs] * stride + _DX[dirs]
    # Successor: the outgoing edge at the end vertex, turning left first (occupied 4-connected:
    # at a diagonal contact the outline stays with its own cell), else straight, else right.
    nxt = np.full(n, -1, dtype=np.int64)
    for turn in (1, 0, 3):
        want = end * 4 + (dirs + turn) % 4
        pos = np.minimum(np.searchsorted(key, want), n - 1)
        hit = (key[pos] == want) & (nxt < 0)
        nxt[hit] = pos[hit]
    # Diagonal contacts: vertices with two outgoing edges (adjacent in the sorted edge list).
    pinch = np.nonzero(vid[1:] == vid[:-1])[0]
    out_a, out_b = pinch, pinch + 1
    label = _cycles(nxt)
    for _ in range(n):
        same = label[out_a] == label[out_b]
        if not same.any():
            break
        # Swapping the successors of the two incoming edges splits the cycle in two. Splits are
        # nested (outlines do not cross), so all of them can be done at once; loop for safety.
        pred = np.empty(n, dtype=np.int64)
        pred[nxt] = np.arange(n, dtype=np.int64)
        a, b = out_a[same], out_b[same]
        in_a, in_b = pred[a], pred[b]
        nxt[in_a], nxt[in_b] = b, a
        label = _cycles(nxt)
    pos = _positions(nxt, label)
    order = np.lexsort((pos, label))
    ring_label = label[order]
    d = dirs[order]
    first = np.ones(n, dtype=bool)
    first[1:] = ring_label[1:] != ring_label[:-1]
    ring_id = np.cumsum(first) - 1
    ring_start = np.nonzero(first)[0]
    # A vertex is a corner when the direction changes; each ring's first edge starts at its
    # lowest-leftmost vertex (edges are numbered by start vertex), always a corner.
    prev = np.arange(-1, n - 1, dtype=np.int64)
    ring_end = np.append(ring_start[1:], n)
    prev[ring_start] = ring_end - 1
    corner = d != d[prev]
    v = vid[order][corner]
    xy = np.stack([v % stride, v // stride], axis=1).astype(np.float64)
    counts = np.bincount(ring_id[corner], minlength=len(ring_start))
    start = np.zeros(len(ring_start) + 1, dtype=np.int64)
    np.cumsum(counts, out=start[1:])
    # Orientation from the exact (integer) shoelace area over the corner vertices.
    area2 = ring_area2(xy, start)
    is_hole = area2 < 0
    owner = _hole_owners(vid[order], d, ring_id, is_hole, stride)
    # Group: each exterior followed by its holes, polygons by their exterior's order.
    ring_order = np.lexsort((is_hole, owner))
    poly_index = np.cumsum(~is_hole) - 1  # polygon number of each exterior, by ring order
    owner_poly = poly_index[owner]
    return _reorder(
        _Rings(xy, start, owner_poly.astype(np.int64), is_hole), ring_order.astype(np.int64)
    )


def ring_area2(xy: NDArray[np.float64], start: NDArray[np.int64]) -> NDArray[np.float64]:
    """Twice the signed area of each ring (rings ``start[i]:start[i + 1]`` of ``xy``), summed
    about each ring's first vertex so coordinates far from the origin lose no precision; 0 for
    an empty ring."""
    sizes = np.diff(start)
    out = np.zeros(len(sizes))
    keep = sizes > 0
    if not keep.any():
        return out
    first, end = start[:-1][keep], start[1:][keep]
    ring = np.repeat(np.arange(len(first)), sizes[keep])
    local = xy - xy[first][ring]
    nxt = np.arange(1, len(xy) + 1)
    nxt[end - 1] = first
    cross = local[:, 0] * local[nxt, 1] - local[nxt, 0] * local[:, 1]
    out[keep] = np.bincount(ring, cross, minlength=len(first))
    return out


def _hole_owners(
    vid: NDArray[np.int64],
    dirs: NDArray[np.int64],
    ring_id: NDArray[np.int64],
    is_hole: NDArray[np.bool_],
    stride: int,
) -> NDArray[np.int64]:
    """The exterior ring of each ring (itself for exteriors).

    From a hole's leftmost +y edge (occupied cell to its west) the occupied run of that row is
    followed west to its first cell; the -y edge on that cell's west side belongs to a ring of
    the same 4-connected group: the exterior, or a hole lying further west, whose owner is
    then taken (pointer jumping; the chain moves strictly west, so it ends).
    """
    n_rings = len(is_hole)
    owner = np.arange(n_rings, dtype=np.int64)
    if not is_hole.any():
        return owner
    x, y = vid % stride, vid // stride
    up = (dirs == 1) & is_hole[ring_id]
    # Leftmost, then lowest, +y edge of each hole.
    cand = np.nonzero(up)[0]
    cand = cand[np.lexsort((y[cand], x[cand], ring_id[cand]))]
    firsts = cand[np.r_[True, ring_id[cand][1:] != ring_id[cand][:-1]]]
    hx, hy = x[firsts], y[firsts]
    # Run starts: -y edges, keyed by (row, column line); the edge starts at (x, row + 1).
    down = np.nonzero(dirs == 3)[0]
    dkey = (y[down] - 1) * stride + x[down]
    order = np.argsort(dkey, kind="stable")
    dkey, down = dkey[order], down[order]
    at = np.searchsorted(dkey, hy * stride + hx - 1, side="right") - 1
    owner[ring_id[firsts]] = ring_id[down[at]]
    while True:
        nxt = owner[owner]
        if np.array_equal(nxt, owner):
            return owner
        owner = nxt


def _reorder(rings: _Rings, order: NDArray[np.int64]) -> _Rings:
    lengths = np.diff(rings.start)[order]
    start = np.zeros(len(order) + 1, dtype=np.int64)
    np.cumsum(lengths, out=start[1:])
    idx = np.repeat(rings.start[:-1][order] - start[:-1], lengths) + np.arange(
        start[-1], dtype=np.int64
    )
    return _Rings(rings.xy[idx], start, rings.owner[order], rings.is_hole[order])


def rasterize(
    polygons: list[Polygon], shape: tuple[int, int], resolution: float, origin: Pose2D
) -> NDArray[np.bool_]:
    """Cells of a grid whose centres lie inside the polygons (even-odd rule, holes excluded).

    Parameters
    ----------
    polygons : list of Polygon
        Map frame, metres.
    shape : (H, W)
        Grid shape, cells.
    resolution : float
        Cell side, metres.
    origin : Pose2D
        Pose of the grid's lower-left corner in the map frame.

    Returns
    -------
    bool array, shape (H, W)
        Grid order (row 0 = lowest y). A centre exactly on a boundary counts as if it lay an
        infinitesimal step above and to the left of it (half-open crossing rule), so a centre
        on the boundary between two touching polygons counts once. Outlines from
        :func:`trace` and :func:`simplify` never pass through a centre.
    """
    check_resolution(resolution)
    h, w = int(shape[0]), int(shape[1])
    out = np.zeros((h, w), dtype=bool)
    if not polygons or h == 0 or w == 0:
        return out
    rings = flatten(polygons)
    # Map frame -> grid units (x along columns, y along rows).
    c, s = math.cos(origin.yaw), math.sin(origin.yaw)
    dx = rings.xy[:, 0] - origin.x
    dy = rings.xy[:, 1] - origin.y
    gx = (c * dx + s * dy) / resolution
    gy = (-s * dx + c * dy) / resolution
    nxt = rings.next_vertex()
    x0, y0, x1, y1 = gx, gy, gx[nxt], gy[nxt]
    lo, hi = np.minimum(y0, y1), np.maximum(y0, y1)
    # Rows whose centre line y = r + 0.5 satisfies lo <= y < hi.
    r_first = np.clip(np.ceil(lo - 0.5), 0, h).astype(np.int64)
    r_stop = np.clip(np.ceil(hi - 0.5), 0, h).astype(np.int64)
    count = np.maximum(r_stop - r_first, 0)
    total = int(count.sum())
    if total == 0:
        return out
    edge = np.repeat(np.arange(len(count)), count)
    offset = np.arange(total) - np.repeat(np.cumsum(count) - count, count)
    row = r_first[edge] + offset
    t = (row + 0.5 - y0[edge]) / (y1[edge] - y0[edge])
    xc = x0[edge] + t * (x1[edge] - x0[edge])
    # Centres c + 0.5 > xc lie to the right of the crossing: toggle from column ceil(xc - 0.5),
    # one column on when the crossing falls exactly on a centre (it then lies right of it).
    col = np.clip(np.floor(xc - 0.5).astype(np.int64) + 1, 0, w)
    toggles = np.bincount(row * (w + 1) + col, minlength=h * (w + 1)).reshape(h, w + 1)
    parity = np.cumsum(toggles[:, :w], axis=1) & 1
    out[:] = parity.astype(bool)
    return out
