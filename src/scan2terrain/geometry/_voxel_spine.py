"""Long rectangles of the voxel mesh triangulated from points on their midline, so that no
triangle turns over where a vertex on their edge was moved (for
:mod:`scan2terrain.geometry.voxel_mesh`).

Why: where solids touch only along an edge or at a corner, the mesher moves a vertex copy or a
midpoint a hair (at most ``SPLIT``, 1% of a voxel) off its rectangle's edge. A fan from a
corner or from the centre joins that point to an apex up to the rectangle's length away; the
triangle's area is its edge segment (half a voxel or more) times the apex's distance from the
edge's line (the short side, or half of it), while a move of ``d`` changes it by up to ``d``
times the far sides' lengths. Past about 25 short sides the move wins and the triangle turns
over (a sliver facing into the solid; two-storey scenes had them). Up to ``SPINE_RATIO`` short
sides long, fans keep every triangle's area more than twice what the largest move can take.

A rectangle with a moved point on its boundary and a long side over ``SPINE_RATIO`` times its
short side ``b`` is triangulated from interior points instead, the *spine*: on its midline,
from ``b / 2`` in from each short edge, evenly at most ``SPINE_STEP * b`` apart. Each long
edge is zipped to the spine (its points and the spine's merged along the long axis: a point's
segment takes the last spine point at or before its end as apex, a spine segment the last edge
point before it), each short edge is fanned from the spine's end. A triangle with two moved
points on an edge then has its exact apex ``b / 2`` from the edge and at most
``SPINE_STEP * b`` plus its segment along it; one with a single moved point (a spine segment's
apex) has that point ``b / 2`` from the spine. Either way the largest move changes its area by
less than half. The spine's points are inside the rectangle, so the boundary, and with it the
edges shared with the neighbouring faces, stays as it was: the mesh stays closed and
2-manifold. Triangles: the boundary's points + 2 per spine point - 2.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

#: Rectangles with a moved point and a long side over this many short sides get a spine.
SPINE_RATIO = 8
#: The spine's points are at most this many short sides apart.
SPINE_STEP = 4


@dataclass
class SpineTriangles:
    """The spines' points and the triangles of the rectangles they serve."""

    uv: NDArray[np.float64]  #: (Q, 2) in-plane (u, v) of the new points, lattice units
    poly_of_point: NDArray[np.int64]  #: (Q,) the polygon each new point is in
    triangles: NDArray[np.int64]  #: (T, 3) vertex ids, counter-clockwise from outside
    poly_of_triangle: NDArray[np.int64]  #: (T,)


def _group_starts(group: NDArray[np.int64]) -> NDArray[np.int64]:
    """For rows sorted by ``group``: the index of each row's group's first row."""
    new = np.ones(len(group), bool)
    new[1:] = group[1:] != group[:-1]
    first: NDArray[np.int64] = np.maximum.accumulate(np.where(new, np.arange(len(group)), 0))
    return first


def spine_triangles(
    polys: NDArray[np.int64],
    size: NDArray[np.int64],
    uv2: NDArray[np.int64],
    vid: NDArray[np.int64],
    lo: NDArray[np.int64],
    hi: NDArray[np.int64],
    reverse: NDArray[np.bool_],
    first_vertex: int,
) -> SpineTriangles:
    """Triangulate the rectangles ``polys`` (indices into the per-polygon arrays: points
    ``size``, corners ``lo`` (u0, v0) and ``hi`` (u1, v1), ``reverse``: wound clockwise in
    (u, v)), each with a spine of new vertices numbered from ``first_vertex`` (see the module
    docstring). ``uv2`` (doubled in-plane coordinates, unmoved) and ``vid`` (vertex ids) hold
    their points, polygon after polygon, in any order within one. A long side over
    ``SPINE_RATIO`` short sides is the caller's choice."""
    n = len(polys)
    rows = np.arange(n)
    lo_s, hi_s = lo[polys], hi[polys]
    ext = hi_s - lo_s
    axis = (ext[:, 1] > ext[:, 0]).astype(np.int64)  # the long axis: 0 = u, 1 = v
    long_ = ext[rows, axis]
    short = ext[rows, 1 - axis]
    count = -(-(long_ - short) // (SPINE_STEP * short)) + 1  # spine points, >= 2
    # The spine: along the long axis from lo + b/2 to hi - b/2, across at the midline.
    sp_poly = np.repeat(rows, count)
    sp_first = np.cumsum(count) - count
    index = np.arange(int(count.sum())) - sp_first[sp_poly]
    along = (
        lo_s[sp_poly, axis[sp_poly]]
        + short[sp_poly] / 2
        + index * ((long_ - short)[sp_poly] / (count - 1)[sp_poly])
    )
    across = lo_s[sp_poly, 1 - axis[sp_poly]] + short[sp_poly] / 2
    uv = np.where(axis[sp_poly, None] == 0, np.column_stack([along, across]),
                  np.column_stack([across, along]))  # fmt: skip
    sp_vid = first_vertex + np.arange(len(sp_poly))
    # The rectangles' points in (along, across), doubled.
    pt_poly = np.repeat(rows, size[polys])
    pt = np.arange(len(pt_poly))
    pa, pc, pv = uv2[pt, axis[pt_poly]], uv2[pt, 1 - axis[pt_poly]], vid
    lo_a, hi_a = 2 * lo_s[pt_poly, axis[pt_poly]], 2 * hi_s[pt_poly, axis[pt_poly]]
    lo_c = 2 * lo_s[pt_poly, 1 - axis[pt_poly]]
    hi_c = 2 * hi_s[pt_poly, 1 - axis[pt_poly]]
    tris, owners = [], []

    # Long edges zipped to the spine: chain 0 at across = lo (the spine above it), 1 at hi.
    on = (pc == lo_c) | (pc == hi_c)
    c_group = 2 * pt_poly[on] + (pc[on] == hi_c[on])
    o = np.lexsort((pa[on], c_group))
    c_group, c_along, c_vid = c_group[o], pa[on][o], pv[on][o]
    c_first = _group_starts(c_group)
    rank = np.arange(len(c_group)) - c_first
    ev_chain = rank > 0  # the chain's first point (a corner) starts it: no event
    sp_event = index > 0
    # Events of both zips: the chains' points, and the spine's points once for each chain.
    sp_rows = np.flatnonzero(sp_event)
    e_group = np.concatenate([c_group[ev_chain], 2 * sp_poly[sp_rows], 2 * sp_poly[sp_rows] + 1])
    e_along = np.concatenate([c_along[ev_chain] / 2.0, along[sp_rows], along[sp_rows]])
    e_chain = np.concatenate([np.ones(int(ev_chain.sum()), bool), np.zeros(2 * len(sp_rows), bool)])
    e_ref = np.concatenate([np.flatnonzero(ev_chain), sp_rows, sp_rows])
    o = np.lexsort((e_chain, e_along, e_group))  # spine points first where they meet a point
    e_group, e_chain, e_ref = e_group[o], e_chain[o], e_ref[o]
    first = _group_starts(e_group)
    chains_before = np.cumsum(e_chain) - e_chain
    chains_before -= chains_before[first]
    spines_before = np.cumsum(~e_chain) - ~e_chain
    spines_before -= spines_before[first]
    poly = e_group // 2
    high = (e_group % 2).astype(bool)
    # The chain's current point: its first point + the chain points already passed.
    g_first = np.searchsorted(c_group, e_group)  # the group's first chain point
    current = c_vid[g_first + chains_before]
    spine_now = sp_vid[sp_first[poly] + spines_before]
    # Below the spine (chain 0) both events give (current chain point, this, current spine
    # point): a chain point's segment from the previous one with the spine point as apex; a
    # spine point's segment back to the previous one with the chain point as apex. Above it
    # (chain 1) the same triangles wind the other way.
    this = np.empty(len(e_ref), np.int64)
    this[e_chain] = c_vid[e_ref[e_chain]]
    this[~e_chain] = sp_vid[e_ref[~e_chain]]
    t = np.column_stack([current, this, spine_now])
    t[high] = t[high][:, [0, 2, 1]]
    tris.append(t)
    owners.append(poly)

    # Short edges fanned from the spine's ends: at along = lo (from s_0), at hi (from the last).
    on = (pa == lo_a) | (pa == hi_a)
    s_group = 2 * pt_poly[on] + (pa[on] == hi_a[on])
    o = np.lexsort((pc[on], s_group))
    s_group, s_vid = s_group[o], pv[on][o]
    seg = np.flatnonzero(s_group[1:] == s_group[:-1])  # consecutive points of one edge
    f_poly = s_group[seg] // 2
    at_hi = (s_group[seg] % 2).astype(bool)
    apex = sp_vid[np.where(at_hi, sp_first[f_poly] + count[f_poly] - 1, sp_first[f_poly])]
    lower, upper = s_vid[seg], s_vid[seg + 1]  # across ascending
    tris.append(
        np.where(
            at_hi[:, None],
            np.column_stack([lower, upper, apex]),
            np.column_stack([upper, lower, apex]),
        )
    )
    owners.append(f_poly)

    triangles = np.concatenate(tris)
    owner = np.concatenate(owners)
    # Counter-clockwise in (along, across); (along, across) = (v, u) mirrors (u, v), and the
    # caller's clockwise rectangles are mirrored again.
    flip = (axis[owner] == 1) ^ reverse[polys[owner]]
    triangles[flip] = triangles[flip][:, [0, 2, 1]]
    return SpineTriangles(uv, polys[sp_poly], triangles, polys[owner])
