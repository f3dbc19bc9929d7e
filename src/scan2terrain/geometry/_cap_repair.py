"""Local repair of an earcut triangulation of one cap (:class:`_Cap`): slivers flipped away,
T-junctions split, runs of slivers ear-clipped anew, so that every cap edge on the outline is
exactly a wall quad's edge and every face has area."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


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
        #: The slivers among them, kept as triangles change (not found anew over every
        #: triangle each round: a speckled map's one big cap made that quadratic).
        self.slivers: set[int] = set()
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
            if tri is not None and self._sliver(t):
                self.slivers.add(t)
            else:
                self.slivers.discard(t)
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
        """Indices of the slivers (see :meth:`_sliver`), in order."""
        return sorted(self.slivers)

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
