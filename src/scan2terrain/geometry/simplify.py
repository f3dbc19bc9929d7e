"""Outline simplification (:func:`simplify`), over the exact outlines of
:mod:`scan2terrain.geometry.outlines`.

Douglas-Peucker, constrained by the grid: a run of outline may become one straight edge
only if every point of it lies within the tolerance, no cell centre lies in the region
between the two, and the new edge passes no cell centre closer than 0.15 cell. So the
simplified polygons cover exactly the same cell centres as the exact ones, and no wall or
gap one cell wide becomes thinner than 0.3 cell. Candidate vertices are the corners and
the cell-edge midpoints half a cell from each corner, which let a staircase become one
straight edge through the midpoints of its steps; Douglas-Peucker keeps the farthest point,
so it runs twice per ring, once with the corners and once (from a tolerance of 0.35 cell,
the corner's distance to such a chamfer) with the midpoints instead of the corners they
flank, and the ring keeps the result with fewer vertices. Afterwards edges that cross or
touch another (found with a uniform-grid index), and rings crossing at a shared vertex, get
their farthest point back until none is left. Because no centre changes side of any ring,
rings keep their nesting: holes stay in their exteriors and islands in their holes, and no
ring collapses. The loops run compiled (numba, ``_outline_kernels.py``).

Why this and not plain Douglas-Peucker or a library (shapely's topology-preserving
simplifier): with a tolerance of one cell, plain Douglas-Peucker collapses every wall one
cell thick (on the Willow Garage map its cells match the source with an IoU of 0.40), and
nothing keeps a small hole inside its exterior. Exact cell coverage is the property the
tests, the simulator and the user can check.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from scan2terrain.geometry.outlines import (
    CHAMFER,
    Polygon,
    _Rings,
    check_resolution,
    flatten,
    ring_area2,
    unflatten,
)
from scan2terrain.types import Pose2D


def simplify(
    polygons: list[Polygon], tolerance_m: float, *, resolution: float, origin: Pose2D
) -> list[Polygon]:
    """Straighten traced outlines within ``tolerance_m`` without moving any cell centre across.

    Parameters
    ----------
    polygons : list of Polygon
        Outlines traced on the grid given by ``resolution`` and ``origin`` (:func:`trace`, or an
        earlier :func:`simplify` of them): every vertex a cell corner or a cell-edge midpoint.
    tolerance_m : float
        Largest distance, metres, of any point of the exact outline from the simplified one,
        >= 0.
    resolution : float
        Cell side of that grid, metres.
    origin : Pose2D
        Pose of that grid's lower-left corner in the map frame.

    Returns
    -------
    list of Polygon
        Same polygons and holes, in the same order, usually with fewer vertices. Vertices are
        points of the exact outline: kept corners, or cell-edge midpoints half a cell from a
        corner (so a staircase can become one straight edge). Guarantees: rings stay simple;
        rings touch only at diagonal-contact corners that both kept; holes stay inside their
        exteriors, islands inside their holes; ``rasterize`` gives exactly the same cells as
        for the input (no cell centre lies in a region a straightened edge sweeps over); and
        no new edge passes closer than 0.15 cell to a cell centre, so walls and gaps one cell
        wide keep at least 0.3 cell. Every ring encloses a cell centre, so none collapses; a
        ring that ends with fewer than three vertices would be dropped (with its holes), which
        only polygons that enclose no cell centre can cause.

    Raises
    ------
    ValueError
        If ``tolerance_m`` is negative or not finite, or a vertex is not a cell corner or a
        cell-edge midpoint of that grid, or the outlines cross each other.
    """
    from scan2terrain.geometry import _outline_kernels as kern

    if not (tolerance_m >= 0 and math.isfinite(tolerance_m)):
        raise ValueError(f"tolerance_m must be a finite number >= 0, got {tolerance_m}")
    check_resolution(resolution)
    if not polygons:
        return []

    rings = flatten(polygons)
    hx, hy = _to_half_cells(rings.xy, resolution, origin)
    tol = 2.0 * tolerance_m / resolution  # half cells
    cand = _candidates(hx, hy, rings.start)
    # Douglas-Peucker picks the farthest point, so given corners it keeps corners; run it
    # once over corners and midpoints, once with the midpoints in place of the corners they
    # flank, and keep, per ring, whichever ends with fewer vertices.
    keep = np.zeros(len(cand.x), dtype=bool)
    complete = kern.simplify_rings(cand.x, cand.y, cand.sel, cand.start, keep, tol)
    sel = cand.sel
    if tol >= CHAMFER:
        keep_c = np.zeros(len(cand.x), dtype=bool)
        complete_c = kern.simplify_rings(cand.x, cand.y, cand.sel_c, cand.start, keep_c, tol)
        n_rings = len(cand.start) - 1
        fewer = np.bincount(cand.ring[keep_c], minlength=n_rings) < np.bincount(
            cand.ring[keep], minlength=n_rings
        )
        fewer &= complete_c
        keep = np.where(fewer[cand.ring], keep_c, keep)
        sel = np.where(fewer[cand.ring], cand.sel_c, cand.sel)
        complete |= fewer
    if not complete.all():
        raise ValueError("an outline is not made of cell edges of this grid")
    for _ in range(len(cand.x) + 1):
        seg = _segments(keep, cand.ring)
        bad = kern.bad_segments(
            cand.x[seg.a], cand.y[seg.a], cand.x[seg.b], cand.y[seg.b], seg.ring, seg.nxt, 16.0
        )
        bad |= _crossing_corners(cand.x, cand.y, seg)
        if not bad.any():
            break
        split = kern.split_segments(
            cand.x, cand.y, sel, cand.start, seg.ring, seg.a, seg.b, bad, keep, tol
        )
        if split == 0:
            raise ValueError("the outlines cross or touch along an edge: not traced on this grid")
    else:  # pragma: no cover - every round keeps at least one more point
        raise RuntimeError("simplify did not converge")
    keep &= ~_collinear(cand.x, cand.y, keep, cand.ring)
    return _rings_out(rings, cand, keep, resolution, origin)


@dataclass(frozen=True)
class _Candidates:
    """The outline of every ring as points in half cells: its vertices and, on axis-parallel
    edges, the points half a cell from each end; ``sel`` marks those that may become vertices
    of the simplified ring."""

    x: NDArray[np.float64]
    y: NDArray[np.float64]
    sel: NDArray[np.bool_]
    sel_c: NDArray[np.bool_]
    start: NDArray[np.int64]  #: (R + 1,) ring k's candidates are start[k]:start[k + 1]
    ring: NDArray[np.int64]  #: ring of each candidate


@dataclass(frozen=True)
class _Segments:
    """Segments between consecutive kept candidates: a -> b (candidate indices)."""

    a: NDArray[np.int64]
    b: NDArray[np.int64]
    ring: NDArray[np.int64]
    nxt: NDArray[np.int64]  #: index of the next segment of the same ring
    prv: NDArray[np.int64]  #: index of the previous segment of the same ring


def _to_half_cells(
    xy: NDArray[np.float64], resolution: float, origin: Pose2D
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Map frame -> grid coordinates in half cells, snapped to integers (checked)."""
    c, s = math.cos(origin.yaw), math.sin(origin.yaw)
    dx, dy = xy[:, 0] - origin.x, xy[:, 1] - origin.y
    gx = 2.0 * (c * dx + s * dy) / resolution
    gy = 2.0 * (-s * dx + c * dy) / resolution
    rx, ry = np.rint(gx), np.rint(gy)
    off = np.abs(gx - rx) + np.abs(gy - ry)
    on_lattice = (off <= 1e-6 * np.maximum(1.0, np.abs(rx) + np.abs(ry))) & ~(
        (rx % 2 == 1) & (ry % 2 == 1)
    )
    if not on_lattice.all():
        k = int(np.argmin(on_lattice))
        raise ValueError(
            f"vertex {tuple(xy[k])} is not a cell corner or cell-edge midpoint of the grid"
            f" (resolution {resolution}, origin {origin})"
        )
    return rx, ry


def _candidates(
    hx: NDArray[np.float64], hy: NDArray[np.float64], start: NDArray[np.int64]
) -> _Candidates:
    """Each vertex, then along an axis-parallel edge the points half a cell (1 unit) from each
    end: the chamfer points that let a staircase become straight. ``sel`` selects them all,
    ``sel_c`` all but the vertices with a chamfer point on both sides."""
    n = len(hx)
    nxt = np.arange(1, n + 1, dtype=np.int64)
    nxt[start[1:] - 1] = start[:-1]
    ex, ey = hx[nxt] - hx, hy[nxt] - hy
    axis = (ex == 0) | (ey == 0)
    length = np.abs(ex) + np.abs(ey)
    first = axis & (length >= 2)
    second = axis & (length >= 3)
    count = 1 + first.astype(np.int64) + second.astype(np.int64)
    ux, uy = np.sign(ex), np.sign(ey)
    pos = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(count, out=pos[1:])
    x = np.empty(int(pos[-1]))
    y = np.empty(int(pos[-1]))
    x[pos[:-1]], y[pos[:-1]] = hx, hy
    i1 = pos[:-1][first] + 1
    x[i1], y[i1] = (hx + ux)[first], (hy + uy)[first]
    i2 = pos[:-1][second] + 2
    x[i2], y[i2] = (hx[nxt] - ux)[second], (hy[nxt] - uy)[second]
    sel_c = np.ones(len(x), dtype=bool)
    prev = np.empty(n, dtype=np.int64)
    prev[nxt] = np.arange(n, dtype=np.int64)
    sel_c[pos[:-1]] = ~(first & first[prev])
    cstart = pos[start]
    ring = np.repeat(np.arange(len(start) - 1, dtype=np.int64), np.diff(cstart))
    return _Candidates(x, y, np.ones(len(x), dtype=bool), sel_c, cstart, ring)


def _segments(keep: NDArray[np.bool_], ring_of: NDArray[np.int64]) -> _Segments:
    a = np.nonzero(keep)[0]
    ring = ring_of[a]
    m = len(a)
    first = np.ones(m, dtype=bool)
    first[1:] = ring[1:] != ring[:-1]
    group_start = np.nonzero(first)[0]
    group_end = np.append(group_start[1:], m)
    nxt = np.arange(1, m + 1, dtype=np.int64)
    nxt[group_end - 1] = group_start
    prv = np.empty(m, dtype=np.int64)
    prv[nxt] = np.arange(m, dtype=np.int64)
    return _Segments(a, a[nxt], ring, nxt, prv)


def _crossing_corners(
    x: NDArray[np.float64], y: NDArray[np.float64], seg: _Segments
) -> NDArray[np.bool_]:
    """Segments at a vertex kept by two rings that cross there.

    Rings may touch at a shared vertex (a diagonal contact) but not cross: the two directions
    of one ring (to its next and its previous vertex) must not separate the two directions of
    the other. Whether the touching rings still nest as before is not a local question; it
    follows from the cell centres (see :func:`simplify`).
    """
    bad = np.zeros(len(seg.a), dtype=bool)
    vx, vy = x[seg.a], y[seg.a]
    order = np.lexsort((vy, vx))
    same = (vx[order][1:] == vx[order][:-1]) & (vy[order][1:] == vy[order][:-1])
    if not same.any():
        return bad
    s1, s2 = order[:-1][same], order[1:][same]

    def angles(s: NDArray[np.int64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Directions to the next and the previous vertex at the vertex starting segment s."""
        nb_, pb_ = seg.b[s], seg.a[seg.prv[s]]
        out = np.arctan2(y[nb_] - vy[s], x[nb_] - vx[s])
        back = np.arctan2(y[pb_] - vy[s], x[pb_] - vx[s])
        return out, back

    def inside(d: NDArray[np.float64], u: NDArray[np.float64], w: NDArray[np.float64]) -> Any:
        span = np.mod(w - u, 2 * math.pi)
        at = np.mod(d - u, 2 * math.pi)
        return (at > 0) & (at < span)

    out1, back1 = angles(s1)
    out2, back2 = angles(s2)
    cross = inside(out2, out1, back1) != inside(back2, out1, back1)
    for s in (s1[cross], s2[cross]):
        bad[s] = True
        bad[seg.prv[s]] = True
    return bad


def _collinear(
    x: NDArray[np.float64],
    y: NDArray[np.float64],
    keep: NDArray[np.bool_],
    ring_of: NDArray[np.int64],
) -> NDArray[np.bool_]:
    """Kept candidates lying straight between their kept neighbours (not at a shared vertex)."""
    seg = _segments(keep, ring_of)
    a, b, p = seg.a, seg.b, seg.a[seg.prv]
    cross = (x[a] - x[p]) * (y[b] - y[p]) - (y[a] - y[p]) * (x[b] - x[p])
    dot = (x[a] - x[p]) * (x[b] - x[a]) + (y[a] - y[p]) * (y[b] - y[a])
    straight = (cross == 0) & (dot > 0)
    # Vertices another ring also kept stay: there the rings touch at a vertex, not an edge.
    order = np.lexsort((y[a], x[a]))
    dup = np.zeros(len(a), dtype=bool)
    same = (x[a][order][1:] == x[a][order][:-1]) & (y[a][order][1:] == y[a][order][:-1])
    dup[order[:-1][same]] = True
    dup[order[1:][same]] = True
    out = np.zeros(len(keep), dtype=bool)
    out[a[straight & ~dup]] = True
    return out


def _rings_out(
    rings: _Rings, cand: _Candidates, keep: NDArray[np.bool_], resolution: float, origin: Pose2D
) -> list[Polygon]:
    """Kept candidates back to map-frame polygons; rings left without area are dropped."""
    kept = np.nonzero(keep)[0]
    counts = np.bincount(cand.ring[kept], minlength=rings.count)
    start = np.zeros(rings.count + 1, dtype=np.int64)
    np.cumsum(counts, out=start[1:])
    hx, hy = cand.x[kept], cand.y[kept]
    area2 = ring_area2(np.stack([hx, hy], axis=1), start)
    alive = (counts >= 3) & (area2 != 0)
    # A hole whose exterior is gone goes too.
    ext_alive = np.zeros(int(rings.owner.max()) + 1, dtype=bool)
    ext_alive[rings.owner[~rings.is_hole]] = alive[~rings.is_hole]
    alive &= ext_alive[rings.owner]
    x, y = origin.transform(hx * (0.5 * resolution), hy * (0.5 * resolution))
    flat = _Rings(np.stack([x, y], axis=1), start, rings.owner, rings.is_hole)
    return unflatten(flat, alive)
