"""Caps of polygons with many holes, triangulated tile by tile (:func:`tiled_cap`).

Earcut joins each hole to the outline by scanning the outline for a bridge, so its cost grows
as holes times points (mapbox/earcut.hpp#124: minutes at 800 x 800 speckled cells, hours at
1500 x 1500), and on thousands of holes it sometimes returns triangles that no local repair
can mend. So a polygon with many holes (or whose earcut output failed its checks) is cut along
axis-parallel lines into tiles of about :data:`TILE_POINTS` points, each tile's pieces are
triangulated as ordinary caps (earcut, checked and repaired), and the points the cuts made
are taken out again: each one's triangles are replaced by a strict ear clipping of the loop
around it (:func:`strict_ears`), so the cap uses the outline's own points only and its
boundary edges are exactly the outline edges, as for any other cap.

The cut lines lie between the distinct coordinates of the points (never through one, never
along an edge), so a cut crosses edges only at their interiors: each crossing is a new point
on that edge (taken out at the end, which leaves the edge whole), and the pieces of a tile
are found by the even-odd rule along each cut line. A piece whose triangulation fails is cut
again, finer.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from scan2terrain.geometry._cap_repair import strict_ears

#: Polygons with more holes than this are triangulated tile by tile.
MANY_HOLES = 64

#: About how many points a tile holds: earcut's hole bridging stays cheap within one.
TILE_POINTS = 1024

#: How often a piece whose triangulation failed is cut again (each time into at least 2 x 2).
_RETRIES = 6

Triangulate = Callable[
    [NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]],
    tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.bool_]],
]
"""Pieces (points, ring starts, polygon of each ring) -> triangles (point indices, counter-
clockwise), the piece of each triangle, and which pieces failed (their triangles left out)."""


def tiled_cap(
    xy: NDArray[np.float64],
    rings: list[NDArray[np.int64]],
    place: NDArray[np.int64],
    triangulate: Triangulate,
    polygon: int,
) -> NDArray[np.int64]:
    """Counter-clockwise triangles covering one polygon, on the places (``place``: one index
    per point, shared by coincident vertices) of its vertices only, whose boundary edges are
    exactly the ring edges.

    ``rings`` are the polygon's rings as vertex indices into ``xy`` (exterior counter-
    clockwise, holes clockwise). Raises ValueError if the polygon is not valid (rings
    crossing) or a piece cannot be triangulated even when cut small.
    """
    tiler = _Tiler(xy, triangulate, polygon)
    size = sum(len(r) for r in rings)
    tiler.pieces(rings, max(1, int(np.ceil(np.sqrt(size / TILE_POINTS)))), _RETRIES)
    tri = np.array(tiler.tris, dtype=np.int64).reshape(-1, 3)
    # Original vertices as their places (what the rest of the cap works on); the points the
    # cuts made keep their own numbers, above every vertex's, until they are taken out.
    n = len(xy)
    steiner = np.concatenate(tiler.steiner) if tiler.steiner else np.zeros((0, 2))
    # Tile corners are made once per tile around them: one number per point.
    _, first, same = np.unique(steiner, axis=0, return_index=True, return_inverse=True)
    ids = np.concatenate([place, n + first[same.reshape(-1)]])
    tri = ids[tri]
    pts = np.concatenate([xy, steiner])
    return _take_out(pts, tri, n, polygon)


class _Tiler:
    """The cuts of one polygon: the points they made, and the pieces' triangles."""

    def __init__(self, xy: NDArray[np.float64], triangulate: Triangulate, polygon: int) -> None:
        self.xy = xy
        self.triangulate = triangulate
        self.polygon = polygon
        #: Points made by the cuts, numbered on from ``len(xy)`` in the order made.
        self.steiner: list[NDArray[np.float64]] = []
        self.count = len(xy)
        self.tris: list[tuple[int, int, int]] = []

    def points(self) -> NDArray[np.float64]:
        return np.concatenate([self.xy, *self.steiner]) if self.steiner else self.xy

    def pieces(self, rings: list[NDArray[np.int64]], side: int, retries: int) -> None:
        """Cut the rings (of one polygon, or one piece) into ``side`` x ``side`` tiles,
        triangulate the pieces, and cut again those that fail."""
        pts = self.points()
        ys = _cuts(pts[np.concatenate(rings), 1], side)
        strips = self.cut(rings, pts, ys, rotate=False)
        pts = self.points()
        xs = _cuts(pts[np.concatenate([r for _, r in strips]), 0], side)
        tiles: dict[tuple[int, int], list[NDArray[np.int64]]] = {}
        for s in sorted({s for s, _ in strips}):
            for c, ring in self.cut([r for k, r in strips if k == s], pts, xs, rotate=True):
                tiles.setdefault((s, c), []).append(ring)
        pts = self.points()
        polys = [p for key in sorted(tiles) for p in _polygons(pts, tiles[key], self.polygon)]
        flat = [r for p in polys for r in p]
        starts = np.zeros(len(flat) + 1, dtype=np.int64)
        np.cumsum([len(r) for r in flat], out=starts[1:])
        owner = np.repeat(np.arange(len(polys)), [len(p) for p in polys])
        ids = np.concatenate(flat)
        tri, _, failed = self.triangulate(pts[ids], starts, owner)
        self.tris += map(tuple, ids[tri].tolist())
        for k in np.flatnonzero(failed).tolist():
            if retries == 0:
                raise ValueError(
                    f"polygon {self.polygon} cannot be triangulated along its own edges, even"
                    f" cut into tiles (a piece of {sum(len(r) for r in polys[k])} points fails)"
                )
            self.pieces(polys[k], 2, retries - 1)

    def cut(
        self,
        rings: list[NDArray[np.int64]],
        pts: NDArray[np.float64],
        cuts: NDArray[np.float64],
        *,
        rotate: bool,
    ) -> list[tuple[int, NDArray[np.int64]]]:
        """The rings cut by the lines y = ``cuts`` (x = ``cuts`` if ``rotate``), as rings of
        the material between two lines, each with its band (0: below the first line).

        Crossings are new points (appended to ``steiner``); material lies left of every ring,
        so along a cut line the crossings alternate between the ring going down (material on
        their +x side) and going up, and each band's boundary runs along the line from one
        crossing to its neighbour there.
        """
        if len(cuts) == 0:
            return [(0, r) for r in rings]
        # Rotating a quarter turn clockwise keeps the turn of the rings: x = c becomes y = -c.
        q = np.stack([pts[:, 1], -pts[:, 0]], axis=1) if rotate else pts
        lines = -cuts[::-1] if rotate else cuts
        size = np.array([len(r) for r in rings], dtype=np.int64)
        start = np.concatenate([[0], np.cumsum(size)])
        ids = np.concatenate(rings)
        ring = np.repeat(np.arange(len(rings)), size)
        nxt = np.arange(1, len(ids) + 1)
        nxt[start[1:] - 1] = start[:-1]
        p, pn = q[ids], q[ids[nxt]]
        band = np.searchsorted(lines, p[:, 1])
        bn = band[nxt]
        # Crossings per edge, in order along it: lines band .. bn - 1 going up, down otherwise.
        count = np.abs(bn - band)
        edge = np.repeat(np.arange(len(ids)), count)
        step = np.arange(len(edge)) - np.repeat(np.cumsum(count) - count, count)
        up = bn[edge] > band[edge]
        line = np.where(up, band[edge] + step, band[edge] - 1 - step)
        y = lines[line]
        a, b = p[edge], pn[edge]
        x = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
        made = np.stack([-y, x], axis=1) if rotate else np.stack([x, y], axis=1)
        first_id = self.count
        self.steiner.append(made)
        self.count += len(made)
        # Ring sequences with the crossings in place: each vertex, then its edge's crossings.
        slot = np.arange(len(ids)) + np.concatenate([[0], np.cumsum(count)[:-1]])
        total = len(ids) + len(edge)
        seq = np.empty(total, dtype=np.int64)
        seq[slot] = ids
        cross_at = np.repeat(slot, count) + 1 + step
        seq[cross_at] = first_id + np.arange(len(edge))
        seq_ring = np.empty(total, dtype=np.int64)
        seq_ring[slot] = ring
        seq_ring[cross_at] = ring[edge]
        crossed = np.bincount(ring[edge], minlength=len(rings)) > 0
        out: list[tuple[int, NDArray[np.int64]]] = [
            (int(band[start[k]]), rings[k]) for k in np.flatnonzero(~crossed).tolist()
        ]
        if len(edge) == 0:
            return out
        # Chains: from each crossing to the next one along its ring (cyclically), in the band
        # the ring enters there. Crossing i sits at seq position cross_at[i].
        seq_start = np.concatenate([[0], np.cumsum(np.bincount(seq_ring, minlength=len(rings)))])
        nxt_cross = np.arange(1, len(edge) + 1)
        last_of_ring = np.r_[ring[edge][1:] != ring[edge][:-1], True]
        first_of_ring = np.flatnonzero(np.r_[True, last_of_ring[:-1]])
        nxt_cross[last_of_ring] = first_of_ring
        chain_band = np.where(up, line + 1, line)
        # Along each line: a chain arriving from above (down crossing) continues at the next
        # crossing in x; one arriving from below (up crossing) at the previous one.
        order = np.lexsort((x, line))
        rank = np.empty(len(order), dtype=np.int64)
        rank[order] = np.arange(len(order))
        partner_rank = np.where(up, rank - 1, rank + 1)
        ok = (partner_rank >= 0) & (partner_rank < len(order))
        partner = order[np.clip(partner_rank, 0, len(order) - 1)]
        ok &= (line[partner] == line) & (up[partner] != up)
        if not ok.all():
            raise ValueError(
                f"polygon {self.polygon} cannot be triangulated into its own area"
                " (rings crossing, or a hole outside its exterior)"
            )
        # The chain ending at crossing e (started at the crossing before it) is followed by
        # the chain starting at e's partner.
        follow = partner[nxt_cross]  # chain (named by its first crossing) -> next chain
        seq_list = seq.tolist()
        pos = cross_at.tolist()
        ring_of = ring[edge].tolist()
        lo_of = seq_start[:-1].tolist()
        hi_of = seq_start[1:].tolist()
        nxt_list = nxt_cross.tolist()
        follow_list = follow.tolist()
        bands = chain_band.tolist()
        seen = np.zeros(len(edge), dtype=bool)
        for c0 in range(len(edge)):
            if seen[c0]:
                continue
            parts: list[int] = []
            c = c0
            while not seen[c]:
                seen[c] = True
                e = nxt_list[c]
                a0, a1 = pos[c], pos[e]
                if a1 > a0:
                    parts += seq_list[a0 : a1 + 1]
                else:  # the chain wraps past the end of its ring's sequence
                    r = ring_of[c]
                    parts += seq_list[a0 : hi_of[r]] + seq_list[lo_of[r] : a1 + 1]
                c = follow_list[c]
            if c != c0:
                raise ValueError(
                    f"polygon {self.polygon} cannot be triangulated into its own area"
                    " (rings crossing, or a hole outside its exterior)"
                )
            out.append((bands[c0], np.array(parts, dtype=np.int64)))
        return out


def _cuts(values: NDArray[np.float64], side: int) -> NDArray[np.float64]:
    """``side - 1`` cut positions splitting the values into about equal parts, each halfway
    between two neighbouring distinct values (so no value is on a cut)."""
    v = np.unique(values)
    at = (np.arange(1, side) * len(v)) // side
    at = np.unique(at[(at > 0) & (at < len(v))])
    mid = 0.5 * (v[at - 1] + v[at])
    keep = (mid > v[at - 1]) & (mid < v[at])  # neighbouring floats have no value between
    cuts: NDArray[np.float64] = mid[keep]
    return cuts


def _polygons(
    pts: NDArray[np.float64], rings: list[NDArray[np.int64]], polygon: int
) -> list[list[NDArray[np.int64]]]:
    """One tile's rings as polygons: each counter-clockwise ring with the clockwise rings
    (holes, never cut: whole original holes) inside it."""
    size = np.array([len(r) for r in rings])
    ids = np.concatenate(rings)
    nxt = np.arange(1, len(ids) + 1)
    nxt[np.cumsum(size) - 1] = np.cumsum(size) - size
    ring = np.repeat(np.arange(len(rings)), size)
    local = pts[ids] - pts[ids[np.cumsum(size) - size]][ring]
    cross = local[:, 0] * local[nxt, 1] - local[nxt, 0] * local[:, 1]
    area = np.bincount(ring, cross, minlength=len(rings))
    outer = np.flatnonzero(area > 0).tolist()
    holes = np.flatnonzero(area < 0).tolist()
    polys: list[list[NDArray[np.int64]]] = [[rings[k]] for k in outer]
    if not holes:
        return polys
    if not outer:
        raise ValueError(
            f"polygon {polygon} cannot be triangulated into its own area"
            " (rings crossing, or a hole outside its exterior)"
        )
    if len(outer) == 1:
        polys[0] += [rings[k] for k in holes]
        return polys
    # A hole's edges touch other rings at most at points, so the midpoint of its first edge
    # is inside exactly the one exterior that holds it (crossing number, ray towards +x).
    test = np.array([0.5 * (pts[rings[k][0]] + pts[rings[k][1]]) for k in holes])
    home = np.full(len(holes), -1, dtype=np.int64)
    for j, k in enumerate(outer):
        e = pts[rings[k]]
        lo, hi = e.min(axis=0), e.max(axis=0)
        near = np.flatnonzero(((test >= lo) & (test <= hi)).all(axis=1) & (home < 0))
        if len(near) == 0:
            continue
        a, b = e, np.roll(e, -1, axis=0)
        tx, ty = test[near, 0:1], test[near, 1:2]
        spans = (a[:, 1] > ty) != (b[:, 1] > ty)
        with np.errstate(divide="ignore", invalid="ignore"):
            at = a[:, 0] + (ty - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
        inside = (np.count_nonzero(spans & (at > tx), axis=1) % 2) == 1
        home[near[inside]] = j
    if (home < 0).any():
        raise ValueError(
            f"polygon {polygon} cannot be triangulated into its own area"
            " (rings crossing, or a hole outside its exterior)"
        )
    for h, j in zip(holes, home.tolist(), strict=True):
        polys[j].append(rings[h])
    return polys


def _take_out(
    pts: NDArray[np.float64], tri: NDArray[np.int64], n: int, polygon: int
) -> NDArray[np.int64]:
    """The triangles with every point numbered ``n`` or more (made by a cut) taken out: the
    triangles around each such point are replaced by a strict ear clipping of the loop around
    it. A point on an outline edge has an open loop, closed by that edge (straight through the
    point), a point inside a closed one."""
    tris: list[tuple[int, int, int] | None] = [(a, b, c) for a, b, c in tri.tolist()]
    at: dict[int, set[int]] = {}
    for t, corners in enumerate(tris):
        assert corners is not None
        for v in corners:
            if v >= n:
                at.setdefault(v, set()).add(t)
    p: dict[int, tuple[float, float]] = {}
    todo = sorted(at)
    while todo:
        # A point of a cut made again in a piece that failed lies on an edge of the pieces
        # around it: until it is out, the points at that edge's ends have broken loops.
        later = []
        for s in todo:
            link: dict[int, int] = {}
            for t in sorted(at[s]):
                corners = tris[t]
                assert corners is not None
                k = corners.index(s)
                link[corners[(k + 1) % 3]] = corners[(k + 2) % 3]
            heads = set(link) - set(link.values())
            begin = min(heads) if heads else min(link)
            loop = [begin]
            while (v := link.get(loop[-1], begin)) != begin and len(loop) <= len(link):
                loop.append(v)
            if len(heads) > 1 or len(loop) != len(link) + (1 if heads else 0):
                later.append(s)
                continue
            for v in loop:
                if v not in p:
                    p[v] = (float(pts[v, 0]), float(pts[v, 1]))
            new = strict_ears(p, loop)
            if new is None or len(new) != len(loop) - 2:
                raise ValueError(
                    f"polygon {polygon} cannot be triangulated along its own edges (no ear"
                    " clipping around a point of a cut)"
                )
            for t in at.pop(s):
                corners = tris[t]
                assert corners is not None
                for v in corners:
                    if v != s and v >= n:
                        at[v].discard(t)
                tris[t] = None
            for corners in new:
                t = len(tris)
                tris.append(corners)
                for v in corners:
                    if v >= n:
                        at[v].add(t)
        if len(later) == len(todo):
            raise ValueError(
                f"polygon {polygon} cannot be triangulated along its own edges (the triangles"
                " of its tiles do not close around a point of a cut)"
            )
        todo = later
    return np.array([t for t in tris if t is not None], dtype=np.int64).reshape(-1, 3)
