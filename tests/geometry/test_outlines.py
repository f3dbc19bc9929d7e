"""Exact outlines of occupied cells, their simplification, and rasterising them back.

Hand-made grids check the shapes themselves (holes, islands in holes, diagonal contacts, single
cells, the whole grid, the grid's edges); hypothesis checks the invariants on random grids in
rotated frames; the real maps (after the default filter) check exactness and counts. Validity is
checked by brute force here, independently of the kernels' own intersection index.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from numpy.typing import NDArray
from scipy import ndimage

from scan2terrain.geometry.outlines import Polygon, rasterize, trace
from scan2terrain.geometry.simplify import simplify
from scan2terrain.types import Pose2D
from tests.geometry.shapes import default_filtered, grid

ORIGIN = Pose2D(0.0, 0.0, 0.0)


def rings_of(polygons: list[Polygon]) -> list[NDArray[np.float64]]:
    return [r for p in polygons for r in p.rings()]


def signed_area(ring: NDArray[np.float64]) -> float:
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


# --- independent validity checks ---------------------------------------------------------------


def _orient(a: NDArray[np.float64], b: NDArray[np.float64], c: NDArray[np.float64]) -> Any:
    """Sign of the turn a -> b -> c, zero within rounding (relative to the lengths involved and
    to the coordinates' magnitude)."""
    u, w = b - a, c - a
    v = u[..., 0] * w[..., 1] - u[..., 1] * w[..., 0]
    lu, lw = np.linalg.norm(u, axis=-1), np.linalg.norm(w, axis=-1)
    scale = 1e-9 * lu * lw + 1e-12 * (lu + lw) * (1.0 + np.abs(a).max(axis=-1))
    return np.where(np.abs(v) <= scale, 0, np.sign(v))


def check_valid(polygons: list[Polygon]) -> None:
    """Brute force: rings simple, no corners on a straight line, orientation, rings meeting only
    at vertices they both have and without crossing there, holes inside their exteriors."""
    rings = rings_of(polygons)
    if not rings:
        return
    seg_a = np.concatenate(rings)
    seg_b = np.concatenate([np.roll(r, -1, axis=0) for r in rings])
    for p in polygons:
        assert signed_area(p.exterior) > 0
        for h in p.holes:
            assert signed_area(h) < 0
            # Every hole vertex inside or on the exterior, and the hole's edge midpoints
            # strictly inside (they cannot lie on the exterior: rings share no edge).
            mid = 0.5 * (h + np.roll(h, -1, axis=0))
            assert inside(mid, p.exterior).all()
    for r in rings:
        assert len(r) >= 3
        assert len(np.unique(r, axis=0)) == len(r), "a ring visits a point twice"
        prev, nxt = np.roll(r, 1, axis=0), np.roll(r, -1, axis=0)
        assert (_orient(prev, r, nxt) != 0).all(), "a vertex between collinear neighbours"
    # Pairs of segments: they may only meet at a common endpoint.
    a1, b1 = seg_a[:, None], seg_b[:, None]
    a2, b2 = seg_a[None, :], seg_b[None, :]
    o1, o2 = _orient(a1, b1, a2), _orient(a1, b1, b2)
    o3, o4 = _orient(a2, b2, a1), _orient(a2, b2, b1)
    proper = (o1 * o2 < 0) & (o3 * o4 < 0)
    assert not proper.any(), "two outline edges cross"
    # Touching: an endpoint of one lying on the other, other than a shared endpoint.
    for p_end, (a, b) in ((seg_a, (seg_a, seg_b)), (seg_b, (seg_a, seg_b))):
        pe = p_end[:, None]
        on = (_orient(a[None], b[None], pe) == 0) & (
            np.einsum("ijk,ijk->ij", pe - a[None], pe - b[None]) < -1e-12
        )
        assert not on.any(), "an outline vertex lies inside another edge"
    # Shared vertices between rings: the two rings must not cross there.
    all_v = np.concatenate(rings)
    uniq, counts = np.unique(all_v, axis=0, return_counts=True)
    for v in uniq[counts > 1]:
        dirs = []
        for r in rings:
            k = np.nonzero((r == v).all(axis=1))[0]
            if len(k):
                i = int(k[0])
                n_, p_ = r[(i + 1) % len(r)] - v, r[i - 1] - v
                dirs.append((math.atan2(n_[1], n_[0]), math.atan2(p_[1], p_[0])))
        assert len(dirs) == 2
        (o_a, b_a), (o_b, b_b) = dirs
        span = (b_a - o_a) % (2 * math.pi)
        in1 = 0 < (o_b - o_a) % (2 * math.pi) < span
        in2 = 0 < (b_b - o_a) % (2 * math.pi) < span
        assert in1 == in2, "two rings cross at a shared vertex"


def inside(points: NDArray[np.float64], ring: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Even-odd point in polygon, brute force (rays towards +x)."""
    x, y = points[:, 0:1], points[:, 1:2]
    a, b = ring[None, :, :], np.roll(ring, -1, axis=0)[None, :, :]
    dy = b[..., 1] - a[..., 1]
    cond = (a[..., 1] > y) != (b[..., 1] > y)
    # x < crossing  <=>  (x - ax) dy < (y - ay)(bx - ax), the sense flipping with dy's sign.
    lhs = (x - a[..., 0]) * dy
    rhs = (y - a[..., 1]) * (b[..., 0] - a[..., 0])
    left = np.where(dy > 0, lhs < rhs, lhs > rhs)
    result: NDArray[np.bool_] = ((cond & left).sum(axis=1) % 2).astype(bool)
    return result


def polygons_partition(
    polygons: list[Polygon], occ: NDArray[np.bool_], res: float, origin: Pose2D
) -> None:
    """Each polygon covers a non-empty set of cells, no cell twice, together exactly ``occ``;
    sampled 3 x 3 per cell too, so overlapping interiors would show."""
    fine = Pose2D(origin.x, origin.y, origin.yaw)
    shape = (occ.shape[0] * 3, occ.shape[1] * 3)
    total = np.zeros(shape, dtype=np.int64)
    cells = np.zeros(occ.shape, dtype=np.int64)
    for p in polygons:
        one = rasterize([p], occ.shape, res, origin)
        assert one.any()
        cells += one
        total += rasterize([p], shape, res / 3, fine)
    assert (cells == occ).all()
    assert total.max() <= 1


# --- trace: hand-made grids ----------------------------------------------------------------------


def test_single_cell_is_a_counter_clockwise_square() -> None:
    occ = grid("""
        ...
        .#.
        ...
    """)
    (p,) = trace(occ, 0.5, Pose2D(10.0, 20.0, 0.0))
    assert p.holes == ()
    np.testing.assert_array_equal(
        p.exterior, [[10.5, 20.5], [11.0, 20.5], [11.0, 21.0], [10.5, 21.0]]
    )


def test_full_grid_and_empty_grid() -> None:
    (p,) = trace(np.ones((3, 4), dtype=bool), 1.0, ORIGIN)
    np.testing.assert_array_equal(p.exterior, [[0, 0], [4, 0], [4, 3], [0, 3]])
    assert trace(np.zeros((3, 4), dtype=bool), 1.0, ORIGIN) == []
    assert trace(np.zeros((0, 4), dtype=bool), 1.0, ORIGIN) == []


def test_hole_and_island_in_the_hole() -> None:
    occ = grid("""
        #######
        #.....#
        #.###.#
        #.#.#.#
        #.###.#
        #.....#
        #######
    """)
    polys = trace(occ, 1.0, ORIGIN)
    assert len(polys) == 2
    outer, island = polys
    assert len(outer.holes) == 1 and len(island.holes) == 1
    np.testing.assert_array_equal(outer.exterior, [[0, 0], [7, 0], [7, 7], [0, 7]])
    np.testing.assert_array_equal(outer.holes[0], [[1, 1], [1, 6], [6, 6], [6, 1]])
    np.testing.assert_array_equal(island.exterior, [[2, 2], [5, 2], [5, 5], [2, 5]])
    np.testing.assert_array_equal(island.holes[0], [[3, 3], [3, 4], [4, 4], [4, 3]])
    assert (rasterize(polys, occ.shape, 1.0, ORIGIN) == occ).all()
    check_valid(polys)


def test_diagonal_contact_makes_two_polygons_touching_at_a_corner() -> None:
    occ = grid("""
        .#
        #.
    """)
    a, b = trace(occ, 1.0, ORIGIN)
    np.testing.assert_array_equal(a.exterior, [[0, 0], [1, 0], [1, 1], [0, 1]])
    np.testing.assert_array_equal(b.exterior, [[1, 1], [2, 1], [2, 2], [1, 2]])
    check_valid([a, b])


def test_pocket_closed_only_by_a_diagonal_becomes_a_touching_hole() -> None:
    occ = grid("""
        ##.
        #.#
        ###
    """)
    (p,) = trace(occ, 1.0, ORIGIN)
    # The free middle cell meets the free top-right cell only at a corner: it is a hole that
    # touches the exterior at (2, 2).
    assert len(p.holes) == 1
    np.testing.assert_array_equal(p.holes[0], [[1, 1], [1, 2], [2, 2], [2, 1]])
    np.testing.assert_array_equal(p.exterior, [[0, 0], [3, 0], [3, 2], [2, 2], [2, 3], [0, 3]])
    assert (rasterize([p], occ.shape, 1.0, ORIGIN) == occ).all()
    check_valid([p])


def test_two_pockets_and_a_chain_of_diagonals() -> None:
    occ = grid("""
        ###.
        #.#.
        ##.#
        ####
    """)
    (p,) = trace(occ, 1.0, ORIGIN)
    assert len(p.holes) == 2
    assert (rasterize([p], occ.shape, 1.0, ORIGIN) == occ).all()
    check_valid([p])


def test_checkerboard_is_one_square_per_cell() -> None:
    occ = (np.indices((5, 6)).sum(axis=0) % 2).astype(bool)
    polys = trace(occ, 1.0, ORIGIN)
    assert len(polys) == occ.sum()
    assert all(len(p.exterior) == 4 and not p.holes for p in polys)
    check_valid(polys)
    assert (rasterize(polys, occ.shape, 1.0, ORIGIN) == occ).all()


def test_cells_on_the_grid_edges_and_corners() -> None:
    occ = grid("""
        #..#
        ....
        #..#
        ####
    """)
    polys = trace(occ, 0.25, Pose2D(-1.0, 3.0, 0.0))
    assert len(polys) == 3
    assert (rasterize(polys, occ.shape, 0.25, Pose2D(-1.0, 3.0, 0.0)) == occ).all()
    # The bottom row and the two cells above its ends: one U with corners only.
    u = polys[0]
    assert len(u.exterior) == 8


def test_yaw_rotates_about_the_lower_left_corner() -> None:
    occ = grid("#.")
    (p,) = trace(occ, 2.0, Pose2D(1.0, 1.0, math.pi / 2))
    np.testing.assert_allclose(p.exterior, [[1, 1], [1, 3], [-1, 3], [-1, 1]], atol=1e-12)
    assert signed_area(p.exterior) == pytest.approx(4.0)


def test_bad_input() -> None:
    with pytest.raises(ValueError, match="2D"):
        trace(np.zeros(3, dtype=bool), 1.0, ORIGIN)
    with pytest.raises(ValueError, match="resolution"):
        trace(np.zeros((2, 2), dtype=bool), 0.0, ORIGIN)
    with pytest.raises(ValueError, match="N >= 3"):
        rasterize([Polygon(np.zeros((2, 2)))], (2, 2), 1.0, ORIGIN)


# --- invariants on random grids ----------------------------------------------------------------

grids = arrays(
    np.bool_,
    st.tuples(st.integers(1, 12), st.integers(1, 12)),
    elements=st.booleans(),
)
frames = st.tuples(
    st.sampled_from([0.05, 0.1, 0.3, 1.0]),
    st.floats(-500, 500),
    st.floats(-500, 500),
    st.floats(-math.pi, math.pi),
)


@settings(max_examples=150, deadline=None)
@given(occ=grids, frame=frames)
def test_trace_is_exact_and_valid(occ: NDArray[np.bool_], frame: tuple[float, ...]) -> None:
    res, x, y, yaw = frame
    origin = Pose2D(x, y, yaw)
    polys = trace(occ, res, origin)
    assert (rasterize(polys, occ.shape, res, origin) == occ).all()
    assert sum(p.area() for p in polys) == pytest.approx(occ.sum() * res * res, abs=1e-6)
    # One polygon per 4-connected group of cells.
    assert len(polys) == ndimage.label(occ)[1]
    polygons_partition(polys, occ, res, origin)
    check_valid(polys)


@settings(max_examples=150, deadline=None)
@given(occ=grids, frame=frames, tolerance=st.sampled_from([0.0, 0.3, 0.5, 1.0, 2.0, 5.0]))
def test_simplify_keeps_cells_and_validity(
    occ: NDArray[np.bool_], frame: tuple[float, ...], tolerance: float
) -> None:
    res, x, y, yaw = frame
    origin = Pose2D(x, y, yaw)
    exact = trace(occ, res, origin)
    simple = simplify(exact, tolerance * res, resolution=res, origin=origin)
    assert (rasterize(simple, occ.shape, res, origin) == occ).all()
    assert [len(p.holes) for p in simple] == [len(p.holes) for p in exact]
    polygons_partition(simple, occ, res, origin)
    check_valid(simple)
    for before, after in zip(rings_of(exact), rings_of(simple), strict=True):
        assert len(after) <= len(before) * 2  # chamfer points replace at most each corner
        # Within tolerance both ways: exact corners near the simplified ring, simplified
        # vertices on the exact ring.
        assert distance_to_ring(before, after).max() <= tolerance * res * (1 + 1e-9) + 1e-9
        assert distance_to_ring(after, before).max() <= 1e-9 * (1 + abs(x) + abs(y))
    # Simplifying again changes nothing about the cells.
    again = simplify(simple, tolerance * res, resolution=res, origin=origin)
    assert (rasterize(again, occ.shape, res, origin) == occ).all()


def distance_to_ring(points: NDArray[np.float64], ring: NDArray[np.float64]) -> Any:
    """Distance from each point to the closed polyline ``ring``."""
    a, b = ring[None, :, :], np.roll(ring, -1, axis=0)[None, :, :]
    p = points[:, None, :]
    d = b - a
    t = np.clip(np.einsum("ijk,ijk->ij", p - a, d) / np.einsum("ijk,ijk->ij", d, d), 0, 1)
    closest = a + t[..., None] * d
    return np.linalg.norm(p - closest, axis=2).min(axis=1)


def test_simplify_straightens_a_staircase_through_the_step_midpoints() -> None:
    occ = np.tril(np.ones((8, 8), dtype=bool))  # cells on and above the diagonal
    exact = trace(occ, 1.0, ORIGIN)
    (p,) = simplify(exact, 1.0, resolution=1.0, origin=ORIGIN)
    assert len(exact[0].exterior) == 18
    # The staircase becomes one edge through the midpoints of its steps; it keeps
    # sqrt(2)/4 cell from the centres on both sides.
    np.testing.assert_array_equal(
        p.exterior, [[0.5, 0], [8, 7.5], [7.5, 8], [0.5, 8], [0, 7.5], [0, 0.5]]
    )
    assert (rasterize([p], occ.shape, 1.0, ORIGIN) == occ).all()


def test_simplify_keeps_thin_walls_whole() -> None:
    occ = np.zeros((9, 40), dtype=bool)
    occ[4, :20] = True
    occ[5, 20:] = True  # a wall one cell thick with a one-cell jog
    occ[0, ::2] = True  # specks
    simple = simplify(trace(occ, 0.05, ORIGIN), 0.1, resolution=0.05, origin=ORIGIN)
    assert (rasterize(simple, occ.shape, 0.05, ORIGIN) == occ).all()
    # Nothing to straighten: every piece stays a rectangle (plain Douglas-Peucker with a
    # tolerance of two cells would collapse them all).
    assert len(simple) == 22
    assert all(len(p.exterior) == 4 for p in simple)
    # Every centre keeps its distance from the outline.
    centres = (
        np.stack(np.nonzero(np.ones(occ.shape, dtype=bool))[::-1], axis=1).astype(np.float64) + 0.5
    )
    for p in simple:
        assert distance_to_ring(centres * 0.05, p.exterior).min() >= 0.15 * 0.05 - 1e-12


def test_simplify_rejects_what_is_not_on_the_grid() -> None:
    off = Polygon(np.array([[0.1, 0.0], [1.0, 0.0], [1.0, 1.0]]))
    with pytest.raises(ValueError, match="cell corner"):
        simplify([off], 1.0, resolution=1.0, origin=ORIGIN)
    with pytest.raises(ValueError, match="tolerance"):
        simplify([], -1.0, resolution=1.0, origin=ORIGIN)
    crossing = Polygon(np.array([[0.0, 0.0], [2.0, 2.0], [2.0, 0.0], [0.0, 2.0]]))
    with pytest.raises(ValueError, match="cross"):
        simplify([crossing], 0.0, resolution=1.0, origin=ORIGIN)


# --- real maps -----------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["levine", "warehouse", "willow", "tb3"])
def test_real_maps_trace_exactly(name: str) -> None:
    occ, res, origin = default_filtered(name)
    polys = trace(occ, res, origin)
    assert (rasterize(polys, occ.shape, res, origin) == occ).all()
    simple = simplify(polys, res, resolution=res, origin=origin)
    assert (rasterize(simple, occ.shape, res, origin) == occ).all()
    n_exact = sum(len(r) for r in rings_of(polys))
    n_simple = sum(len(r) for r in rings_of(simple))
    print(
        f"\n{name}: {int(occ.sum())} occupied cells, {len(polys)} polygons,"
        f" {sum(len(p.holes) for p in polys)} holes, {n_exact} vertices exact,"
        f" {n_simple} simplified (1 cell)"
    )
    # Levine's walls are axis-parallel rectangles already: nothing to straighten there.
    assert n_simple < n_exact if name != "levine" else n_simple == n_exact
