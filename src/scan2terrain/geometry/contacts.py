"""Diagonal contacts: where outline rings touch at a point, one vertex per sector of material
around it, each moved a hair into its own sector (:data:`SPLIT`), so the extruded mesh stays
2-manifold even for readers that weld vertices by position (:mod:`scan2terrain.geometry.mesh`)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

#: How far a vertex at a diagonal contact moves into its sector of material, along the sector's
#: bisector: this fraction of the shorter of its two outline edges, at most ``SPLIT_MAX`` metres
#: (0.5 mm on a 5 cm grid). Far above float32's step in map-frame metres (STL, COLLADA), far
#: below anything a robot or a physics engine resolves.
SPLIT = 0.01


SPLIT_MAX = 1e-3


class SharedPoints:
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
        self.angle_in = angles(xy[prv[m]] - xy[m])
        self.angle_out = angles(xy[nxt[m]] - xy[m])
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


def angles(d: NDArray[np.float64]) -> NDArray[np.float64]:
    angle: NDArray[np.float64] = np.arctan2(d[:, 1], d[:, 0])
    return angle
