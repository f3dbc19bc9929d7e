"""Voxels -> occupancy / height grids, ground estimate and hole filling, on hand-made voxel sets."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from numpy.typing import NDArray

from scan2terrain.grids.projection import (
    ColumnStats,
    column_stats,
    estimate_ground,
    fill_idw,
    fill_nearest,
    project_occupancy,
)
from scan2terrain.types import FREE, OCCUPIED, UNKNOWN, HeightGrid, Pose2D

RES = 0.1
OFF = 32768
NAN = math.nan


def voxels(*blocks: tuple[NDArray[Any], bool]) -> tuple[NDArray[np.uint16], NDArray[np.bool_]]:
    """Keys and occupancy from blocks of voxel indices (i, j, k) = key - 32768."""
    keys = np.concatenate([np.asarray(ijk, dtype=np.int64).reshape(-1, 3) for ijk, _ in blocks])
    occ = np.concatenate([np.full(len(np.asarray(ijk).reshape(-1, 3)), o) for ijk, o in blocks])
    return (keys + OFF).astype(np.uint16), occ.astype(bool)


def box(i: range, j: range, k: range) -> NDArray[np.int64]:
    """All voxel indices of a box, shape (N, 3)."""
    return np.stack(np.meshgrid(i, j, k, indexing="ij"), axis=-1).reshape(-1, 3)


def grid(text: str) -> NDArray[np.int8]:
    """int8 occupancy from rows of ``#`` occupied, ``.`` free, ``?`` unknown; the FIRST line is
    row 0 (lowest y)."""
    codes = {"#": OCCUPIED, ".": FREE, "?": UNKNOWN}
    return np.array(
        [[codes[c] for c in line.split()] for line in text.strip().splitlines()], np.int8
    )


def cell_centre(origin: Pose2D, row: int, col: int, res: float) -> tuple[float, float]:
    x, y = origin.transform(np.array((col + 0.5) * res), np.array((row + 0.5) * res))
    return float(x), float(y)


# --- occupancy projection -------------------------------------------------------------------


def wall_scene() -> tuple[NDArray[np.uint16], NDArray[np.bool_]]:
    # Wall: x in [0, 0.6) (i = 0..5), y in [0.1, 0.2) (j = 1), z in [0, 2) (k = 0..19).
    wall = box(range(6), range(1, 2), range(20))
    # Free floor band (k = 1..3) over i = -1..6, j = 0..2, except where the wall stands.
    floor = box(range(-1, 7), range(3), range(1, 4))
    floor = floor[~((floor[:, 1] == 1) & (floor[:, 0] >= 0) & (floor[:, 0] <= 5))]
    # One free voxel far away widens the grid: the cells between stay unknown.
    far = np.array([[8, 4, 2]])
    return voxels((wall, True), (floor, False), (far, False))


def test_wall_projects_to_a_line_of_occupied_cells() -> None:
    keys, occ = wall_scene()
    out = project_occupancy(keys, occ, RES)
    expected = grid("""
        . . . . . . . . ? ?
        . # # # # # # . ? ?
        . . . . . . . . ? ?
        ? ? ? ? ? ? ? ? ? ?
        ? ? ? ? ? ? ? ? ? .
    """)
    np.testing.assert_array_equal(out.data, expected)
    assert out.data.dtype == np.int8
    assert out.resolution == RES
    # Origin on the boundary of voxel column (i, j) = (-1, 0).
    assert out.origin == Pose2D(-1 * RES, 0.0, 0.0)
    # Cell (1, 3) is voxel column (i, j) = (2, 1), centre (0.25, 0.15).
    assert cell_centre(out.origin, 1, 3, RES) == pytest.approx((0.25, 0.15), abs=1e-12)


def test_wall_band_above_the_wall_is_free_where_observed() -> None:
    keys, occ = wall_scene()
    # Band above the wall top (2 m): no voxel there, so everything is unknown, same frame.
    out = project_occupancy(keys, occ, RES, z_min=2.0, z_max=3.0)
    assert out.shape == (5, 10)
    assert (out.data == UNKNOWN).all()


def table_scene(*, floor_under_table: bool) -> tuple[NDArray[np.uint16], NDArray[np.bool_]]:
    # Table top: z in [0.9, 1.0) (k = 9) over i, j = 1..2; free air k = 1..4 around it.
    top = box(range(1, 3), range(1, 3), range(9, 10))
    air = box(range(4), range(4), range(1, 5))
    if not floor_under_table:
        air = air[~((air[:, 0] >= 1) & (air[:, 0] <= 2) & (air[:, 1] >= 1) & (air[:, 1] <= 2))]
    return voxels((top, True), (air, False))


def test_table_outside_band_is_free_when_floor_under_it_was_seen() -> None:
    keys, occ = table_scene(floor_under_table=True)
    out = project_occupancy(keys, occ, RES, z_min=0.0, z_max=0.5)
    np.testing.assert_array_equal(out.data, np.zeros((4, 4), np.int8))


def test_table_outside_band_is_unknown_when_floor_under_it_was_not_seen() -> None:
    keys, occ = table_scene(floor_under_table=False)
    out = project_occupancy(keys, occ, RES, z_min=0.0, z_max=0.5)
    expected = grid("""
        . . . .
        . ? ? .
        . ? ? .
        . . . .
    """)
    np.testing.assert_array_equal(out.data, expected)


@pytest.mark.parametrize("floor_under_table", [True, False])
def test_table_inside_band_is_occupied(floor_under_table: bool) -> None:
    keys, occ = table_scene(floor_under_table=floor_under_table)
    out = project_occupancy(keys, occ, RES, z_min=0.0, z_max=1.2)
    expected = grid("""
        . . . .
        . # # .
        . # # .
        . . . .
    """)
    np.testing.assert_array_equal(out.data, expected)


def test_band_tests_voxel_centres_inclusively() -> None:
    # Table top centre is at 9.5 * res = 0.95 m: in [c, c], not in [0, 0.949] nor [0.951, 2].
    keys, occ = table_scene(floor_under_table=True)
    c = 9.5 * RES  # the centre exactly as float arithmetic gives it (0.9500000000000001)
    assert project_occupancy(keys, occ, RES, z_min=c, z_max=c).data[1, 1] == OCCUPIED
    assert project_occupancy(keys, occ, RES, z_min=0.0, z_max=0.949).data[1, 1] == FREE
    assert project_occupancy(keys, occ, RES, z_min=0.951, z_max=2).data[1, 1] == UNKNOWN


def test_unobserved_room_is_unknown() -> None:
    # Two observed rooms (free floor, walls) with an unobserved one between them.
    west = box(range(3), range(3), range(2))
    east = box(range(6, 9), range(3), range(2))
    walls = np.array([[0, 0, 5], [8, 2, 5]])
    keys, occ = voxels((west, False), (east, False), (walls, True))
    out = project_occupancy(keys, occ, RES)
    expected = grid("""
        # . . ? ? ? . . .
        . . . ? ? ? . . .
        . . . ? ? ? . . #
    """)
    np.testing.assert_array_equal(out.data, expected)


def test_negative_coordinates() -> None:
    keys, occ = voxels(
        (np.array([[-3, -2, -1], [-1, -1, -7]]), True), (np.array([[-2, -2, 0]]), False)
    )
    out = project_occupancy(keys, occ, 0.25)
    np.testing.assert_array_equal(out.data, grid("# . ?\n? ? #"))
    assert out.origin == Pose2D(-0.75, -0.5, 0.0)
    assert cell_centre(out.origin, 1, 2, 0.25) == pytest.approx((-0.125, -0.125))


def test_keys_at_the_ends_of_the_uint16_range() -> None:
    keys = np.array([[0, 65535, 0], [2, 65533, 65535], [1, 65534, 100]], dtype=np.uint16)
    occ = np.array([True, True, False])
    out = project_occupancy(keys, occ, RES)
    np.testing.assert_array_equal(out.data, grid("? ? #\n? . ?\n# ? ?"))
    assert out.origin.x == pytest.approx(-32768 * RES)
    assert out.origin.y == pytest.approx((65533 - OFF) * RES)
    # The far corner cell is the last key column, centre (32767.5 * res).
    assert cell_centre(out.origin, 2, 0, RES)[1] == pytest.approx(32767.5 * RES)
    # Other integer dtypes are accepted when they hold 16-bit keys.
    same = project_occupancy(keys.astype(np.int64), occ, RES)
    np.testing.assert_array_equal(same.data, out.data)
    stats = column_stats(keys, occ, RES)
    assert stats.max_z[2, 0] == np.float32(-32767.5 * RES)
    assert stats.max_z[0, 2] == np.float32(32767.5 * RES)


def test_bounds_snap_outwards_and_crop() -> None:
    keys, occ = wall_scene()
    # x in [0.3, 0.6) -> columns i = 3..5; y in [-0.1, 0.25) -> rows j = -1..2.
    out = project_occupancy(keys, occ, RES, bounds=(0.3, -0.1, 0.6, 0.25))
    expected = grid("""
        ? ? ?
        . . .
        # # #
        . . .
    """)
    np.testing.assert_array_equal(out.data, expected)
    assert out.origin.x == pytest.approx(0.3)
    assert out.origin.y == pytest.approx(-0.1)
    # A box entirely away from the voxels is all unknown.
    empty = project_occupancy(keys, occ, RES, bounds=(-5.0, -5.0, -4.0, -4.5))
    assert empty.shape == (5, 10)
    assert (empty.data == UNKNOWN).all()
    # Stats on the same bounds share the frame.
    stats = column_stats(keys, occ, RES, bounds=(0.3, -0.1, 0.6, 0.25))
    assert stats.shape == out.shape
    assert stats.origin == out.origin
    np.testing.assert_array_equal(stats.known, out.data == OCCUPIED)


@settings(max_examples=60, deadline=None)
@given(
    ijk=hnp.arrays(
        np.int64, st.tuples(st.integers(1, 40), st.just(3)), elements=st.integers(-4, 4)
    ),
    data=st.data(),
)
def test_projection_and_stats_match_a_voxel_by_voxel_reference(
    ijk: NDArray[np.int64], data: Any
) -> None:
    """The vectorised code against the definition, voxel by voxel (duplicate keys allowed)."""
    occ = data.draw(hnp.arrays(np.bool_, len(ijk)))
    z_lo = data.draw(st.sampled_from([-math.inf, -0.2, 0.0, 0.15]))
    z_hi = data.draw(st.sampled_from([math.inf, 0.25, 0.3]))
    box_ = data.draw(st.none() | st.just((-0.25, -0.1, 0.2, 0.35)))
    keys = (ijk + OFF).astype(np.uint16)
    out = project_occupancy(keys, occ, RES, z_min=z_lo, z_max=z_hi, bounds=box_)
    stats = column_stats(keys, occ, RES, z_min=z_lo, z_max=z_hi, bounds=box_)
    i0, j0 = (-3, -1) if box_ else (ijk[:, 0].min(), ijk[:, 1].min())
    expected = np.full(out.shape, UNKNOWN, np.int8)
    zs: dict[tuple[int, int], list[float]] = {}
    for (i, j, k), o in zip(ijk.tolist(), occ.tolist(), strict=True):
        row, col = j - j0, i - i0
        z = (k + 0.5) * RES
        if not (0 <= row < out.shape[0] and 0 <= col < out.shape[1] and z_lo <= z <= z_hi):
            continue
        if o:
            expected[row, col] = OCCUPIED
            zs.setdefault((row, col), []).append(z)
        elif expected[row, col] == UNKNOWN:
            expected[row, col] = FREE
    np.testing.assert_array_equal(out.data, expected)
    assert out.origin == Pose2D(int(i0) * RES, int(j0) * RES, 0.0)
    assert stats.shape == out.shape
    np.testing.assert_array_equal(stats.known, expected == OCCUPIED)
    for (row, col), col_z in zs.items():
        assert stats.count[row, col] == len(col_z)
        assert stats.max_z[row, col] == np.float32(max(col_z))
        assert stats.min_z[row, col] == np.float32(min(col_z))
        assert stats.mean_z[row, col] == pytest.approx(np.mean(col_z), abs=1e-6)


# --- column statistics ----------------------------------------------------------------------


def stats_scene() -> tuple[NDArray[np.uint16], NDArray[np.bool_]]:
    # Column (0, 0): occupied k = 0, 2, 5; column (1, 0): free only; column (2, 0): k = -3.
    occ = np.array([[0, 0, 0], [0, 0, 2], [0, 0, 5], [2, 0, -3]])
    free = np.array([[1, 0, 1], [0, 0, 1]])
    return voxels((occ, True), (free, False))


def test_column_stats_per_column() -> None:
    keys, occ = stats_scene()
    s = column_stats(keys, occ, RES)
    assert s.shape == (1, 3)
    z = np.float32
    np.testing.assert_array_equal(s.max_z, [[z(0.55), NAN, z(-0.25)]])
    np.testing.assert_array_equal(s.min_z, [[z(0.05), NAN, z(-0.25)]])
    np.testing.assert_allclose(s.mean_z, [[0.85 / 3, NAN, -0.25]], rtol=1e-6)
    np.testing.assert_array_equal(s.count, [[3, 0, 1]])
    np.testing.assert_array_equal(s.known, [[True, False, True]])
    assert s.max_z.dtype == s.min_z.dtype == s.mean_z.dtype == np.float32
    assert s.count.dtype == np.int32
    assert s.origin == Pose2D(0.0, 0.0, 0.0)


def test_column_stats_band() -> None:
    keys, occ = stats_scene()
    s = column_stats(keys, occ, RES, z_min=0.0, z_max=0.3)
    np.testing.assert_array_equal(s.max_z, [[np.float32(0.25), NAN, NAN]])
    np.testing.assert_array_equal(s.count, [[2, 0, 0]])
    np.testing.assert_array_equal(s.known, [[True, False, False]])


def test_height_grid_from_stats_and_above_ground() -> None:
    keys, occ = stats_scene()
    s = column_stats(keys, occ, RES)
    hg = s.to_height_grid("min")
    assert isinstance(hg, HeightGrid)
    assert hg.heights.dtype == np.float32
    np.testing.assert_array_equal(hg.heights, s.min_z)
    np.testing.assert_array_equal(hg.known, s.known)
    assert (hg.resolution, hg.origin) == (s.resolution, s.origin)
    ground = np.array([[0.05, 0.0, NAN]], dtype=np.float32)
    above = s.to_height_grid("max", ground=ground)
    np.testing.assert_allclose(above.heights, [[0.5, NAN, NAN]], rtol=1e-6)
    # No ground under column 2: its height above ground is unknown.
    np.testing.assert_array_equal(above.known, [[True, False, False]])
    mean = s.to_height_grid("mean", ground=np.zeros((1, 3), np.float32))
    np.testing.assert_array_equal(mean.heights, s.mean_z)


def test_height_grid_does_not_share_memory_with_stats() -> None:
    keys, occ = stats_scene()
    s = column_stats(keys, occ, RES)
    hg = s.to_height_grid("max")
    hg.heights[0, 0] = 7.0
    hg.known[0, 0] = False
    assert s.max_z[0, 0] == np.float32(0.55)
    assert s.known[0, 0]


# --- ground -----------------------------------------------------------------------------------


def test_estimate_ground_follows_a_sloped_floor_not_the_boxes() -> None:
    n = 60  # 6 m x 6 m at 0.1 m, floor rising 0.1 m per metre along x (one voxel per 10 cells)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    floor_k = i // 10
    ijk = np.stack([i, j, floor_k], axis=-1)
    unseen = np.zeros((n, n), dtype=bool)  # floor hidden under the boxes, and a hole
    unseen[20:25, 20:25] = unseen[30:38, 10:18] = unseen[45:48, 45:48] = True
    floor = ijk[~unseen]
    # A 0.5 m box seen only from above (its top 0.5 m over the floor) ...
    top = (ijk + np.array([0, 0, 5]))[20:25, 20:25].reshape(-1, 3)
    # ... and a 0.8 m box whose sides were seen (voxels 0.1..0.8 m up its outer columns).
    sides = np.zeros((n, n), dtype=bool)
    sides[30:38, 10:18] = True
    sides[31:37, 11:17] = False
    tall_box = np.concatenate(
        [(ijk + np.array([0, 0, 8]))[30:38, 10:18].reshape(-1, 3)]
        + [(ijk + np.array([0, 0, dk]))[sides] for dk in range(1, 8)]
    )
    air = (ijk + np.array([0, 0, 12])).reshape(-1, 3)
    keys, occ = voxels((floor, True), (top, True), (tall_box, True), (air, False))
    stats = column_stats(keys, occ, RES)
    ground = estimate_ground(stats, window_m=2.0)
    assert ground.shape == (n, n)
    assert ground.dtype == np.float32
    assert np.isfinite(ground).all()
    truth = ((floor_k + 0.5) * RES).T  # grid rows are y (j), columns x (i)
    # Away from the uphill edge (half a window) the ground is the floor within a voxel.
    interior = np.s_[:, : n - 10]
    np.testing.assert_allclose(ground[interior], truth[interior], atol=RES + 1e-6)
    # Exact on the open floor, including the unobserved hole (filled from its neighbours).
    np.testing.assert_allclose(ground[40:50, :10], truth[40:50, :10], atol=1e-6)
    np.testing.assert_allclose(ground[45:48, 45:48], truth[45:48, 45:48], atol=RES + 1e-6)
    # The box tops are well above the estimate.
    assert (stats.max_z[20:25, 20:25] - ground[20:25, 20:25] > 0.4).all()
    assert (stats.max_z[10:18, 30:38] - ground[10:18, 30:38] > 0.7).all()
    # Heights above ground: the floor is ~0, the tall box ~0.8 m.
    above = stats.to_height_grid("max", ground=ground)
    assert abs(float(above.heights[5, 5])) < 1e-6
    assert float(above.heights[14, 34]) == pytest.approx(0.8, abs=0.15)


def test_estimate_ground_window_of_one_cell_is_the_lowest_voxel() -> None:
    keys, occ = stats_scene()
    s = column_stats(keys, occ, RES)
    ground = estimate_ground(s, window_m=0.1)
    # Column 1 has no occupied voxel: filled from a nearest neighbour.
    assert ground[0, 0] == np.float32(0.05)
    assert ground[0, 2] == np.float32(-0.25)
    assert ground[0, 1] in (np.float32(0.05), np.float32(-0.25))


# --- hole filling -----------------------------------------------------------------------------


def hgrid(values: list[list[float]], res: float = 1.0) -> HeightGrid:
    heights = np.array(values, dtype=np.float32)
    return HeightGrid(heights, ~np.isnan(heights), res, Pose2D(1.0, 2.0))


def test_fill_nearest_exact() -> None:
    g = hgrid([[1, NAN, NAN, 5, NAN, NAN, NAN]], res=0.5)
    out = fill_nearest(g)
    np.testing.assert_array_equal(out.heights, [[1, 1, 5, 5, 5, 5, 5]])
    assert out.known.all()
    assert (out.resolution, out.origin) == (g.resolution, g.origin)
    # Within 1 m = 2 cells only; the last cell is 1.5 m away.
    near = fill_nearest(g, max_distance_m=1.0)
    np.testing.assert_array_equal(near.heights, [[1, 1, 5, 5, 5, 5, NAN]])
    np.testing.assert_array_equal(near.known, [[True] * 6 + [False]])
    # The input is untouched.
    assert np.isnan(g.heights[0, 1])
    assert not g.known[0, 1]


def test_fill_nearest_diagonal_distance() -> None:
    g = hgrid([[7, NAN, NAN], [NAN, NAN, NAN], [NAN, NAN, 3]])
    out = fill_nearest(g, max_distance_m=1.5)
    # (0, 2) and (2, 0) are 2 cells from both donors: beyond 1.5; (1, 1) is sqrt(2) from both.
    assert out.heights[0, 1] == 7
    assert out.heights[1, 0] == 7
    assert out.heights[1, 2] == 3
    assert out.heights[2, 1] == 3
    assert out.heights[1, 1] in (3, 7)
    np.testing.assert_array_equal(
        out.known, [[True, True, False], [True, True, True], [False, True, True]]
    )


def test_fill_nearest_without_known_cells_is_a_copy() -> None:
    g = hgrid([[NAN, NAN]])
    out = fill_nearest(g)
    assert not out.known.any()
    assert out.heights is not g.heights


def test_fill_idw_exact_euclidean_power_two() -> None:
    # Edge neighbours weigh 1, corner neighbours 1 / (sqrt 2)^2 = 1/2.
    g = hgrid([[NAN, 1, NAN], [2, NAN, NAN], [NAN, NAN, 4]])
    out = fill_idw(g, window=1, power=2.0)
    # Centre: (1 + 2 + 4 / 2) / (1 + 1 + 1/2) = 2.
    assert out.heights[1, 1] == np.float32(2.0)
    # (0, 0): 1 and 2 at distance 1: 1.5.
    assert out.heights[0, 0] == np.float32(1.5)
    # (2, 0): 2 at distance 1 only (4 is 2 cells away, outside the window): 2.
    assert out.heights[2, 0] == np.float32(2.0)
    # (1, 2): 1 at corner (1/2), 4 at edge (1): (0.5 + 4) / 1.5 = 3.
    assert out.heights[1, 2] == np.float32(3.0)
    assert out.known.all()
    # Known cells unchanged.
    np.testing.assert_array_equal(out.heights[g.known], g.heights[g.known])


def test_fill_idw_window_and_pdal_metric() -> None:
    g = hgrid([[2, NAN, NAN, 8, NAN, NAN, NAN]])
    # PDAL: Chebyshev distance, power 1: (2/1 + 8/2) / (1 + 1/2) = 4; (2/2 + 8/1) / 1.5 = 6.
    pdal = fill_idw(g, window=2, power=1.0, metric="chebyshev")
    np.testing.assert_array_equal(pdal.heights, [[2, 4, 6, 8, 8, 8, NAN]])
    np.testing.assert_array_equal(pdal.known, [[True] * 6 + [False]])
    # Euclidean power 2, window 2: (2 + 8/4) / 1.25 = 3.2; cell 5: 8 alone.
    euc = fill_idw(g, window=2, power=2.0)
    assert euc.heights[0, 1] == np.float32(3.2)
    assert euc.heights[0, 2] == np.float32((2 / 4 + 8) / 1.25)
    # Window 1: cell 5 is 2 cells from the nearest donor and stays unknown.
    one = fill_idw(g, window=1)
    np.testing.assert_array_equal(one.known, [[True, True, True, True, True, False, False]])
    np.testing.assert_array_equal(one.heights[0, :5], [2, 2, 8, 8, 8])


def test_fill_idw_uses_only_original_donors() -> None:
    g = hgrid([[10, NAN, NAN, NAN]])
    out = fill_idw(g, window=1)
    # (0, 2) would get a value if (0, 1) fed it; it does not.
    np.testing.assert_array_equal(out.known, [[True, True, False, False]])


height_arrays = hnp.arrays(
    np.float32,
    hnp.array_shapes(min_dims=2, max_dims=2, min_side=1, max_side=12),
    elements=st.floats(-1e4, 1e4, width=32),
)


@settings(max_examples=80, deadline=None)
@given(heights=height_arrays, data=st.data())
def test_filled_values_lie_within_the_known_range(heights: NDArray[np.float32], data: Any) -> None:
    known = data.draw(hnp.arrays(np.bool_, heights.shape))
    if not known.any():
        known.flat[0] = True
    g = HeightGrid(np.where(known, heights, np.float32(NAN)), known, 0.5, Pose2D(0.0, 0.0))
    lo, hi = heights[known].min(), heights[known].max()
    window = data.draw(st.integers(1, 3))
    power = data.draw(st.floats(0.0, 4.0))
    metric = data.draw(st.sampled_from(["euclidean", "chebyshev"]))
    max_d = data.draw(st.none() | st.floats(0.0, 5.0))
    for out in (
        fill_idw(g, window=window, power=power, metric=metric),
        fill_nearest(g, max_distance_m=max_d),
    ):
        assert out.heights.dtype == np.float32
        np.testing.assert_array_equal(out.heights[known], heights[known])
        assert out.known[known].all()
        filled = out.known & ~known
        assert (out.heights[filled] >= lo).all()
        assert (out.heights[filled] <= hi).all()
        assert np.isnan(out.heights[~out.known]).all()
    # Nearest copies a known value.
    near = fill_nearest(g)
    assert near.known.all()
    assert np.isin(near.heights, heights[known]).all()


# --- errors -----------------------------------------------------------------------------------


def test_errors_on_bad_voxels() -> None:
    keys, occ = stats_scene()
    with pytest.raises(ValueError, match="no voxels"):
        project_occupancy(np.zeros((0, 3), np.uint16), np.zeros(0, bool), RES)
    with pytest.raises(ValueError, match="no voxels"):
        column_stats(np.zeros((0, 3), np.uint16), np.zeros(0, bool), RES)
    with pytest.raises(ValueError, match="occupied must have shape"):
        project_occupancy(keys, occ[:-1], RES)
    with pytest.raises(ValueError, match=r"keys must have shape \(M, 3\)"):
        column_stats(keys[:, :2], occ, RES)
    with pytest.raises(ValueError, match="bool"):
        project_occupancy(keys, occ.astype(np.float32), RES)
    with pytest.raises(ValueError, match="integer"):
        project_occupancy(keys.astype(np.float64), occ, RES)
    with pytest.raises(ValueError, match=r"0\.\.65535"):
        project_occupancy(keys.astype(np.int64) - 40000, occ, RES)
    with pytest.raises(ValueError, match="resolution"):
        project_occupancy(keys, occ, 0.0)
    with pytest.raises(ValueError, match="z_min <= z_max"):
        column_stats(keys, occ, RES, z_min=1.0, z_max=0.0)
    with pytest.raises(ValueError, match="bounds"):
        project_occupancy(keys, occ, RES, bounds=(1.0, 0.0, 0.0, 1.0))
    with pytest.raises(ValueError, match="bounds"):
        project_occupancy(keys, occ, RES, bounds=(0.0, 0.0, 1.0))  # type: ignore[arg-type]


def test_errors_on_bad_stats_and_fill_options() -> None:
    keys, occ = stats_scene()
    s = column_stats(keys, occ, RES)
    with pytest.raises(ValueError, match="stat must be one of"):
        s.to_height_grid("median")
    with pytest.raises(ValueError, match=r"ground must have shape \(1, 3\)"):
        s.to_height_grid("max", ground=np.zeros((3, 1), np.float32))
    with pytest.raises(ValueError, match="one shape"):
        ColumnStats(s.max_z, s.min_z, s.mean_z[:, :2], s.count, s.known, RES, s.origin)
    with pytest.raises(ValueError, match="window_m"):
        estimate_ground(s, window_m=0.0)
    only_free = column_stats(keys, ~occ, RES, z_min=5.0)
    with pytest.raises(ValueError, match="no column has an occupied voxel"):
        estimate_ground(only_free)
    g = hgrid([[1.0, NAN]])
    with pytest.raises(ValueError, match="max_distance_m"):
        fill_nearest(g, max_distance_m=-1.0)
    with pytest.raises(ValueError, match="window"):
        fill_idw(g, window=0)
    with pytest.raises(ValueError, match="power"):
        fill_idw(g, power=-1.0)
    with pytest.raises(ValueError, match="metric"):
        fill_idw(g, metric="manhattan")


# --- pruned leaves: vertical runs -------------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(
    leaves=hnp.arrays(
        np.int64, st.tuples(st.integers(1, 12), st.just(4)), elements=st.integers(0, 3)
    ),
    data=st.data(),
)
def test_runs_give_what_the_expanded_voxels_give(leaves: NDArray[np.int64], data: Any) -> None:
    """Leaves of sides 1, 2, 4, 8 (tree depths 16..13), as runs and as every voxel: the same
    occupancy grid and column statistics, for any z band."""
    from scan2terrain.grids.projection import leaf_columns

    depth = (16 - leaves[:, 3]).astype(np.uint8)
    side = 1 << (16 - depth.astype(np.int64))
    low = (leaves[:, :3] * 8 + OFF).astype(np.uint16)  # leaves may overlap: fine for both
    occ = data.draw(hnp.arrays(np.bool_, len(leaves)))
    z_lo = data.draw(st.sampled_from([-math.inf, 0.05, 0.4, 1.0]))
    z_hi = data.draw(st.sampled_from([math.inf, 1.2, 3.0]))
    keys, states, runs = leaf_columns(low, depth, occ)
    assert len(keys) == int((side * side).sum())
    cubes = [
        low[i] + np.indices((s, s, s), dtype=np.uint16).reshape(3, -1).T
        for i, s in enumerate(side.tolist())
    ]
    full = np.concatenate(cubes)
    full_occ = np.repeat(occ, side**3)
    a = project_occupancy(keys, states, RES, z_min=z_lo, z_max=z_hi, runs=runs)
    b = project_occupancy(full, full_occ, RES, z_min=z_lo, z_max=z_hi)
    np.testing.assert_array_equal(a.data, b.data)
    assert a.origin == b.origin
    sa = column_stats(keys, states, RES, z_min=z_lo, z_max=z_hi, runs=runs)
    sb = column_stats(full, full_occ, RES, z_min=z_lo, z_max=z_hi)
    for name in ("count", "known", "max_z", "min_z", "mean_z"):
        np.testing.assert_array_equal(getattr(sa, name), getattr(sb, name), err_msg=name)


def test_leaf_columns_refuse_past_the_budget() -> None:
    from scan2terrain.grids.projection import leaf_columns

    keys = np.full((1, 3), OFF, dtype=np.uint16)
    with pytest.raises(ValueError, match="65536 columns"):
        leaf_columns(keys, np.array([8], dtype=np.uint8), np.array([False]), max_rows=1000)
