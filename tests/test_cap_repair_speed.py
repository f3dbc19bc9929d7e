"""Cap repair on speckle maps (about one wall cell in two, what an airborne survey at about one
point a cell gives): one polygon holds thousands of holes, and earcut leaves its cap with
thousands of slivers. The walls still make one closed solid, and the repair's work grows with
the map, not faster (counted in attempts, not timed: timings flake). T-junctions, which the
speckle maps do not make, are split on hand-made caps."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray

from scan2terrain.geometry import caps
from scan2terrain.geometry._cap_repair import _Cap
from scan2terrain.geometry.mesh import extrude
from scan2terrain.geometry.outlines import trace
from scan2terrain.types import Pose2D
from tests.geometry.shapes import check_solid

Tri = tuple[int, int, int]


def speckle(size: int, fill: float = 0.63, seed: int = 0) -> NDArray[np.bool_]:
    walls: NDArray[np.bool_] = np.random.default_rng(seed).random((size, size)) < fill
    return walls


def test_speckle_map_extrudes_to_a_closed_solid() -> None:
    origin = Pose2D(2.0, -1.0, 0.3)
    polys = trace(speckle(120), 0.1, origin)
    assert max(len(p.holes) for p in polys) > 500  # one polygon, full of holes
    check_solid(extrude(polys, 2.0), polys, 2.0, 0.0)


def test_repair_work_grows_as_the_map(monkeypatch: pytest.MonkeyPatch) -> None:
    """Four times the cells, about four times the attempts. Trying every sliver again each
    round, as the repair once did, made it ten times as many (and took minutes at 400 x 400)."""
    attempts: list[int] = []

    class Counted(_Cap):
        def repair(self, ring_edges: NDArray[np.int64], polygon: int) -> None:
            super().repair(ring_edges, polygon)
            attempts.append(self.attempts)

    monkeypatch.setattr(caps, "_Cap", Counted)
    work = {}
    for size in (60, 120, 240):
        attempts.clear()
        extrude(trace(speckle(size), 0.1, Pose2D(0.0, 0.0)), 2.0)
        work[size] = sum(attempts)
    assert work[60] > 100
    assert work[120] <= 5 * work[60]
    assert work[240] <= 5 * work[120]


def repaired(xy: list[tuple[float, float]], tri: list[Tri], ring: list[int]) -> set[Tri]:
    """The cap's triangles after repair, each turned to start at its lowest corner."""
    cap = _Cap(np.array(xy, dtype=np.float64), np.array(tri, dtype=np.int64))
    edges = np.array([(a, ring[(i + 1) % len(ring)]) for i, a in enumerate(ring)])
    cap.repair(edges, 0)
    turned = (tuple(np.roll(t, -int(np.argmin(t))).tolist()) for t in cap.array())
    return {(a, b, c) for a, b, c in turned}


def test_outline_point_left_out_is_split_in() -> None:
    # A 2 x 1 rectangle whose triangles leave out point 1, halfway along the bottom edge.
    xy = [(0.0, 0.0), (1.0, 0.0), (2.0, 0.0), (2.0, 1.0), (0.0, 1.0)]
    got = repaired(xy, [(0, 2, 3), (0, 3, 4)], [0, 1, 2, 3, 4])
    assert got == {(0, 1, 3), (1, 2, 3), (0, 3, 4)}


def test_edge_through_a_point_is_split_there() -> None:
    # A 2 x 2 square: one triangle's edge 2 -> 0 runs through point 4, where the two
    # triangles across it meet.
    xy = [(0.0, 0.0), (2.0, 0.0), (2.0, 2.0), (0.0, 2.0), (1.0, 1.0)]
    got = repaired(xy, [(0, 1, 2), (2, 3, 4), (0, 4, 3)], [0, 1, 2, 3])
    assert got == {(1, 2, 4), (0, 1, 4), (2, 3, 4), (0, 4, 3)}
