"""Tiled column statistics (grids/tiles.py): against a per-point reference, and exact merging."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from scan2terrain.grids.projection import column_stats, project_occupancy
from scan2terrain.grids.tiles import SUM_SCALE, Lattice, TileSet
from scan2terrain.octree.keys import KEY_OFFSET
from scan2terrain.octree.tree import VoxelOctree

FIELDS = ("max_z", "min_z", "mean_z", "count", "known")


def reference(points: np.ndarray, lat: Lattice) -> dict[str, np.ndarray]:
    """Per-point Python over a dict of cells: the definition, with no tiles."""
    cells: dict[tuple[int, int], list[float]] = {}
    for x, y, z in points.tolist():
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            continue
        if not lat.z_min <= z <= lat.z_max:
            continue
        key = (math.floor(y * (1.0 / lat.resolution)), math.floor(x * (1.0 / lat.resolution)))
        cells.setdefault(key, []).append(z)
    rows = [k[0] for k in cells]
    cols = [k[1] for k in cells]
    r0, c0 = min(rows), min(cols)
    shape = (max(rows) - r0 + 1, max(cols) - c0 + 1)
    out: dict[str, np.ndarray] = {
        f: np.full(shape, np.nan, dtype=np.float32) for f in ("max_z", "min_z", "mean_z")
    }
    out["count"] = np.zeros(shape, dtype=np.int32)
    for (r, c), zs in cells.items():
        z32 = np.array(zs, dtype=np.float32)
        out["max_z"][r - r0, c - c0] = z32.max()
        out["min_z"][r - r0, c - c0] = z32.min()
        q = sum(math.floor(z * SUM_SCALE + 0.5) for z in zs)
        out["mean_z"][r - r0, c - c0] = np.float32(q / len(zs) / SUM_SCALE)
        out["count"][r - r0, c - c0] = len(zs)
    out["known"] = out["count"] > 0
    out["origin"] = np.array([c0 * lat.resolution, r0 * lat.resolution])
    return out


def stats_of(tiles: TileSet) -> dict[str, np.ndarray]:
    s = tiles.column_stats()
    out = {f: getattr(s, f) for f in FIELDS}
    out["origin"] = np.array([s.origin.x, s.origin.y])
    return out


def assert_same(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> None:
    assert a.keys() == b.keys()
    for k, mine in a.items():
        assert mine.dtype == b[k].dtype, k
        assert np.array_equal(mine, b[k], equal_nan=mine.dtype.kind == "f"), k


def cloud(seed: int, n: int = 3000) -> np.ndarray:
    rng = np.random.default_rng(seed)
    pts = rng.uniform([-7.3, -4.1, -1.0], [6.2, 9.9, 3.0], (n, 3))
    pts[::97] = [np.nan, 0.0, 0.0]
    pts[::89, 2] = np.inf
    return pts


@pytest.mark.parametrize("tile", [1, 4, 64, 4096])
def test_matches_the_per_point_definition(tile: int) -> None:
    lat = Lattice(0.25, tile, z_min=-0.5, z_max=2.5)
    pts = cloud(1)
    tiles = TileSet(lat)
    counted = tiles.add_points(pts)
    ref = reference(pts, lat)
    assert counted == ref["count"].sum() == tiles.points
    assert_same(stats_of(tiles), ref)


def test_mean_is_exact_to_the_sum_quantum() -> None:
    lat = Lattice(1.0)
    z = np.array([0.1, 0.2, 0.7000001, 1e3 + 1 / 3])
    tiles = TileSet(lat)
    tiles.add_points(np.column_stack([np.full(4, 0.5), np.full(4, 0.5), z]))
    got = float(tiles.column_stats().mean_z[0, 0])
    assert abs(got - float(np.float32(z.mean()))) <= 1 / SUM_SCALE


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**16),
    tile=st.sampled_from([1, 2, 8, 32]),
    cuts=st.lists(st.integers(0, 600), max_size=6),
    order_seed=st.integers(0, 2**16),
)
def test_any_split_merged_in_any_order_is_the_same_grid(
    seed: int, tile: int, cuts: list[int], order_seed: int
) -> None:
    lat = Lattice(0.5, tile, z_min=-0.8)
    pts = cloud(seed, 600)
    whole = TileSet(Lattice(0.5, 4096, z_min=-0.8))  # another tile size: same grid
    whole.add_points(pts)
    parts = np.split(pts, sorted(cuts))
    rng = np.random.default_rng(order_seed)
    merged = TileSet(lat)
    partials = []
    for part in parts:
        t = TileSet(lat)
        t.add_points(part)
        partials.append(t)
    for i in rng.permutation(len(partials)):
        merged.merge(pickle.loads(pickle.dumps(partials[i])))  # as results cross to Dask
    assert_same(stats_of(merged), stats_of(whole))


def test_occupancy_equals_the_octree_end_points_projection() -> None:
    rng = np.random.default_rng(3)
    # float32-representable points: the octree keys float32 points, the tiles float64 ones.
    pts = rng.uniform([-5, -5, -1], [5, 8, 2], (20000, 3)).astype(np.float32).astype(np.float64)
    tree = VoxelOctree(0.1)
    tree.insert_endpoints(pts)
    keys, occupied = tree.occupied_and_free()
    expected = project_occupancy(keys, occupied, 0.1)
    tiles = TileSet(Lattice(0.1, 16))
    tiles.add_points(pts)
    got = tiles.occupancy()
    assert got.origin == expected.origin
    assert np.array_equal(got.data, expected.data)


def test_merge_refuses_another_lattice() -> None:
    a, b = TileSet(Lattice(0.5)), TileSet(Lattice(0.25))
    b.add_points(np.zeros((1, 3)))
    with pytest.raises(ValueError, match="cannot merge"):
        a.merge(b)


def test_empty_and_bad_input() -> None:
    tiles = TileSet(Lattice(1.0, z_max=0.0))
    assert tiles.add_points(np.zeros((0, 3))) == 0
    assert tiles.add_points(np.array([[0.0, 0.0, 5.0], [np.nan, 0.0, 0.0]])) == 0
    with pytest.raises(ValueError, match="no point in the z band"):
        tiles.column_stats()
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        tiles.add_points(np.zeros((4, 2)))
    for bad in (
        {"resolution": 0.0},
        {"resolution": 1.0, "tile": 3},
        {"resolution": 1.0, "z_min": 2.0, "z_max": 1.0},
    ):
        with pytest.raises(ValueError):
            Lattice(**bad)  # type: ignore[arg-type]


def test_only_tiles_with_points_take_memory() -> None:
    tiles = TileSet(Lattice(1.0, 8))
    # Two points 1 km apart: two tiles of 64 cells, not the 1000 x 1000 cells between them.
    tiles.add_points(np.array([[0.5, 0.5, 0.0], [1000.5, 1000.5, 1.0]]))
    assert len(tiles.index) == 2
    assert tiles.nbytes == 2 * 64 * 24
    state = pickle.dumps(tiles)
    assert len(state) < 10_000  # only the tiles in use travel


@pytest.mark.parametrize("stat", ["max", "min", "mean"])
def test_one_statistic_is_the_column_stats_one(stat: str) -> None:
    tiles = TileSet(Lattice(0.25, 4, z_min=-0.5))
    tiles.add_points(cloud(5))
    one = tiles.heights(stat)
    full = tiles.column_stats().to_height_grid(stat)
    assert one.origin == full.origin
    assert np.array_equal(one.known, full.known)
    assert np.array_equal(one.heights, full.heights, equal_nan=True)
    with pytest.raises(ValueError, match="stat"):
        tiles.heights("median")


def test_partial_results_travel_by_the_cells_with_a_point() -> None:
    tiles = TileSet(Lattice(0.1, 256))
    pts = np.random.default_rng(8).uniform([0, 0, 0], [25.5, 25.5, 1], (300, 3))
    tiles.add_points(pts)
    assert tiles.nbytes == 256 * 256 * 24  # one whole tile while counting
    rec = tiles.records()
    cells = len({(int(x * 10), int(y * 10)) for x, y, _ in pts})
    assert len(rec.cell) == cells and rec.records.shape == (cells, 3)
    assert rec.nbytes <= cells * (24 + 4) + 64
    again = TileSet(Lattice(0.1, 256))
    again.merge(rec)
    assert_same(stats_of(again), stats_of(tiles))


# --- heights within the octree's occupied voxels (ray casting) --------------------------------


def test_heights_stay_within_the_octrees_occupied_voxels() -> None:
    """After ray casting the octree may hold a point's voxel free (a later ray cleared it): a
    column without an occupied voxel left is unknown, and a height beyond the column's
    occupied voxels is moved onto their nearest face; the rest are the points' own."""
    r = 0.5
    k = KEY_OFFSET
    pts = np.array(
        [
            [0.2, 0.2, 0.1], [0.2, 0.2, 1.7],  # column (0, 0): 1.7 was cleared
            [1.2, 0.2, 2.2],  # column (0, 2): its only voxel cleared
            [2.2, 0.2, 0.3], [2.2, 0.2, 0.4],  # column (0, 4): as the points say
            [0.2, 1.2, -0.8], [0.2, 1.2, 0.9],  # column (2, 0): -0.8 cleared
        ]
    )  # fmt: skip
    tiles = TileSet(Lattice(r, 4))
    tiles.add_points(pts)
    occupied_keys = np.array(
        [[k, k, k], [k + 4, k, k], [k, k + 2, k + 1]], dtype=np.uint16
    )  # z cells 0, 0, 1 (0.9 is in cell 1)
    free_keys = np.array([[k, k, k + 3], [k + 2, k, k + 4], [k - 3, k + 6, k]], dtype=np.uint16)
    keys = np.concatenate([occupied_keys, free_keys])
    occupied = np.array([True] * 3 + [False] * 3)
    octree = column_stats(keys, occupied, r)  # a wider frame: free voxels around
    for stat, want in (
        ("max", {(0, 0): 0.5, (0, 4): 0.4, (2, 0): 0.9}),
        ("min", {(0, 0): 0.1, (0, 4): 0.3, (2, 0): 0.5}),
        ("mean", {(0, 0): 0.5, (0, 4): 0.35, (2, 0): 0.5}),
    ):
        got = tiles.heights(stat, occupied=octree)
        alone = tiles.heights(stat)
        assert got.origin == alone.origin and got.heights.shape == alone.heights.shape
        known = {(int(a), int(b)) for a, b in zip(*np.nonzero(got.known), strict=True)}
        assert known == set(want), stat
        for (row, col), h in want.items():
            assert got.heights[row, col] == pytest.approx(h, abs=1e-4), (stat, row, col)
        assert np.isnan(got.heights[~got.known]).all()


@pytest.mark.parametrize("band", [(-math.inf, math.inf), (-0.26, 1.74)])
def test_end_points_occupy_every_voxel_they_hit_so_the_octree_changes_no_height(
    band: tuple[float, float],
) -> None:
    """The octree path of end points may take its heights from the tiles alone: every hit
    voxel is occupied, so bounding them by the octree's columns changes nothing, even at cell
    edges where float32 and float64 disagree."""
    rng = np.random.default_rng(21)
    k = rng.integers(-40, 40, (30_000, 3))
    pts = k * 0.1 + rng.uniform(-1e-7, 1e-7, k.shape)
    tree = VoxelOctree(0.1)
    tree.insert_endpoints(pts)
    keys, occupied = tree.occupied_and_free()
    octree = column_stats(keys, occupied, 0.1, z_min=band[0], z_max=band[1])
    tiles = TileSet(Lattice(0.1, 16, *band))
    tiles.add_points(pts)
    for stat in ("max", "min", "mean"):
        a, b = tiles.heights(stat, occupied=octree), tiles.heights(stat)
        assert a.origin == b.origin
        assert np.array_equal(a.known, b.known)
        assert np.array_equal(a.heights, b.heights, equal_nan=True)


def test_cell_spreads_are_max_minus_min_of_cells_with_two_points() -> None:
    lat = Lattice(0.25, 4, z_min=-0.5)
    pts = cloud(9)
    tiles = TileSet(lat)
    tiles.add_points(pts)
    ref = reference(pts, lat)
    two = ref["count"] >= 2
    want = np.sort((ref["max_z"] - ref["min_z"])[two])
    assert np.array_equal(np.sort(tiles.cell_spreads()), want)
    assert len(want) > 100 and (ref["count"] == 1).any()
