"""Walls as one watertight triangle mesh extruded from outlines (the files: exporters.meshfile).

Frames and units: vertices are in the MAP frame, metres, z up. Faces wind counter-clockwise seen
from outside (right-hand normals point out of the solid).

:func:`extrude` builds, per polygon (:class:`scan2terrain.geometry.outlines.Polygon`), a prism:
each outline edge becomes one wall quad (two triangles) and the polygon, holes included, is
triangulated once for the top and once for the bottom cap, using only the outline's own
vertices, so every boundary edge of a cap is exactly a wall quad's edge (no T-junctions) and
every edge of the mesh belongs to exactly two faces. Where rings touch at a point (a diagonal
contact of two cells) the point has one vertex per sector of material around it, each moved a
hair into its own sector (:data:`SPLIT`): the mesh stays 2-manifold there even for readers that
merge vertices by position (STL holds no indices; trimesh and Gazebo's assimp weld equal
positions), and the solids stand about a millimetre apart instead of sharing a vertical line.

Caps: convex polygons without holes (most wall pieces: rectangles) take a fan; the others go to
earcut, on points moved by a tiny deterministic jitter (:func:`_jitter`), because outlines are
full of exactly collinear points (the corners of staircases) on which ear clipping gets stuck and
drops points. Its output is then checked and, where needed, repaired locally (:class:`_Cap`):
slivers flipped away, T-junctions split, runs of slivers ear-clipped anew; a polygon that still
cannot be triangulated along its own edges raises. Every face has area: on a grid, at least half
a square cell (an eighth for simplified outlines).

Why mapbox-earcut: the caps are polygons with holes (up to thousands of vertices) and earcut is
the small, fast, widely used ear-clipping triangulator (Mapbox's C++ header behind a thin
binding: numpy in and out, no other dependency, a 77 kB wheel). Constrained Delaunay libraries
would need less repair but are either large (CGAL) or not free to use (Triangle).

"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from scan2terrain.geometry.outlines import Polygon, _flatten, ring_area2

__all__ = ["Mesh", "boxes_mesh", "extrude", "is_watertight", "splitmix64"]

#: How far a vertex at a diagonal contact moves into its sector of material, along the sector's
#: bisector: this fraction of the shorter of its two outline edges, at most ``SPLIT_MAX`` metres
#: (0.5 mm on a 5 cm grid). Far above float32's step in map-frame metres (STL, COLLADA), far
#: below anything a robot or a physics engine resolves.
SPLIT = 0.01
SPLIT_MAX = 1e-3


@dataclass(frozen=True)
class Mesh:
    """A triangle mesh.

    Attributes
    ----------
    vertices : float64 array, shape (V, 3)
        Map frame, metres, z up.
    faces : int64 array, shape (F, 3)
        Vertex indices, counter-clockwise seen from outside.
    """

    vertices: NDArray[np.float64]
    faces: NDArray[np.int64]

    def normals(self) -> NDArray[np.float64]:
        """Unit normal of each face, float64 (F, 3) (zero for a face without area)."""
        v = self.vertices[self.faces]
        n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        length = np.linalg.norm(n, axis=1, keepdims=True)
        unit: NDArray[np.float64] = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
        return unit


def extrude(polygons: list[Polygon], height: float, base: float = 0.0) -> Mesh:
    """Walls from ``base`` to ``base + height`` over the polygons, as one watertight mesh.

    Parameters
    ----------
    polygons : list of Polygon
        Map frame, metres; valid polygons (simple rings, holes inside, not overlapping, rings
        touching at most at vertices), such as
        :func:`~scan2terrain.geometry.outlines.trace` or
        :func:`~scan2terrain.geometry.outlines.simplify` return.
    height : float
        Wall height, metres, > 0.
    base : float
        z of the bottom caps, metres.

    Returns
    -------
    Mesh
        Vertices: every ring vertex at ``base`` (in ring order, polygon by polygon, exterior
        then holes), then the same at ``base + height``. Faces: two per outline edge (walls),
        then the top caps, then the bottom caps. :func:`is_watertight` holds.

    Notes
    -----
    Where rings meet at a point (a diagonal contact) the mesh needs one vertex per *sector* of
    material there, not one per ring: a hole touching its own exterior leaves the exterior's
    corner along the hole's edge (see :mod:`~scan2terrain.geometry.outlines`), so a sector
    lies between one ring's outgoing edge and, counter-clockwise, another ring's incoming edge.
    Each sector uses the vertex that ends its incoming edge, for both walls and for the cap
    triangles inside it, so every vertical edge has exactly two wall faces.

    Raises
    ------
    ValueError
        If ``height`` is not positive and finite, ``base`` not finite, or a polygon cannot be
        triangulated into exactly its area (it is not valid).
    """
    if not (height > 0 and math.isfinite(height)):
        raise ValueError(f"height must be a positive number of metres, got {height}")
    if not math.isfinite(base):
        raise ValueError(f"base must be a finite number of metres, got {base}")
    if not polygons:
        return Mesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    rings = _flatten(polygons)
    xy = rings.xy
    n = len(xy)
    vertices = np.empty((2 * n, 3))
    vertices[:n, :2] = xy
    vertices[n:, :2] = xy
    vertices[:n, 2] = base
    vertices[n:, 2] = base + height
    nxt = rings.next_vertex()
    prv = np.empty(n, dtype=np.int64)
    prv[nxt] = np.arange(n, dtype=np.int64)
    shared = _SharedPoints(xy, nxt, prv)
    # Edge k runs from vertex k to nxt[k]; at a shared point it starts at its sector's vertex.
    a = np.arange(n, dtype=np.int64)
    sector = shared.sector_of_edges()
    a[shared.members] = sector
    vertices[sector, :2] += shared.split(sector, nxt, prv)
    vertices[sector + n, :2] = vertices[sector, :2]
    b = nxt
    # Material is left of a -> b, so outside is to the right: (a, b, b') and (a, b', a') wind
    # counter-clockwise seen from there.
    walls = np.stack([a, b, b + n, a, b + n, a + n], axis=1).reshape(-1, 3)
    caps = _caps(xy, rings.start, rings.owner, shared)
    top = caps + n
    bottom = caps[:, ::-1]
    return Mesh(vertices, np.concatenate([walls, top, bottom]).astype(np.int64))


class _SharedPoints:
    """Ring vertices at points that more than one ring vertex occupies, and their sectors.

    At such a point every vertex brings an incoming ray (towards its previous vertex) and an
    outgoing ray (towards its next). Material lies counter-clockwise from each outgoing ray up
    to the next incoming ray: that sector is named by the incoming ray's vertex.
    """

    def __init__(
        self, xy: NDArray[np.float64], nxt: NDArray[np.int64], prv: NDArray[np.int64]
    ) -> None:
        self.xy = xy
        order = np.lexsort((xy[:, 1], xy[:, 0]))
        same = np.all(xy[order][1:] == xy[order][:-1], axis=1)
        group = np.empty(len(xy), dtype=np.int64)
        group[order] = np.cumsum(np.r_[True, ~same]) - 1
        #: One vertex index per point: the lowest index of the vertices there.
        self.place = np.full(int(group.max(initial=-1)) + 1, len(xy), dtype=np.int64)
        np.minimum.at(self.place, group, np.arange(len(xy)))
        self.place = self.place[group]
        self.is_shared = np.bincount(group)[group] > 1
        m = np.nonzero(self.is_shared)[0]
        self.members = m
        self.angle_in = _angles(xy[prv[m]] - xy[m])
        self.angle_out = _angles(xy[nxt[m]] - xy[m])
        # Members sorted by point, and where each member's point starts/ends in that order.
        self.by_point = m[np.argsort(group[m], kind="stable")]
        g = group[self.by_point]
        first = np.r_[True, g[1:] != g[:-1]] if len(g) else np.zeros(0, dtype=bool)
        lo = np.nonzero(first)[0]
        size = np.diff(np.append(lo, len(g)))
        self._lo = np.empty(len(xy), dtype=np.int64)
        self._size = np.zeros(len(xy), dtype=np.int64)
        self._lo[self.by_point] = np.repeat(lo, size)
        self._size[self.by_point] = np.repeat(size, size)
        self._index = np.full(len(xy), -1, dtype=np.int64)
        self._index[m] = np.arange(len(m))

    def _first_ccw(self, vertex: NDArray[np.int64], angle: NDArray[np.float64]) -> Any:
        """Per query, the vertex at ``vertex``'s point whose incoming ray is the first one
        counter-clockwise from ``angle`` (radians), strictly."""
        if len(vertex) == 0:
            return vertex.copy()
        size = self._size[vertex]
        query = np.repeat(np.arange(len(vertex)), size)
        offset = np.arange(len(query)) - np.repeat(np.cumsum(size) - size, size)
        cand = self.by_point[np.repeat(self._lo[vertex], size) + offset]
        turn = np.mod(self.angle_in[self._index[cand]] - angle[query], 2 * math.pi)
        turn[turn == 0] = 2 * math.pi
        best = np.lexsort((turn, query))
        firsts = best[np.r_[True, query[best][1:] != query[best][:-1]]]
        return cand[firsts]

    def sector_of_edges(self) -> Any:
        """The sector vertex each shared vertex's outgoing edge starts from."""
        return self._first_ccw(self.members, self.angle_out)

    def sector_at(self, vertex: NDArray[np.int64], angle: NDArray[np.float64]) -> Any:
        """The sector vertex for directions ``angle`` (radians) leaving shared ``vertex``."""
        return self._first_ccw(vertex, angle)

    def split(
        self, sector: NDArray[np.int64], nxt: NDArray[np.int64], prv: NDArray[np.int64]
    ) -> NDArray[np.float64]:
        """Per member, the (x, y) move of ``sector`` (its :meth:`sector_of_edges`): along the
        bisector of the sector, which runs counter-clockwise from the member's outgoing ray to
        the sector vertex's incoming ray, by :data:`SPLIT` of the shorter of those two edges
        (at most :data:`SPLIT_MAX`)."""
        m = self.members
        start = self.angle_out
        span = np.mod(self.angle_in[self._index[sector]] - start, 2 * math.pi)
        span[span == 0] = 2 * math.pi
        bisector = start + span / 2
        out = np.linalg.norm(self.xy[nxt[m]] - self.xy[m], axis=1)
        into = np.linalg.norm(self.xy[prv[sector]] - self.xy[sector], axis=1)
        step = np.minimum(SPLIT * np.minimum(out, into), SPLIT_MAX)
        move: NDArray[np.float64] = step[:, None] * np.stack(
            [np.cos(bisector), np.sin(bisector)], axis=1
        )
        return move


def _angles(d: NDArray[np.float64]) -> NDArray[np.float64]:
    angle: NDArray[np.float64] = np.arctan2(d[:, 1], d[:, 0])
    return angle


def _caps(
    xy: NDArray[np.float64],
    start: NDArray[np.int64],
    owner: NDArray[np.int64],
    shared: _SharedPoints,
) -> NDArray[np.int64]:
    """Counter-clockwise triangles (vertex indices) covering every polygon, whose boundary
    edges are exactly the outline edges (with the sector vertices of :class:`_SharedPoints`):
    a fan for convex polygons without holes, earcut (then repaired, see :class:`_Cap`) for
    the others."""
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
    # Earcut for the others, on jittered local coordinates (see _jitter); every check of its
    # output is done for all polygons at once, the repairs (rare) one polygon at a time.
    ear_polys = np.nonzero(~fan)[0]
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
    clockwise = np.bincount(owner_of, _twice_areas(xy, tri), minlength=n_poly) < 0
    tri[clockwise[owner_of]] = tri[clockwise[owner_of]][:, ::-1]
    # Repairs work on points (coincident vertices as one); a triangle between two copies of
    # one point has no area and no place in the cap.
    tri = place[tri]
    keep = (tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 2] != tri[:, 0])
    tri, owner_of = tri[keep], owner_of[keep]
    is_ear = ~fan[poly_of_vertex]
    ring_edges = np.stack([place[is_ear], place[nxt[is_ear]]], axis=1)
    ring_owner = poly_of_vertex[is_ear]
    broken = _needs_repair(
        xy, tri, owner_of, ring_edges=ring_edges, ring_owner=ring_owner, n_poly=n_poly
    )
    if broken.any():
        fixed = [tri[~broken[owner_of]]]
        owners = [owner_of[~broken[owner_of]]]
        for k in np.nonzero(broken)[0].tolist():
            cap = _Cap(xy, tri[owner_of == k])
            cap.repair(ring_edges[ring_owner == k], k)
            fixed.append(cap.array())
            owners.append(np.full(len(fixed[-1]), k))
        tri, owner_of = np.concatenate(fixed), np.concatenate(owners)
    # Each corner at a point several vertices share takes the vertex of its sector.
    parts = [_sector_corners(xy, np.concatenate([fans, tri]), shared)]
    owners = [np.concatenate([fan_owner, owner_of])]
    tri = np.concatenate(parts)
    polygon = np.concatenate(owners)
    # Each polygon's triangles must add up to exactly its area, none turned over.
    area2 = _twice_areas(xy, tri)
    got = np.bincount(polygon, np.abs(area2), minlength=n_poly)
    want = np.bincount(poly_of_ring, ring_area2(xy, start), minlength=n_poly)
    bad = ~np.isclose(got, want, rtol=1e-9, atol=1e-12) | (
        np.bincount(polygon, area2 < 0, minlength=n_poly) > 0
    )
    if bad.any():
        k = int(np.argmax(bad))
        raise ValueError(
            f"polygon {int(owner[ring_lo[k]])} cannot be triangulated into its own area"
            " (rings crossing, or a hole outside its exterior)"
        )
    return tri


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
    xy: NDArray[np.float64], tri: NDArray[np.int64], shared: _SharedPoints
) -> NDArray[np.int64]:
    """Triangle corners at shared points renamed to the vertex of the sector they lie in."""
    t, c = np.nonzero(shared.is_shared[tri])
    if len(t) == 0:
        return tri
    tri = tri.copy()
    v = tri[t, c]
    mid = 0.5 * (xy[tri[t, (c + 1) % 3]] + xy[tri[t, (c + 2) % 3]])
    tri[t, c] = shared.sector_at(v, _angles(mid - xy[v]))
    return tri


def _twice_areas(xy: NDArray[np.float64], tri: NDArray[np.int64]) -> NDArray[np.float64]:
    p0, p1, p2 = xy[tri[:, 0]], xy[tri[:, 1]], xy[tri[:, 2]]
    area2: NDArray[np.float64] = (p1[:, 0] - p0[:, 0]) * (p2[:, 1] - p0[:, 1]) - (
        p1[:, 1] - p0[:, 1]
    ) * (p2[:, 0] - p0[:, 0])
    return area2


def _sliver_mask(xy: NDArray[np.float64], tri: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Triangles without area (up to rounding, relative to their longest edge)."""
    p = xy[tri]
    e = p[:, [1, 2, 0]] - p
    longest = np.einsum("ijk,ijk->ij", e, e).max(axis=1)
    mask: NDArray[np.bool_] = np.abs(_twice_areas(xy, tri)) <= 1e-9 * longest
    return mask


def _needs_repair(
    xy: NDArray[np.float64],
    tri: NDArray[np.int64],
    owner: NDArray[np.int64],
    *,
    ring_edges: NDArray[np.int64],
    ring_owner: NDArray[np.int64],
    n_poly: int,
) -> NDArray[np.bool_]:
    """Per polygon: whether its cap has a sliver, an edge that is neither an outline edge nor
    shared with the triangle across, or misses an outline edge (see :class:`_Cap`)."""
    broken = np.zeros(n_poly, dtype=bool)
    broken[owner[_sliver_mask(xy, tri)]] = True
    n = len(xy)
    u, v = tri.reshape(-1), tri[:, [1, 2, 0]].reshape(-1)
    tri_owner = np.repeat(owner, 3)
    have = np.sort((tri_owner * n + u) * n + v)
    ring = (ring_owner * n + ring_edges[:, 0]) * n + ring_edges[:, 1]
    broken[ring_owner[~_member(ring, have)]] = True
    lonely = ~_member((tri_owner * n + v) * n + u, have)
    lonely &= ~_member((tri_owner * n + u) * n + v, np.sort(ring))
    broken[tri_owner[lonely]] = True
    return broken


def _member(keys: NDArray[np.int64], sorted_keys: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Whether each key is in ``sorted_keys`` (sorted ascending)."""
    if len(sorted_keys) == 0:
        return np.zeros(len(keys), dtype=bool)
    pos = np.minimum(np.searchsorted(sorted_keys, keys), len(sorted_keys) - 1)
    found: NDArray[np.bool_] = sorted_keys[pos] == keys
    return found


Tri = tuple[int, int, int]


def _tri_edges(tri: Tri) -> tuple[tuple[int, int], ...]:
    a, b, c = tri
    return ((a, b), (b, c), (c, a))


class _Cap:
    """One polygon's cap triangles with their edges, for local repairs of earcut's output.

    Earcut's triangulation covers the polygon but has habits that break a watertight mesh,
    undone here edge by edge (geometry in Python floats: the repairs are few and local):

    * slivers: triangles whose middle corner lies on their longest edge (points on one line,
      like the corners of a staircase, collinear exactly or up to rounding). Flipping that edge
      with the triangle across it, (a, b, c) + (a, c, d) -> (a, b, d) + (b, c, d), removes
      the sliver and keeps every other edge;
    * T-junctions: when it joins a hole to its exterior, or gets stuck, earcut drops points
      that became exactly collinear with their neighbours, so a triangle edge runs straight
      through a point. That edge (and the one of the triangle across it) is split there;
    * what is left (a run of slivers along one line, each the other's neighbour) is cut out
      with its neighbours and ear-clipped anew with strict ears (:func:`_strict_ears`).
    """

    def __init__(self, xy: NDArray[np.float64], tri: NDArray[np.int64]) -> None:
        keys = tri.reshape(-1) * len(xy) + tri[:, [1, 2, 0]].reshape(-1)
        if len(np.unique(keys)) != len(keys):
            raise ValueError("overlapping cap triangles")
        self.xy = xy
        idx = np.unique(tri)
        self.p: dict[int, tuple[float, float]] = dict(
            zip(idx.tolist(), map(tuple, xy[idx].tolist()), strict=True)
        )
        self.tris: list[Tri | None] = []
        self.edge: dict[tuple[int, int], int] = {}
        self.out: dict[int, set[int]] = {}
        self.into: dict[int, set[int]] = {}
        self._set(*((t, (a, b, c)) for t, (a, b, c) in enumerate(tri.tolist())))

    def array(self) -> NDArray[np.int64]:
        return np.array([t for t in self.tris if t is not None], dtype=np.int64).reshape(-1, 3)

    def _set(self, *changes: tuple[int, Tri | None]) -> None:
        """Put each triangle at its index (appending when new, deleting when None): the old
        triangles' edges go first, so edges passing from one triangle to another stay."""
        for t, _ in changes:
            old = self.tris[t] if t < len(self.tris) else None
            if old is not None:
                a, b, c = old
                for u, v in ((a, b), (b, c), (c, a)):
                    del self.edge[u, v]
                    self.out[u].discard(v)
                    self.into[v].discard(u)
        for t, tri in changes:
            while t >= len(self.tris):
                self.tris.append(None)
            self.tris[t] = tri
            if tri is None:
                continue
            a, b, c = tri
            for u, v in ((a, b), (b, c), (c, a)):
                self.edge[u, v] = t
                self.out.setdefault(u, set()).add(v)
                self.into.setdefault(v, set()).add(u)

    def _fits(self, *changes: tuple[int, Tri | None]) -> bool:
        """Whether the changes keep every directed edge in one triangle at most."""
        gone = {e for t, _ in changes if t < len(self.tris) for e in self._edges_of(t)}
        new = [(u, v) for _, tri in changes if tri is not None for u, v in _tri_edges(tri)]
        return len(set(new)) == len(new) and not any(e in self.edge and e not in gone for e in new)

    def _between(self, w: int, p: int, q: int) -> bool:
        """Whether point w lies on segment p-q, strictly inside it, up to rounding."""
        (ax, ay), (bx, by), (cx, cy) = self.p[p], self.p[q], self.p[w]
        dx, dy, ex, ey = bx - ax, by - ay, cx - ax, cy - ay
        length2 = dx * dx + dy * dy
        along = ex * dx + ey * dy
        return abs(dx * ey - dy * ex) <= 1e-9 * length2 and 0.0 < along < length2

    def _sliver(self, t: int) -> bool:
        tri = self.tris[t]
        if tri is None:
            return False
        (ax, ay), (bx, by), (cx, cy) = (self.p[i] for i in tri)
        cross = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
        longest = max(
            (bx - ax) ** 2 + (by - ay) ** 2,
            (cx - bx) ** 2 + (cy - by) ** 2,
            (ax - cx) ** 2 + (ay - cy) ** 2,
        )
        return abs(cross) <= 1e-9 * longest

    def _slivers(self) -> list[int]:
        """Indices of the slivers (see :meth:`_sliver`), found with numpy."""
        live = [t for t, tri in enumerate(self.tris) if tri is not None]
        tri = np.array([self.tris[t] for t in live], dtype=np.int64).reshape(-1, 3)
        return [live[i] for i in np.nonzero(_sliver_mask(self.xy, tri))[0].tolist()]

    def _edges_of(self, t: int) -> tuple[tuple[int, int], ...]:
        tri = self.tris[t]
        return () if tri is None else _tri_edges(tri)

    def _flip_slivers(self) -> bool:
        """Flip every sliver that has a proper triangle across its longest edge."""
        changed = False
        queue = self._slivers()
        for _ in range(10 * len(self.tris)):
            if not queue:
                break
            t = queue.pop()
            tri = self.tris[t]
            if tri is None or not self._sliver(t):
                continue
            a, b, c = tri
            for _rot in range(3):  # rotate so that c -> a is the longest edge
                if self._between(b, c, a):
                    break
                a, b, c = b, c, a
            else:
                continue  # two corners at one place: not a sliver to flip
            t2 = self.edge.get((a, c))
            other = self.tris[t2] if t2 is not None else None
            if t2 is None or other is None:
                continue
            d = next((v for v in other if v not in (a, c)), b)
            # Only a flip that makes two triangles with area and no edge twice.
            flip: tuple[tuple[int, Tri | None], ...] = ((t, (a, b, d)), (t2, (b, c, d)))
            if d == b or self._between(d, c, a) or not self._fits(*flip):
                continue
            self._set(*flip)
            if self._sliver(t) or self._sliver(t2):
                self._set((t, (a, b, c)), (t2, other))  # undo: it made no progress
                continue
            queue += [t, t2]
            changed = True
        return changed

    def _split(self, p: int, q: int, w: int) -> bool:
        """Split edge p-q (both triangles at it) at the point w lying on it; a triangle across
        that already has w as its corner is a sliver along the edge and goes. False (and nothing
        done) if that would put an edge in two triangles."""
        changes: list[tuple[int, Tri | None]] = []
        extra = len(self.tris)
        for u, v in ((p, q), (q, p)):
            t = self.edge.get((u, v))
            tri = self.tris[t] if t is not None else None
            if t is None or tri is None:
                continue
            x2 = next(i for i in tri if i not in (u, v))
            if x2 == w:
                changes.append((t, None))
                continue
            changes += [(t, (u, w, x2)), (extra, (w, v, x2))]
            extra += 1
        if not self._fits(*changes):
            return False
        self._set(*changes)
        return True

    def _close_t_junctions(self, ring: set[tuple[int, int]]) -> bool:
        """One pass of splits; returns whether anything changed."""
        changed = False
        for u, v in list(self.edge):
            if (u, v) not in self.edge or (v, u) in self.edge or (u, v) in ring:
                continue
            # The far side runs u <- w ... or ... w <- v along this edge: split it at w.
            w = next((w for w in self.into.get(u, ()) if self._between(w, u, v)), None)
            if w is None:
                w = next((w for w in self.out.get(v, ()) if self._between(w, u, v)), None)
            if w is not None and self._split(u, v, w):
                changed = True
        for a, b in ring:
            if (a, b) in self.edge:
                continue
            # A triangle edge along a -> b, from a past b or from before a to b.
            split = next(((a, v, b) for v in self.out.get(a, ()) if self._between(b, a, v)), None)
            if split is None:
                split = next(
                    ((u, b, a) for u in self.into.get(b, ()) if self._between(a, u, b)), None
                )
            if split is not None and self._split(*split):
                changed = True
        return changed

    def _neighbours(self, t: int) -> set[int]:
        return {t2 for u, v in self._edges_of(t) if (t2 := self.edge.get((v, u))) is not None}

    def _retriangulate(self, seed: int, grow: int) -> bool:
        """Triangulate anew the slivers connected to sliver ``seed`` and the triangles within
        ``grow`` steps of them, by strict ear clipping on their boundary. False when that
        region is not a disk with all its points on its boundary, or has no strict ear."""
        region = {seed}
        todo = [seed]
        while todo:
            for t2 in self._neighbours(todo.pop()):
                if t2 not in region and self._sliver(t2):
                    region.add(t2)
                    todo.append(t2)
        for _ in range(grow):
            region |= {t3 for t in region for t3 in self._neighbours(t)}
        inner = {e for t in region for e in self._edges_of(t)}
        outer = [(u, v) for u, v in inner if (v, u) not in inner]
        boundary = dict(outer)
        if not outer or len(boundary) != len(outer):
            return False  # no boundary, or a point twice on it
        start = outer[0][0]
        loop = [start]
        while (v := boundary.get(loop[-1], start)) != start and len(loop) <= len(boundary):
            loop.append(v)
        points = {i for t in region for e in self._edges_of(t) for i in e}
        if len(loop) != len(boundary) or points != set(loop) or len(loop) - 2 != len(region):
            return False
        new = _strict_ears(self.p, loop)
        if new is None:
            return False
        changes = tuple(zip(sorted(region), new, strict=True))
        if not self._fits(*changes):
            return False
        self._set(*changes)
        return True

    def repair(self, ring_edges: NDArray[np.int64], polygon: int) -> None:
        ring = {(int(a), int(b)) for a, b in ring_edges.tolist()}
        for _ in range(4 * len(ring) + 8):
            if self._flip_slivers():
                continue
            slivers = self._slivers()
            if any(self._retriangulate(t, grow) for t in slivers for grow in (1, 2, 3)):
                continue
            if not self._close_t_junctions(ring):
                break
        tri = self.array()
        zeros = np.zeros(len(tri), dtype=np.int64)
        ring_owner = np.zeros(len(ring_edges), dtype=np.int64)
        if _needs_repair(
            self.xy, tri, zeros, ring_edges=ring_edges, ring_owner=ring_owner, n_poly=1
        )[0]:
            raise ValueError(
                f"polygon {polygon} cannot be triangulated along its own edges"
                " (rings crossing, or a hole outside its exterior)"
            )


def _strict_ears(p: dict[int, tuple[float, float]], loop: list[int]) -> list[Tri] | None:
    """Ear clipping of a small counter-clockwise loop of points, clipping only ears with area
    that hold no other point of the loop, not even on their edges (so no triangle edge runs
    through a point: collinear points are handled). None if it gets stuck."""
    loop = list(loop)
    out: list[Tri] = []
    while len(loop) >= 3:
        for k in range(len(loop)):
            a, b, c = loop[k - 1], loop[k], loop[(k + 1) % len(loop)]
            (ax, ay), (bx, by), (cx, cy) = p[a], p[b], p[c]
            area2 = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
            scale = max((bx - ax) ** 2 + (by - ay) ** 2, (cx - bx) ** 2 + (cy - by) ** 2)
            if area2 <= 1e-9 * scale:
                continue
            tol = -1e-9 * area2
            blocked = False
            for i in loop:
                if i in (a, b, c):
                    continue
                qx, qy = p[i]
                if (
                    (bx - ax) * (qy - ay) - (by - ay) * (qx - ax) >= tol
                    and (cx - bx) * (qy - by) - (cy - by) * (qx - bx) >= tol
                    and (ax - cx) * (qy - cy) - (ay - cy) * (qx - cx) >= tol
                ):
                    blocked = True
                    break
            if blocked:
                continue
            out.append((a, b, c))
            del loop[k]
            break
        else:
            return None
        if len(loop) == 2:
            return out
    return out


def boxes_mesh(boxes: NDArray[np.float64], height: float, base: float = 0.0) -> Mesh:
    """Upright boxes as one mesh: 8 vertices and 12 triangles each (outward, counter-clockwise).

    ``boxes`` (K, 5): centre x, y, size x, size y (metres, along the box's axes), yaw (radians),
    as :func:`scan2terrain.exporters.sdf.boxes_model_sdf` takes them; each from ``base`` to
    ``base + height``. Neighbouring boxes keep their shared faces (a visual, not a solid).
    """
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 5)
    k = len(b)
    sx = np.array([-0.5, 0.5, 0.5, -0.5])
    sy = np.array([-0.5, -0.5, 0.5, 0.5])
    c, s = np.cos(b[:, 4:5]), np.sin(b[:, 4:5])
    u, v = sx[None, :] * b[:, 2:3], sy[None, :] * b[:, 3:4]
    x = b[:, 0:1] + c * u - s * v  # (K, 4) corners, counter-clockwise from above
    y = b[:, 1:2] + s * u + c * v
    ring = np.stack([x, y], axis=-1)
    low = np.concatenate([ring, np.full((k, 4, 1), base)], axis=-1)
    high = np.concatenate([ring, np.full((k, 4, 1), base + height)], axis=-1)
    vertices = np.concatenate([low, high], axis=1).reshape(-1, 3)
    # Per box: bottom (seen from below), top, and the four sides.
    local = np.array(
        [[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7]]
        + [[i, (i + 1) % 4, (i + 1) % 4 + 4] for i in range(4)]
        + [[i, (i + 1) % 4 + 4, i + 4] for i in range(4)],
        dtype=np.int64,
    )
    faces = (local[None, :, :] + 8 * np.arange(k, dtype=np.int64)[:, None, None]).reshape(-1, 3)
    return Mesh(vertices, faces)


def is_watertight(mesh: Mesh) -> bool:
    """Every edge is used by exactly two faces, once in each direction, and no face repeats a
    vertex: a closed, consistently oriented 2-manifold (combinatorially)."""
    f = np.asarray(mesh.faces, dtype=np.int64)
    if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        return False
    if ((f < 0) | (f >= len(mesh.vertices))).any():
        return False
    if ((f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 2] == f[:, 0])).any():
        return False
    v = len(mesh.vertices)
    a = f.reshape(-1)
    b = f[:, [1, 2, 0]].reshape(-1)
    directed = np.sort(a * v + b)
    if (directed[1:] == directed[:-1]).any():
        return False  # a directed edge twice: inconsistent orientation or more than two faces
    reverse = np.sort(b * v + a)
    return bool(np.array_equal(directed, reverse))
