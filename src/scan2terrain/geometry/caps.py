"""Cap triangulation of extruded outlines: convex rings take a fan, the others go to earcut on
jittered points (:func:`_jitter`: outlines are full of exactly collinear points), then are
checked and repaired along their own edges (:mod:`scan2terrain.geometry._cap_repair`)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from scan2terrain.geometry._cap_repair import _Cap, needs_repair, twice_areas
from scan2terrain.geometry._cap_tiles import MANY_HOLES, tiled_cap
from scan2terrain.geometry.contacts import SharedPoints, angles
from scan2terrain.geometry.outlines import ring_area2


def _caps(
    xy: NDArray[np.float64],
    start: NDArray[np.int64],
    owner: NDArray[np.int64],
    shared: SharedPoints,
) -> NDArray[np.int64]:
    """Counter-clockwise triangles (vertex indices) covering every polygon, whose boundary
    edges are exactly the outline edges (with the sector vertices of :class:`SharedPoints`):
    a fan for convex polygons without holes, earcut (then repaired, see :class:`_Cap`) for
    the others, tile by tile (:func:`tiled_cap`) for those with many holes or whose earcut
    output is beyond repair."""
    tri, _, _ = _triangulate(xy, start, owner, shared, tiles=True)
    return tri


def _triangulate(  # noqa: PLR0915 (one triangulation, its repair steps in order)
    xy: NDArray[np.float64],
    start: NDArray[np.int64],
    owner: NDArray[np.int64],
    shared: SharedPoints,
    *,
    tiles: bool,
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.bool_]]:
    """:func:`_caps`' triangles, the polygon of each, and which polygons failed. With
    ``tiles``, none fails (polygons that cannot be triangulated raise ValueError); without
    (the pieces of a tiled polygon), those whose earcut output cannot be repaired or does
    not cover their area are left out and reported."""
    import mapbox_earcut

    # Rings of one polygon are consecutive: find each polygon's first and last ring.
    first = np.ones(len(owner), dtype=bool)
    first[1:] = owner[1:] != owner[:-1]
    poly_of_ring = np.cumsum(first) - 1
    ring_lo = np.nonzero(first)[0]
    ring_hi = np.append(ring_lo[1:], len(owner))
    n_poly = len(ring_lo)
    size = np.diff(start)
    # Strictly convex rings (every turn left by more than rounding) take a fan.
    nxt = np.arange(1, len(xy) + 1)
    nxt[start[1:] - 1] = start[:-1]
    prv = np.empty(len(xy), dtype=np.int64)
    prv[nxt] = np.arange(len(xy))
    e1, e2 = xy - xy[prv], xy[nxt] - xy
    turn = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    sharp = turn > 1e-9 * np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1)
    ring = np.repeat(np.arange(len(size)), size)
    convex = np.bincount(ring, ~sharp, minlength=len(size)) == 0
    fan = (ring_hi - ring_lo == 1) & convex[ring_lo]
    fan_rings = ring_lo[fan]
    count = size[fan_rings] - 2
    lo = np.repeat(start[fan_rings], count)
    i = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count) + 1
    fans = np.stack([lo, lo + i, lo + i + 1], axis=1)
    fan_owner = np.repeat(np.nonzero(fan)[0], count)
    # Polygons with many holes are tiled (earcut's hole bridging is quadratic in them).
    many = (ring_hi - ring_lo > MANY_HOLES + 1) if tiles else np.zeros(n_poly, dtype=bool)
    # Earcut for the others, on jittered local coordinates (see _jitter); every check of its
    # output is done for all polygons at once, the repairs (rare) one polygon at a time.
    ear_polys = np.nonzero(~fan & ~many)[0]
    place = shared.place
    first_vertex = start[ring_lo]
    poly_of_vertex = poly_of_ring[ring]
    local = _jitter(xy - xy[first_vertex[poly_of_vertex]], place, poly_of_vertex, n_poly)
    parts: list[NDArray[np.int64]] = []
    for k in ear_polys.tolist():
        r0, r1 = int(ring_lo[k]), int(ring_hi[k])
        p0, p1 = int(start[r0]), int(start[r1])
        ends = (start[r0 + 1 : r1 + 1] - p0).astype(np.uint32)
        ear = mapbox_earcut.triangulate_float64(local[p0:p1], ends)
        parts.append(ear.astype(np.int64).reshape(-1, 3) + p0)
    tri = np.concatenate(parts) if parts else np.zeros((0, 3), dtype=np.int64)
    owner_of = poly_of_vertex[tri[:, 0]]
    # Earcut winds all triangles of a polygon the same way: turn them all where that is
    # clockwise (decided on their total, which rounding cannot flip, unlike a sliver's).
    clockwise = np.bincount(owner_of, twice_areas(xy, tri), minlength=n_poly) < 0
    tri[clockwise[owner_of]] = tri[clockwise[owner_of]][:, ::-1]
    # Repairs work on points (coincident vertices as one); a triangle between two copies of
    # one point has no area and no place in the cap.
    tri = place[tri]
    keep = (tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 2] != tri[:, 0])
    tri, owner_of = tri[keep], owner_of[keep]
    is_ear = ~(fan | many)[poly_of_vertex]
    ring_edges = np.stack([place[is_ear], place[nxt[is_ear]]], axis=1)
    ring_owner = poly_of_vertex[is_ear]
    broken = needs_repair(
        xy, tri, owner_of, ring_edges=ring_edges, ring_owner=ring_owner, n_poly=n_poly
    )
    failed = np.zeros(n_poly, dtype=bool)
    if broken.any():
        fixed = [tri[~broken[owner_of]]]
        owners = [owner_of[~broken[owner_of]]]
        # Each broken polygon's triangles and outline edges as slices of arrays sorted by
        # polygon (stably: in their order), not picked out of all of them polygon by polygon.
        tri_of, tri_at = _by_polygon(owner_of, broken)
        ring_of, ring_at = _by_polygon(ring_owner, broken)
        for j, k in enumerate(np.nonzero(broken)[0].tolist()):
            try:
                cap = _Cap(xy, tri[tri_of[tri_at[j] : tri_at[j + 1]]])
                cap.repair(ring_edges[ring_of[ring_at[j] : ring_at[j + 1]]], k)
            except ValueError:
                failed[k] = True  # earcut's output beyond repair: tiled below
                continue
            fixed.append(cap.array())
            owners.append(np.full(len(fixed[-1]), k))
        tri, owner_of = np.concatenate(fixed), np.concatenate(owners)
    # Each polygon's triangles must add up to exactly its area, none turned over.
    want = np.bincount(poly_of_ring, ring_area2(xy, start), minlength=n_poly).astype(np.float64)
    tri = np.concatenate([fans, tri])
    polygon = np.concatenate([fan_owner, owner_of])
    bad = _bad_area(xy, tri, polygon, want)
    if (bad & fan).any():
        _refuse(int(owner[ring_lo[int(np.argmax(bad & fan))]]))
    failed |= bad & ~many
    if failed.any():
        keep = ~failed[polygon]
        tri, polygon = tri[keep], polygon[keep]
    if tiles:
        # Polygons with many holes, and those earcut failed, tile by tile (on points, as the
        # repaired ones; the sectors are chosen below for all).
        extra, extra_owner = [tri], [polygon]

        def pieces(
            pxy: NDArray[np.float64], pstart: NDArray[np.int64], powner: NDArray[np.int64]
        ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.bool_]]:
            pnxt = np.arange(1, len(pxy) + 1)
            pnxt[pstart[1:] - 1] = pstart[:-1]
            pprv = np.empty(len(pxy), dtype=np.int64)
            pprv[pnxt] = np.arange(len(pxy))
            return _triangulate(pxy, pstart, powner, SharedPoints(pxy, pnxt, pprv), tiles=False)

        for k in np.flatnonzero(many | failed).tolist():
            rings = [
                np.arange(start[r], start[r + 1], dtype=np.int64)
                for r in range(int(ring_lo[k]), int(ring_hi[k]))
            ]
            done = tiled_cap(xy, rings, place, pieces, int(owner[ring_lo[k]]))
            extra.append(done)
            extra_owner.append(np.full(len(done), k, dtype=np.int64))
        if len(extra) > 1:
            tri, polygon = np.concatenate(extra), np.concatenate(extra_owner)
            bad = _bad_area(xy, tri, polygon, want)
            if bad.any():
                _refuse(int(owner[ring_lo[int(np.argmax(bad))]]))
        failed[:] = False
    # Each corner at a point several vertices share takes the vertex of its sector.
    return _sector_corners(xy, tri, shared), polygon, failed


def _bad_area(
    xy: NDArray[np.float64],
    tri: NDArray[np.int64],
    polygon: NDArray[np.int64],
    want: NDArray[np.float64],
) -> NDArray[np.bool_]:
    """Per polygon: whether its triangles do not add up to exactly its area (twice ``want``),
    or one is turned over."""
    area2 = twice_areas(xy, tri)
    got = np.bincount(polygon, np.abs(area2), minlength=len(want))
    bad: NDArray[np.bool_] = ~np.isclose(got, want, rtol=1e-9, atol=1e-12) | (
        np.bincount(polygon, area2 < 0, minlength=len(want)) > 0
    )
    return bad


def _refuse(polygon: int) -> None:
    raise ValueError(
        f"polygon {polygon} cannot be triangulated into its own area"
        " (rings crossing, or a hole outside its exterior)"
    )


def _by_polygon(
    owner: NDArray[np.int64], chosen: NDArray[np.bool_]
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The items of the chosen polygons (``owner`` numbers each item's polygon), in polygon
    order and, within one, in their own order; and where each chosen polygon's run starts
    (one more entry: the end)."""
    items = np.flatnonzero(chosen[owner])
    items = items[np.argsort(owner[items], kind="stable")]
    count = np.bincount(owner[items], minlength=len(chosen))[chosen]
    return items, np.concatenate([[0], np.cumsum(count)])


def _jitter(
    pts: NDArray[np.float64], place: NDArray[np.int64], polygon: NDArray[np.int64], n_poly: int
) -> NDArray[np.float64]:
    """The points moved by a tiny deterministic amount, for earcut only; points with the same
    ``place`` (copies of one point) move together, so rings that touch still just touch.

    Outlines are full of exactly collinear points (the corners of a staircase). Earcut clips
    no ear there, gets stuck and drops points, leaving triangle edges through vertices. Moved
    into general position it triangulates cleanly; back at the true points its triangles are
    the same or have no area at all (slivers, flipped away by :class:`_Cap`), never turned
    over: the move, ``1e-3 m^2 / D`` for the shortest edge ``m`` and the extent ``D`` of each
    polygon (``polygon`` numbers the points' polygons, in order), changes a triangle's area by
    far less than the smallest area that three outline points that are not collinear span (an
    eighth of a square cell for points on the half-cell lattice).
    """
    # Successive points across rings count as edges too: that can only make the move smaller.
    edges = np.diff(pts, axis=0, append=pts[:1])
    lengths = np.einsum("ij,ij->i", edges, edges)
    lengths[(lengths == 0) | (np.append(polygon[1:], -1) != polygon)] = np.inf
    shortest = np.full(n_poly, np.inf)
    np.minimum.at(shortest, polygon, lengths)
    lo = np.full((n_poly, 2), np.inf)
    hi = np.full((n_poly, 2), -np.inf)
    np.minimum.at(lo, polygon, pts)
    np.maximum.at(hi, polygon, pts)
    extent = (hi - lo).max(axis=1)
    step = 1e-3 * shortest / np.where(extent > 0, extent, 1.0)  # shortest is squared
    step[~np.isfinite(step)] = 0.0
    # A hash of the place, not a random draw: the same bytes every run. Not a multiplicative
    # hash either: that is linear, and evenly numbered points on a line would stay on one.
    key = place.astype(np.uint64)[:, None] * np.uint64(2) + np.array([0, 1], dtype=np.uint64)
    unit = (splitmix64(key) >> np.uint64(11)).astype(np.float64) / float(1 << 53) * 2.0 - 1.0
    moved: NDArray[np.float64] = pts + unit * step[polygon][:, None]
    return moved


def splitmix64(x: NDArray[np.uint64]) -> NDArray[np.uint64]:
    """The splitmix64 finaliser (Steele, Lea, Flood 2014): a well-mixed 64-bit hash."""
    z = x + np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    mixed: NDArray[np.uint64] = z ^ (z >> np.uint64(31))
    return mixed


def _sector_corners(
    xy: NDArray[np.float64], tri: NDArray[np.int64], shared: SharedPoints
) -> NDArray[np.int64]:
    """Triangle corners at shared points renamed to the vertex of the sector they lie in."""
    t, c = np.nonzero(shared.is_shared[tri])
    if len(t) == 0:
        return tri
    tri = tri.copy()
    v = tri[t, c]
    mid = 0.5 * (xy[tri[t, (c + 1) % 3]] + xy[tri[t, (c + 2) % 3]])
    tri[t, c] = shared.sector_at(v, angles(mid - xy[v]))
    return tri
