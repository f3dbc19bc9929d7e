"""Local repair of an earcut triangulation of one cap (:class:`_Cap`): slivers flipped away,
T-junctions split, runs of slivers ear-clipped anew, so that every cap edge on the outline is
exactly a wall quad's edge and every face has area."""

from __future__ import annotations

import heapq
from collections.abc import Iterable
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray


def twice_areas(xy: NDArray[np.float64], tri: NDArray[np.int64]) -> NDArray[np.float64]:
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
    mask: NDArray[np.bool_] = np.abs(twice_areas(xy, tri)) <= 1e-9 * longest
    return mask


def needs_repair(
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
    u, v = tri.reshape(-1), tri[:, [1, 2, 0]].reshape(-1)
    tri_owner = np.repeat(owner, 3)
    forward, backward, ring = _edge_keys(
        len(xy),
        (tri_owner, u, v),
        (tri_owner, v, u),
        (ring_owner, ring_edges[:, 0], ring_edges[:, 1]),
    )
    have = np.sort(forward)
    broken[ring_owner[~_member(ring, have)]] = True
    lonely = ~_member(backward, have)
    lonely &= ~_member(forward, np.sort(ring))
    broken[tri_owner[lonely]] = True
    return broken


def _edge_keys(
    n: int, *edges: tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]
) -> list[NDArray[np.int64]]:
    """One int64 key per directed edge (polygon, from point, to point) of each group, equal
    for equal edges across the groups; points are below ``n``. The (polygon, from point) pairs
    are numbered densely first: ``(polygon * n + a) * n + b`` overflowed int64 once polygons
    times n squared passed 9.2e18 (a few hundred thousand polygons on a 3000^2 map)."""
    starts = [owner * n + a for owner, a, _ in edges]  # < polygons * n: no overflow
    pairs = np.unique(np.concatenate(starts))
    ends = [b for _, _, b in edges]
    return [np.searchsorted(pairs, a) * n + b for a, b in zip(starts, ends, strict=True)]


def _member(keys: NDArray[np.int64], sorted_keys: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Whether each key is in ``sorted_keys`` (sorted ascending)."""
    if len(sorted_keys) == 0:
        return np.zeros(len(keys), dtype=bool)
    pos = np.minimum(np.searchsorted(sorted_keys, keys), len(sorted_keys) - 1)
    found: NDArray[np.bool_] = sorted_keys[pos] == keys
    return found


Tri = tuple[int, int, int]
Edge = tuple[int, int]
_A = TypeVar("_A")


def _tri_edges(tri: Tri) -> tuple[Edge, ...]:
    a, b, c = tri
    return ((a, b), (b, c), (c, a))


def _flat(p: dict[int, tuple[float, float]], tri: Tri) -> bool:
    """Whether the triangle has no area (up to rounding, relative to its longest edge)."""
    (ax, ay), (bx, by), (cx, cy) = (p[i] for i in tri)
    cross = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
    longest = max(
        (bx - ax) ** 2 + (by - ay) ** 2,
        (cx - bx) ** 2 + (cy - by) ** 2,
        (ax - cx) ** 2 + (ay - cy) ** 2,
    )
    return abs(cross) <= 1e-9 * longest


def _grouped(keys: NDArray[np.int64], values: NDArray[np.int64]) -> dict[int, set[int]]:
    """Each key's values as a set, filled in array order (as one ``add`` after another would
    fill it, so the sets iterate in the same order too)."""
    if len(keys) == 0:
        return {}
    order = np.argsort(keys, kind="stable")
    keys = keys[order]
    first = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
    bounds = np.append(first, len(keys)).tolist()
    vals = values[order].tolist()
    return {
        k: set(vals[lo:hi])
        for k, lo, hi in zip(keys[first].tolist(), bounds[:-1], bounds[1:], strict=True)
    }


def _watch(watchers: dict[int, list[_A]], attempt: _A, points: Iterable[int]) -> None:
    """Have a failed attempt made again once a triangle at one of the points changes."""
    for v in points:
        watchers.setdefault(v, []).append(attempt)


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
      with its neighbours and ear-clipped anew with strict ears (:func:`strict_ears`).

    Each round of :meth:`repair` is a sweep of flips over every sliver, else the first sliver
    that ear-clips anew, else a sweep of splits over every edge. A speckled map's one big cap
    holds tens of thousands of slivers, most of which no flip helps until a neighbour is
    ear-clipped, one per round: trying them all every round was quadratic. So an attempt that
    fails is watched (:func:`_watch`) by the points its outcome depends on (the corners of the
    triangles it reads: every triangle it looks at has a corner among them) and made again only
    once a triangle at one of them changes (:meth:`_set`). The sweeps visit what is left to try
    in the order a sweep over everything visits it, so the repairs, and the triangles, are the
    same as trying everything every round. (One thing is not done again: a flip that made no
    progress used to be made and undone every round, which moved its two triangles' edges to
    the end of ``edge`` and could reorder the ``out``/``into`` sets. Only the order in which one
    sweep of splits meets two T-junctions side by side could tell.)
    """

    def __init__(self, xy: NDArray[np.float64], tri: NDArray[np.int64]) -> None:
        u, v = tri.reshape(-1), tri[:, [1, 2, 0]].reshape(-1)
        keys = np.sort(u * len(xy) + v)
        if (keys[1:] == keys[:-1]).any():
            raise ValueError("overlapping cap triangles")
        self.xy = xy
        idx = np.unique(tri)
        self.p: dict[int, tuple[float, float]] = dict(
            zip(idx.tolist(), map(tuple, xy[idx].tolist()), strict=True)
        )
        tris = [(a, b, c) for a, b, c in tri.tolist()]
        self.tris: list[Tri | None] = list(tris)
        #: Directed edge -> its triangle, in the order the edges were made (each triangle's in
        #: turn: a triangle set anew makes its edges anew, see ``_born``).
        pairs = zip(u.tolist(), v.tolist(), strict=True)
        self.edge: dict[Edge, int] = dict(
            zip(pairs, np.repeat(np.arange(len(tri)), 3).tolist(), strict=True)
        )
        self.out: dict[int, set[int]] = _grouped(u, v)
        self.into: dict[int, set[int]] = _grouped(v, u)
        #: The slivers among the triangles, kept as triangles change (numpy only shortlists
        #: them: whether one is a sliver is decided in Python floats, as for later triangles).
        maybe = np.abs(twice_areas(xy, tri)) <= 1e-6 * np.max(
            np.sum((xy[tri[:, [1, 2, 0]]] - xy[tri]) ** 2, axis=2), axis=1, initial=0.0
        )
        self.slivers = {t for t in np.flatnonzero(maybe).tolist() if _flat(self.p, tris[t])}
        #: When each triangle was set, counting triangles set: it orders the edges as ``edge``
        #: does (one triangle's in the order of :func:`_tri_edges`).
        self._born = list(range(len(tri)))
        self._births = len(tri)
        self._ring: set[Edge] = set()
        self._ring_places: dict[Edge, int] | None = None
        # Attempts to make (again), not yet in a sweep's order.
        self._retry_flip: list[int] = sorted(self.slivers)
        self._retry_clip: list[int] = list(self._retry_flip)
        self._retry_split: list[Edge] = []  # (the first ones: see repair)
        # Failed attempts by the points they watch: slivers that flip, slivers that ear-clip
        # anew, and edges without a twin (or outline edges missing) that split.
        self._watch_flip: dict[int, list[int]] = {}
        self._watch_clip: dict[int, list[int]] = {}
        self._watch_split: dict[int, list[Edge]] = {}
        # Attempts to make in the next sweep: of flips, of splits of edges without a twin, of
        # splits for missing outline edges; and the slivers yet to ear-clip, lowest first.
        self._flips: set[int] = set()
        self._lonely: set[Edge] = set()
        self._missing: set[Edge] = set()
        self._clips: list[int] = []
        self._clips_queued: set[int] = set()
        # While a sweep of splits runs: its start (in births), and the place each edge it
        # deleted had in its list of edges.
        self._sweep_start = 0
        self._moved: dict[Edge, int] | None = None
        #: Flips, ear clippings and splits tried so far: the work done, which tests check
        #: grows with the cap, not with the cap times the rounds.
        self.attempts = 0

    def array(self) -> NDArray[np.int64]:
        return np.array([t for t in self.tris if t is not None], dtype=np.int64).reshape(-1, 3)

    def _set(self, *changes: tuple[int, Tri | None]) -> None:
        """Put each triangle at its index (appending when new, deleting when None): the old
        triangles' edges go first, so edges passing from one triangle to another stay. Attempts
        watching a corner of an old or new triangle are to be made again, and so are the
        splits this may call for (an edge that lost its twin, an outline edge gone)."""
        for t, tri in changes:
            old = self.tris[t] if t < len(self.tris) else None
            for corners in (old, tri):
                if corners is not None:
                    self._touch(corners)
        for t, _ in changes:
            old = self.tris[t] if t < len(self.tris) else None
            if old is None:
                continue
            a, b, c = old
            for k, (u, v) in enumerate(((a, b), (b, c), (c, a))):
                del self.edge[u, v]
                self.out[u].discard(v)
                self.into[v].discard(u)
                if self._moved is not None and self._born[t] < self._sweep_start:
                    self._moved.setdefault((u, v), 3 * self._born[t] + k)
                if (v, u) in self.edge:
                    self._retry_split.append((v, u))
                if (u, v) in self._ring:
                    self._retry_split.append((u, v))
        for t, tri in changes:
            while t >= len(self.tris):
                self.tris.append(None)
                self._born.append(-1)
            self.tris[t] = tri
            if tri is not None and _flat(self.p, tri):
                self.slivers.add(t)
                self._retry_flip.append(t)
                self._retry_clip.append(t)
            else:
                self.slivers.discard(t)
            if tri is None:
                continue
            self._born[t] = self._births
            self._births += 1
            a, b, c = tri
            for u, v in ((a, b), (b, c), (c, a)):
                self.edge[u, v] = t
                self.out.setdefault(u, set()).add(v)
                self.into.setdefault(v, set()).add(u)
                if (v, u) not in self.edge:
                    self._retry_split.append((u, v))

    def _touch(self, corners: Iterable[int]) -> None:
        """Attempts watching these points are to be made again."""
        for v in corners:
            if (flips := self._watch_flip.pop(v, None)) is not None:
                self._retry_flip += flips
            if (clips := self._watch_clip.pop(v, None)) is not None:
                self._retry_clip += clips
            if (splits := self._watch_split.pop(v, None)) is not None:
                self._retry_split += splits

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

    def _edges_of(self, t: int) -> tuple[Edge, ...]:
        tri = self.tris[t]
        return () if tri is None else _tri_edges(tri)

    def _flip_slivers(self) -> bool:
        """Flip every sliver that has a proper triangle across its longest edge (see
        :meth:`_flip`), sweeping down from the highest index; returns whether any flipped."""
        todo = self._flips
        todo.update(self._retry_flip)
        self._retry_flip.clear()
        self._flips = set()
        heap = [-t for t in todo]
        heapq.heapify(heap)
        changed = False
        while heap:
            t = -heapq.heappop(heap)
            if t in self.slivers and self._flip(t):
                changed = True
            # What to try again because of this attempt: below it in this sweep, above it
            # (already swept) in the next.
            for s in self._retry_flip:
                if s >= t:
                    self._flips.add(s)
                elif s not in todo:
                    todo.add(s)
                    heapq.heappush(heap, -s)
            self._retry_flip.clear()
        return changed

    def _flip(self, t: int) -> bool:
        """Flip sliver t with the triangle across its longest edge if that makes two triangles
        with area and no edge twice; else watch the corners of both and return False."""
        self.attempts += 1
        tri = self.tris[t]
        if tri is None:
            return False
        a, b, c = tri
        for _rot in range(3):  # rotate so that c -> a is the longest edge
            if self._between(b, c, a):
                break
            a, b, c = b, c, a
        else:
            _watch(self._watch_flip, t, tri)
            return False  # two corners at one place: not a sliver to flip
        t2 = self.edge.get((a, c))
        other = self.tris[t2] if t2 is not None else None
        if t2 is None or other is None:
            _watch(self._watch_flip, t, tri)
            return False
        d = next((v for v in other if v not in (a, c)), b)
        flip: tuple[tuple[int, Tri | None], ...] = ((t, (a, b, d)), (t2, (b, c, d)))
        if d == b or self._between(d, c, a) or not self._fits(*flip):
            _watch(self._watch_flip, t, (a, b, c, d))
            return False
        if _flat(self.p, (a, b, d)) or _flat(self.p, (b, c, d)):
            # No progress. Such a flip used to be made and undone, which left the sliver's
            # corners in the turn found above: they are kept so (earcut's turn of a triangle
            # is what the mesh files hold, and an ear-clipping region's edges are walked in
            # it, see _retriangulate).
            if tri != (a, b, c):
                self._set((t, (a, b, c)))
            _watch(self._watch_flip, t, (a, b, c, d))
            return False
        self._set(*flip)
        return True

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

    def _split_points(self, p: int, q: int, w: int) -> set[int]:
        """The points whose triangles decide whether ``_split(p, q, w)`` fits."""
        return {w, *(i for e in ((p, q), (q, p)) if e in self.edge for i in self._corners(e))}

    def _corners(self, e: Edge) -> Tri:
        tri = self.tris[self.edge[e]]
        assert tri is not None  # an edge's triangle is never deleted before the edge
        return tri

    def _place(self, e: Edge) -> int | None:
        """Where edge e stands in the list of edges made before the running sweep of splits
        began (the list a sweep over every edge walks), or None if it is not in it."""
        if self._moved is not None and (place := self._moved.get(e)) is not None:
            return place
        t = self.edge.get(e)
        if t is None or self._born[t] >= self._sweep_start:
            return None
        return 3 * self._born[t] + self._edges_of(t).index(e)

    def _take_splits(self) -> tuple[list[Edge], list[Edge]]:
        """The splits to try again: edges without a twin (off the outline), and outline edges
        missing. Others are dropped: what makes one of them a T-junction later retries it."""
        lonely = [
            e
            for e in self._retry_split
            if e not in self._ring and e in self.edge and (e[1], e[0]) not in self.edge
        ]
        missing = [e for e in self._retry_split if e in self._ring and e not in self.edge]
        self._retry_split.clear()
        return lonely, missing

    def _close_t_junctions(self) -> bool:
        """One sweep of splits: edges without a twin in the order of ``edge`` (as listed when
        the sweep starts: edges made during it wait for the next one), then outline edges
        missing, in the order of the ring's set. Returns whether anything changed."""
        lonely, missing = self._lonely, self._missing
        self._lonely, self._missing = set(), set()
        new_lonely, new_missing = self._take_splits()
        lonely.update(new_lonely)
        missing.update(new_missing)
        self._sweep_start, self._moved = self._births, {}
        heap = [(place, e) for e in lonely if (place := self._place(e)) is not None]
        heapq.heapify(heap)
        changed = False
        while heap:
            at, (u, v) = heapq.heappop(heap)
            if (u, v) not in self.edge or (v, u) in self.edge:
                continue
            self.attempts += 1
            # The far side runs u <- w ... or ... w <- v along this edge: split it at w.
            w = next((w for w in self.into.get(u, ()) if self._between(w, u, v)), None)
            if w is None:
                w = next((w for w in self.out.get(v, ()) if self._between(w, u, v)), None)
            if w is None:
                _watch(self._watch_split, (u, v), (u, v))
                continue
            points = self._split_points(u, v, w)
            if not self._split(u, v, w):
                _watch(self._watch_split, (u, v), points)
                continue
            changed = True
            # What the split calls for: outline edges in this sweep; other edges in this sweep
            # if the list it walks has them further on, else in the next.
            new_lonely, new_missing = self._take_splits()
            missing.update(new_missing)
            for e in new_lonely:
                if (place := self._place(e)) is not None and place > at and e not in lonely:
                    lonely.add(e)
                    heapq.heappush(heap, (place, e))
                else:
                    self._lonely.add(e)
        self._moved = None
        if missing and self._ring_places is None:
            self._ring_places = {e: i for i, e in enumerate(self._ring)}
        places = self._ring_places or {}
        ring_heap = sorted((places[e], e) for e in missing)
        while ring_heap:
            at, (a, b) = heapq.heappop(ring_heap)
            if (a, b) in self.edge:
                continue
            self.attempts += 1
            # A triangle edge along a -> b, from a past b or from before a to b.
            split = next(((a, v, b) for v in self.out.get(a, ()) if self._between(b, a, v)), None)
            if split is None:
                split = next(
                    ((u, b, a) for u in self.into.get(b, ()) if self._between(a, u, b)), None
                )
            if split is None:
                _watch(self._watch_split, (a, b), (a, b))
                continue
            points = self._split_points(*split)
            if not self._split(*split):
                _watch(self._watch_split, (a, b), points)
                continue
            changed = True
            new_lonely, new_missing = self._take_splits()
            self._lonely.update(new_lonely)
            for e in new_missing:
                if places[e] > at and e not in missing:
                    missing.add(e)
                    heapq.heappush(ring_heap, (places[e], e))
                else:
                    self._missing.add(e)
        return changed

    def _neighbours(self, t: int) -> set[int]:
        return {t2 for u, v in self._edges_of(t) if (t2 := self.edge.get((v, u))) is not None}

    def _clip_slivers(self) -> bool:
        """Ear-clip anew around the lowest sliver where that works, growing the region by 1, 2,
        then 3 steps (see :meth:`_region`); returns whether one was."""
        for t in self._retry_clip:
            if t not in self._clips_queued:
                self._clips_queued.add(t)
                heapq.heappush(self._clips, t)
        self._retry_clip.clear()
        while self._clips:
            t = self._clips[0]
            if t in self.slivers:
                region: set[int] = set()
                for grow in (1, 2, 3):
                    region = self._region(t, grow)
                    if self._retriangulate(region):
                        return True  # t stays: it has changed, so it is to be tried again
                _watch(
                    self._watch_clip, t, {i for s in region for e in self._edges_of(s) for i in e}
                )
            heapq.heappop(self._clips)
            self._clips_queued.discard(t)
        return False

    def _region(self, seed: int, grow: int) -> set[int]:
        """The slivers connected to sliver ``seed`` and the triangles within ``grow`` steps of
        them."""
        region = {seed}
        todo = [seed]
        while todo:
            for t2 in self._neighbours(todo.pop()):
                if t2 not in region and t2 in self.slivers:
                    region.add(t2)
                    todo.append(t2)
        for _ in range(grow):
            region |= {t3 for t in region for t3 in self._neighbours(t)}
        return region

    def _retriangulate(self, region: set[int]) -> bool:
        """Triangulate the region anew, by strict ear clipping on its boundary. False when it
        is not a disk with all its points on its boundary, or has no strict ear."""
        self.attempts += 1
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
        new = strict_ears(self.p, loop)
        if new is None:
            return False
        changes = tuple(zip(sorted(region), new, strict=True))
        if not self._fits(*changes):
            return False
        self._set(*changes)
        return True

    def repair(self, ring_edges: NDArray[np.int64], polygon: int) -> None:
        ring = {(int(a), int(b)) for a, b in ring_edges.tolist()}
        self._ring = ring
        # An outline point that earcut left out of every triangle (collinear with its
        # neighbours) is split into the edge running through it: it needs its place too.
        left_out = np.setdiff1d(ring_edges, np.fromiter(self.p, dtype=np.int64, count=len(self.p)))
        self.p.update(zip(left_out.tolist(), map(tuple, self.xy[left_out].tolist()), strict=True))
        # The first sweep of splits tries every edge without a twin off the outline, and every
        # outline edge missing (found here with numpy; from then on _set finds them).
        tri = self.array()
        n = len(self.xy)
        u, v = tri.reshape(-1), tri[:, [1, 2, 0]].reshape(-1)
        have = np.sort(u * n + v)
        outline = ring_edges[:, 0] * n + ring_edges[:, 1]
        lonely = ~_member(v * n + u, have) & ~_member(u * n + v, np.sort(outline))
        missing = ring_edges[~_member(outline, have)]
        for a, b in ((u[lonely], v[lonely]), (missing[:, 0], missing[:, 1])):
            self._retry_split += zip(a.tolist(), b.tolist(), strict=True)
        for _ in range(4 * len(ring) + 8):
            if self._flip_slivers() or self._clip_slivers():
                continue
            if not self._close_t_junctions():
                break
        done = self.array()
        zeros = np.zeros(len(done), dtype=np.int64)
        ring_owner = np.zeros(len(ring_edges), dtype=np.int64)
        if needs_repair(
            self.xy, done, zeros, ring_edges=ring_edges, ring_owner=ring_owner, n_poly=1
        )[0]:
            raise ValueError(
                f"polygon {polygon} cannot be triangulated along its own edges (rings crossing,"
                " a hole outside its exterior, or earcut's output on a polygon of thousands of"
                f" holes, here {len(self.p)} points, beyond repair)"
            )


def strict_ears(p: dict[int, tuple[float, float]], loop: list[int]) -> list[Tri] | None:
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
