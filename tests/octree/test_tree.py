"""The voxel octree (VoxelOctree) against OctoMap itself, voxel by voxel, and its own semantics.

OctoMap (octomap-python's ``OcTree.insertPointCloud``) is the reference: every known voxel must
be known to both trees with bit-identical float32 log-odds. The issue's acceptance bar is >= 99.99%
of voxels in the same state and with the same log-odds; the tests assert that bar *and* exact
equality, and print the agreement (``pytest -s`` shows it).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from types import ModuleType
from typing import Any

import numba
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from scan2terrain.errors import InputError
from scan2terrain.octree import _kernels as K
from scan2terrain.octree import _raybox, _raycast
from scan2terrain.octree import tree as tree_module
from scan2terrain.octree.tree import InsertStats, SensorModel, VoxelOctree
from tests.octree._octomap_ref import (
    assert_identical,
    compare,
    import_octomap,
    load_scan,
    octomap_endpoints,
    octomap_leaves,
    octomap_leaves_iterated,
    octomap_tree,
    our_tree,
    ours_voxels,
    pack,
)
from tests.octree.room import Scan, room_scans

OFF = 32768


@pytest.fixture(scope="module")
def octomap() -> ModuleType:
    return import_octomap()


@pytest.fixture(scope="module")
def fr079() -> Scan:
    points, origin = load_scan()
    assert points.shape == (88206, 3)
    return points, origin


@pytest.fixture(scope="module")
def fr079_octomap_01(octomap: ModuleType, fr079: Scan) -> Any:
    """OctoMap's tree of FR-079 at 0.1 m (shared: OctoMap takes seconds per insertion)."""
    return octomap_tree(octomap, 0.1, [fr079])


def yaw_pose(points: NDArray[np.float64], yaw: float, shift: tuple[float, float, float]) -> Scan:
    """The scan seen from another pose: points rotated by ``yaw`` about z and shifted, and the
    sensor origin (at the scan's origin) moved with them."""
    c, s = math.cos(yaw), math.sin(yaw)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    t = np.asarray(shift, dtype=np.float64)
    return points @ rot.T + t, t.copy()


@pytest.fixture
def threads() -> Iterator[None]:
    """Restore numba's thread count after a test that changes it."""
    before = numba.get_num_threads()
    yield
    numba.set_num_threads(before)


# -- 1. agreement with OctoMap ----------------------------------------------------------------


def test_reference_reader_equals_octomaps_leaf_iterator(fr079_octomap_01: Any) -> None:
    """The fast reader of OctoMap's trees (its .ot serialisation) gives exactly the leaves
    OctoMap's own leaf iterator gives, in the same order."""
    fast = octomap_leaves(fr079_octomap_01)
    slow = octomap_leaves_iterated(fr079_octomap_01)
    assert len(fast[0]) == fr079_octomap_01.getNumLeafNodes() > 300_000
    for a, b in zip(fast, slow, strict=True):
        np.testing.assert_array_equal(a, b)
    assert len(np.unique(fast[1])) > 3  # pruned leaves at several depths


def test_fr079_single_scan_equals_octomap_at_01(fr079: Scan, fr079_octomap_01: Any) -> None:
    ours = our_tree(0.1, [fr079])
    assert_identical(compare(ours, fr079_octomap_01), "FR-079 at 0.1 m")


def test_fr079_single_scan_equals_octomap_at_005(octomap: ModuleType, fr079: Scan) -> None:
    ref = octomap_tree(octomap, 0.05, [fr079])
    ours = our_tree(0.05, [fr079])
    assert_identical(compare(ours, ref), "FR-079 at 0.05 m")


def test_fr079_from_three_poses_equals_octomap_at_01(octomap: ModuleType, fr079: Scan) -> None:
    points, _ = fr079
    scans = [
        yaw_pose(points, 0.0, (0.0, 0.0, 0.0)),
        yaw_pose(points, 0.4, (1.3, -0.7, 0.2)),
        yaw_pose(points, -1.1, (-2.1, 1.9, -0.1)),
    ]
    ref = octomap_tree(octomap, 0.1, scans)
    ours = our_tree(0.1, scans)
    agreement = compare(ours, ref)
    assert_identical(agreement, "FR-079 from 3 poses at 0.1 m")
    # the poses overlap: some voxels were updated by more than one scan
    _, lo = ours.voxels()
    th = ours.thresholds
    single = np.isin(lo, np.array([th["hit"], th["miss"]], np.float32))
    assert (~single).sum() > 1000


def test_room_ten_scans_with_max_range_equal_octomap(octomap: ModuleType) -> None:
    scans = room_scans()
    ref = octomap_tree(octomap, 0.1, scans, max_range=6.0)
    ours = VoxelOctree(0.1)
    stats = [ours.insert_scan(p, o, max_range=6.0) for p, o in scans]
    assert_identical(compare(ours, ref), "room, 10 lidar scans, max_range 6 m, at 0.1 m")
    # the room's diagonal is ~10 m: every scan has beams cut at 6 m
    assert all(s.beams_cut > 0 for s in stats), stats
    assert sum(s.beams_cut for s in stats) > 500, stats
    assert all(s.points == 3200 and s.dropped_nonfinite == s.out_of_range == 0 for s in stats)
    _, lo = ours.voxels()
    th = ours.thresholds
    assert (lo == np.float32(th["clamp_max"])).sum() > 50
    assert (lo == np.float32(th["clamp_min"])).sum() > 10000
    assert lo.max() == np.float32(th["clamp_max"])
    assert lo.min() == np.float32(th["clamp_min"])


def spy(monkeypatch: pytest.MonkeyPatch, name: str) -> list[tuple[Any, ...]]:
    """Record the arguments of every call to ray-casting kernel ``name`` made by tree.py (for
    the kernels that also have a serial build, the calls of the parallel one)."""
    calls: list[tuple[Any, ...]] = []
    parallel = name in K.Kernels._fields
    kernel = getattr(K.PARALLEL if parallel else _raycast, name)

    def wrapper(*args: Any) -> Any:
        calls.append(args)
        return kernel(*args)

    if parallel:
        monkeypatch.setattr(K, "PARALLEL", K.PARALLEL._replace(**{name: wrapper}))
    else:
        monkeypatch.setattr(_raycast, name, wrapper)
    return calls


def test_long_beams_beyond_the_dense_box_equal_octomap(
    octomap: ModuleType, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Beams of hundreds of metres at 2 cm: the per-scan dense block index cannot span them
    (tree.MAX_DENSE), so rays leave it and take the serial fallback; end points beyond the key
    range (+-655 m) are skipped and counted, as OctoMap skips them."""
    rng = np.random.default_rng(3)
    d = rng.normal(size=(40, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    origin = np.array([0.31, -0.17, 0.05])
    dist = np.r_[rng.uniform(200.0, 320.0, 36), np.full(4, 800.0)]
    points = origin + d * dist[:, None]
    points[36:] = [[800.0, 0.0, 0.0], [0.0, -800.0, 1.0], [1.0, 2.0, 700.0], [-900.0, 5.0, 3.0]]
    ref = octomap_tree(octomap, 0.02, [(points, origin)])
    ours = VoxelOctree(0.02)
    serial = spy(monkeypatch, "cast_serial")
    stats = ours.insert_scan(points, origin)
    assert len(serial[0][2]) > 10  # rays redone by the serial fallback
    assert stats.out_of_range == 4
    assert stats.hits == 36
    assert_identical(compare(ours, ref), "40 beams of 200-320 m at 0.02 m")


def test_insert_endpoints_hits_each_voxel_once_per_call(octomap: ModuleType) -> None:
    rng = np.random.default_rng(11)
    res = 0.1
    base = rng.uniform(-1.0, 1.0, (400, 3))
    grid = rng.integers(-10, 10, (100, 3)) * res  # on voxel faces
    calls = [
        np.vstack([base[:300], base[:50]]),  # duplicates within a call
        np.vstack([base[200:], grid]),  # overlaps the first call
        np.vstack([grid, grid, base[:10]]),
        base[:300] + 0.01,  # mostly the same voxels again: several hits, then clamped
        base[:300] - 0.01,
        base[:300],
    ]
    ref = octomap_endpoints(octomap, res, calls)
    ours = VoxelOctree(res)
    for points in calls:
        before = len(ours)
        distinct = len(np.unique(ours.coord_to_key(points), axis=0))
        stats = ours.insert_endpoints(points)
        assert stats == InsertStats(len(points), 0, 0, 0, distinct, 0)
        assert len(ours) >= before
    assert_identical(compare(ours, ref), "insert_endpoints, 6 calls")
    _, lo = ours.voxels()
    assert lo.max() == np.float32(ours.thresholds["clamp_max"])
    assert (lo > 0).all()


def test_insert_endpoints_counts_out_of_range_and_nonfinite() -> None:
    ours = VoxelOctree(0.05)
    points = np.array([[0.0, 0.0, 0.0], [5000.0, 0.0, 0.0], [np.nan, 0, 0], [0.01, 0.01, 0.01]])
    stats = ours.insert_endpoints(points)
    assert stats == InsertStats(4, 1, 1, 0, 1, 0)
    keys, lo = ours.voxels()
    assert keys.tolist() == [[OFF, OFF, OFF]]
    assert lo.tolist() == [np.float32(ours.thresholds["hit"])]


def test_parallel_insertion_is_deterministic(
    fr079: Scan, threads: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    """FR-079 at 0.05 m with 1 and with 2 numba threads, cast into the scan's own box of bits
    and into the dense store's bits: the same voxels, bit for bit."""
    if numba.config.NUMBA_NUM_THREADS < 2:  # type: ignore[attr-defined]
        pytest.fail("needs numba with >= 2 threads (set NUMBA_NUM_THREADS=2) to run in parallel")
    boxed: list[tuple[Any, ...]] = []
    cast_box = _raybox.cast_box

    def recorded(*a: Any) -> Any:
        boxed.append(a)
        return cast_box(*a)

    monkeypatch.setattr(_raybox, "cast_box", recorded)
    parallel = spy(monkeypatch, "cast_parallel")
    results = []
    for n in (1, 2, 1, 2):
        numba.set_num_threads(n)
        results.append(ours_voxels(our_tree(0.05, [fr079])))
    assert [call[6].shape[0] for call in boxed] == [2, 3, 2, 3]  # hits + a plane a thread
    assert not tree_module._SCRATCH[0].any()  # apply_box cleared every bit it applied
    assert parallel == []
    monkeypatch.setattr(tree_module, "MAX_BOX_BLOCKS", 0)  # no box: the dense store's bits
    for n in (1, 2):
        numba.set_num_threads(n)
        results.append(ours_voxels(our_tree(0.05, [fr079])))
    assert [call[4] for call in parallel] == [1, 2]
    for keys, lo in results[1:]:
        np.testing.assert_array_equal(keys, results[0][0])
        np.testing.assert_array_equal(lo, results[0][1])


def test_a_ray_leaving_the_box_casts_the_scan_the_dense_stores_way(
    octomap: ModuleType, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A ray that would step out of the scan's box (rounding past its end by more than the
    box's block of margin: not seen, but not proven impossible) sends the whole scan to the
    dense store's bits; told so by cast_box, the tree is as OctoMap's."""
    rng = np.random.default_rng(21)
    origin = np.array([0.12, -0.31, 0.4])
    points = origin + rng.normal(0.0, 3.0, (6000, 3))
    cast_box = _raybox.cast_box
    monkeypatch.setattr(_raybox, "cast_box", lambda *a: cast_box(*a) + 1)
    parallel = spy(monkeypatch, "cast_parallel")
    ours = VoxelOctree(0.1)
    ours.insert_scan(points, origin)
    assert len(parallel) == 1
    assert not tree_module._SCRATCH[0].any()  # the box's bits left zeroed for the next scan
    ref = octomap_tree(octomap, 0.1, [(points, origin)])
    assert_identical(compare(ours, ref), "6000 rays, box refused")


# -- 2. semantics on hand-made scans ----------------------------------------------------------

ORIGIN = np.array([0.05, 0.05, 0.05])  # the centre of voxel (OFF, OFF, OFF) at 0.1 m


def row(tree: VoxelOctree, x0: int, x1: int) -> NDArray[np.float32]:
    """Log-odds of voxels (x, OFF, OFF) for x0 <= x < x1."""
    keys = np.array([[x, OFF, OFF] for x in range(x0, x1)])
    return tree.logodds_at_keys(keys)


def test_single_ray_frees_the_voxels_before_its_end_and_occupies_the_end() -> None:
    tree = VoxelOctree(0.1)
    th = tree.thresholds
    stats = tree.insert_scan(np.array([[1.05, 0.05, 0.05]]), ORIGIN)
    assert stats == InsertStats(1, 0, 0, 0, 1, 10)
    assert len(tree) == 11
    np.testing.assert_array_equal(row(tree, OFF, OFF + 10), np.full(10, th["miss"], np.float32))
    assert row(tree, OFF + 10, OFF + 11)[0] == np.float32(th["hit"])
    assert np.isnan(row(tree, OFF - 3, OFF)).all()
    assert np.isnan(row(tree, OFF + 11, OFF + 14)).all()
    keys, occupied = tree.occupied_and_free()
    assert keys[occupied].tolist() == [[OFF + 10, OFF, OFF]]
    assert np.float32(th["hit"]) == np.float32(math.log(0.7 / 0.3))
    assert np.float32(th["miss"]) == np.float32(math.log(0.4 / 0.6))


def test_voxel_free_on_one_ray_and_hit_by_another_is_occupied_and_updated_once() -> None:
    tree = VoxelOctree(0.1)
    th = tree.thresholds
    # ray 1 passes through voxel OFF + 5 (x in [0.5, 0.6)); ray 2 ends there
    stats = tree.insert_scan(np.array([[1.05, 0.05, 0.05], [0.55, 0.05, 0.05]]), ORIGIN)
    assert stats.hits == 2
    assert stats.misses == 9
    expected = np.full(11, th["miss"], np.float32)
    expected[5] = expected[10] = th["hit"]
    np.testing.assert_array_equal(row(tree, OFF, OFF + 11), expected)
    # the same, with the hit listed first and the voxel on several clearing rays
    tree2 = VoxelOctree(0.1)
    pts = np.array([[0.55, 0.05, 0.05], [1.05, 0.05, 0.05], [1.05, 0.051, 0.05], [0.9, 0.05, 0.05]])
    tree2.insert_scan(pts, ORIGIN)
    assert row(tree2, OFF + 5, OFF + 6)[0] == np.float32(th["hit"])
    assert row(tree2, OFF + 4, OFF + 5)[0] == np.float32(th["miss"])


def test_repeated_insertion_accumulates_and_clamps(octomap: ModuleType) -> None:
    tree = VoxelOctree(0.1)
    th = tree.thresholds
    hit, miss = np.float32(th["hit"]), np.float32(th["miss"])
    cmin, cmax = np.float32(th["clamp_min"]), np.float32(th["clamp_max"])
    points = np.array([[1.05, 0.05, 0.05]])
    ref = octomap.OcTree(0.1)
    occ, free = np.float32(0.0), np.float32(0.0)
    for _ in range(12):
        tree.insert_scan(points, ORIGIN)
        ref.insertPointCloud(points, ORIGIN)
        occ = min(np.float32(occ + hit), cmax)
        free = max(np.float32(free + miss), cmin)
        values = row(tree, OFF, OFF + 11)
        assert values[10] == occ
        np.testing.assert_array_equal(values[:10], np.full(10, free, np.float32))
        assert_identical(compare(tree, ref), "one ray, repeated")
    assert occ == cmax
    assert free == cmin
    assert cmax == np.float32(math.log(0.971 / 0.029))
    assert cmin == np.float32(math.log(0.1192 / 0.8808))


def test_max_range_cuts_a_beam_which_only_clears(octomap: ModuleType) -> None:
    tree = VoxelOctree(0.1)
    points = np.array([[3.05, 0.05, 0.05]])
    stats = tree.insert_scan(points, ORIGIN, max_range=1.0)
    assert stats == InsertStats(1, 0, 0, 1, 0, 10)
    keys, lo = tree.voxels()
    assert sorted(keys[:, 0].tolist()) == list(range(OFF, OFF + 10))  # to x = 1.0 m, 1 m out
    assert (keys[:, 1:] == OFF).all()
    assert (lo == np.float32(tree.thresholds["miss"])).all()
    assert not tree.is_occupied(lo).any()
    assert np.isnan(tree.logodds_at(np.array([[1.5, 0.05, 0.05], [3.05, 0.05, 0.05]]))).all()
    ref = octomap_tree(octomap, 0.1, [(points, ORIGIN)], max_range=1.0)
    assert_identical(compare(tree, ref), "one beam cut at max_range")
    # a beam within max_range is not cut
    within = VoxelOctree(0.1).insert_scan(points, ORIGIN, max_range=3.5)
    assert (within.beams_cut, within.hits, within.misses) == (0, 1, 30)


def test_end_point_in_the_origin_voxel_is_a_hit_without_clearing() -> None:
    tree = VoxelOctree(0.1)
    stats = tree.insert_scan(np.array([[0.01, 0.09, 0.02]]), ORIGIN)
    assert (stats.hits, stats.misses) == (1, 0)
    assert tree.logodds_at(ORIGIN)[0] == np.float32(tree.thresholds["hit"])


def test_origin_in_the_last_voxel_of_the_key_range_is_accepted_like_octomap(
    octomap: ModuleType,
) -> None:
    """OctoMap takes any origin whose key is valid (coordToKeyChecked), the last voxel of the
    range (key 65535) included; rays from it towards the map are cast as anywhere else."""
    res = 0.05
    for x in (1638.36, 1638.38, 1638.399):  # all three have key 65535 at 0.05 m
        origin = np.array([x, 0.0, 0.0])
        assert VoxelOctree(res).coord_to_key(origin).tolist() == [65535, OFF, OFF]
        points = np.array([[x - 1.0, 0.3, 0.2]])
        ref = octomap_tree(octomap, res, [(points, origin)])
        ours = VoxelOctree(res)
        ours.insert_scan(points, origin)
        assert_identical(compare(ours, ref), f"origin x = {x} (key 65535)")


# -- 3. queries -------------------------------------------------------------------------------


def random_tree(seed: int, n: int = 3000) -> tuple[VoxelOctree, dict[tuple[int, int, int], float]]:
    """A tree from set_voxels: clustered and scattered keys (ends of the key range included)."""
    rng = np.random.default_rng(seed)
    keys = np.vstack(
        [
            rng.integers(OFF - 40, OFF + 40, (n, 3)),
            rng.integers(0, 65536, (50, 3)),
            [[0, 0, 0], [65535, 65535, 65535], [0, 65535, 7]],
        ]
    )
    values = rng.uniform(-2.0, 3.5, len(keys)).astype(np.float32)
    ref: dict[tuple[int, int, int], float] = {}
    for k, v in zip(keys.tolist(), values.tolist(), strict=True):
        ref[tuple(k)] = v  # the last write wins
    tree = VoxelOctree(0.1)
    tree.set_voxels(keys, values)
    return tree, ref


def test_set_voxels_round_trip() -> None:
    tree, ref = random_tree(5)
    keys, lo = tree.voxels()
    assert keys.dtype == np.uint16
    assert lo.dtype == np.float32
    assert len(tree) == len(ref) == len(keys)
    got = {tuple(k): v for k, v in zip(keys.tolist(), lo.tolist(), strict=True)}
    assert got == ref
    # replacing values, and lookups by key
    some = np.array(list(ref)[:100])
    tree.set_voxels(some, np.full(100, -1.25, np.float32))
    assert (tree.logodds_at_keys(some) == np.float32(-1.25)).all()
    assert len(tree) == len(ref)


def test_scans_on_top_of_set_voxels_equal_octomap(octomap: ModuleType) -> None:
    """A map loaded with set_voxels (e.g. from a .bt file), then scans inserted: each voxel
    continues from its set value, as OctoMap continues from its nodes' values."""
    rng = np.random.default_rng(9)
    keys = np.unique(
        np.c_[rng.integers(0, 80, 3000), rng.integers(0, 60, 3000), rng.integers(0, 30, 3000)]
        + OFF,
        axis=0,
    )
    values = rng.uniform(-1.9, 3.4, len(keys)).astype(np.float32)  # inside the clamping range
    ref = octomap.OcTree(0.1)
    for (kx, ky, kz), v in zip(keys.tolist(), values.tolist(), strict=True):
        key = octomap.OcTreeKey()
        key[0], key[1], key[2] = kx, ky, kz
        ref.updateNode(key, float(v))  # a new node starts at 0: it takes the value v
    ours = VoxelOctree(0.1)
    ours.set_voxels(keys, values)
    assert_identical(compare(ours, ref), "set_voxels")
    for points, origin in room_scans()[2:6]:
        ref.insertPointCloud(points, origin)
        ours.insert_scan(points, origin)
    assert_identical(compare(ours, ref), "room scans on top of set_voxels")


def test_logodds_at_known_and_unknown_points() -> None:
    tree = VoxelOctree(0.1)
    tree.insert_scan(np.array([[1.05, 0.05, 0.05]]), ORIGIN)
    th = tree.thresholds
    got = tree.logodds_at(
        np.array(
            [
                [1.05, 0.05, 0.05],  # end voxel
                [1.0001, 0.0999, 0.0],  # the same voxel, near its corners
                [0.35, 0.01, 0.02],  # free
                [0.35, -0.01, 0.02],  # next to the ray: unknown
                [-0.05, 0.05, 0.05],  # behind the origin: unknown
                [1e6, 0.0, 0.0],  # outside the key range: unknown
            ]
        )
    )
    np.testing.assert_array_equal(got[:3], np.array([th["hit"], th["hit"], th["miss"]], np.float32))
    assert np.isnan(got[3:]).all()
    assert tree.logodds_at(np.array([1.05, 0.05, 0.05])).shape == (1,)
    assert tree.is_occupied(got).tolist() == [True, True, False, False, False, False]
    # isNodeOccupied uses >= the threshold (log-odds 0)
    at_threshold = np.array([0.0, -1e-7, np.nan], np.float32)
    assert tree.is_occupied(at_threshold).tolist() == [True, False, False]
    keys = tree.coord_to_key(np.array([[1.05, 0.05, 0.05], [-0.05, 0, 0], [1e6, 0, 0]]))
    assert keys.tolist() == [[OFF + 10, OFF, OFF], [OFF - 1, OFF, OFF], [-1, OFF, OFF]]
    np.testing.assert_allclose(tree.key_to_coord(keys[:1]), [[1.05, 0.05, 0.05]])


def groupby_max(ref: dict[tuple[int, int, int], float], depth: int) -> dict[tuple[int, ...], float]:
    shift = 16 - depth
    out: dict[tuple[int, ...], float] = {}
    for k, v in ref.items():
        node = tuple((c >> shift) << shift for c in k)
        out[node] = max(out.get(node, -math.inf), v)
    return out


@pytest.mark.parametrize("depth", [0, 1, 5, 10, 12, 13, 14, 15, 16])
def test_at_depth_is_the_maximum_over_each_nodes_voxels(depth: int) -> None:
    tree, ref = random_tree(depth)
    keys, lo = tree.at_depth(depth)
    got = {tuple(k): v for k, v in zip(keys.tolist(), lo.tolist(), strict=True)}
    assert len(got) == len(keys)
    assert got == groupby_max(ref, depth)


def test_at_depth_16_equals_voxels(fr079: Scan) -> None:
    tree = our_tree(0.1, [fr079])
    keys, lo = tree.at_depth(16)
    vkeys, vlo = tree.voxels()
    a, b = np.argsort(pack(keys)), np.argsort(pack(vkeys))
    np.testing.assert_array_equal(keys[a], vkeys[b])
    np.testing.assert_array_equal(lo[a], vlo[b])
    with pytest.raises(ValueError):
        tree.at_depth(17)
    with pytest.raises(ValueError):
        tree.at_depth(-1)


def test_at_depth_matches_octomaps_inner_nodes(
    octomap: ModuleType, fr079: Scan, fr079_octomap_01: Any
) -> None:
    tree = our_tree(0.1, [fr079])
    rng = np.random.default_rng(0)
    checked = 0
    # the root (OctoMap's search takes depth 0 to mean the full depth, 16)
    keys, lo = tree.at_depth(0)
    assert keys.tolist() == [[0, 0, 0]]
    assert lo.tolist() == [np.float32(fr079_octomap_01.getRoot().getValue())]
    for depth in (1, 4, 8, 11, 12, 13, 14, 15, 16):
        keys, lo = tree.at_depth(depth)
        pick = rng.choice(len(keys), min(40, len(keys)), replace=False)
        pick = np.r_[pick, np.argmax(lo), np.argmin(lo)]
        for i in pick:
            key = octomap.OcTreeKey()
            key[0], key[1], key[2] = (int(c) for c in keys[i])
            node = fr079_octomap_01.search(key, depth)
            assert np.float32(node.getValue()) == lo[i], (depth, keys[i])
            checked += 1
    assert checked > 250


def test_bounds() -> None:
    tree = VoxelOctree(0.1)
    assert tree.bounds() is None
    tree.insert_scan(np.array([[1.05, 0.05, 0.05], [0.05, -0.25, 0.35]]), ORIGIN)
    lo, hi = tree.bounds()  # type: ignore[misc]
    np.testing.assert_allclose(lo, [0.0, -0.3, 0.0], atol=1e-12)
    np.testing.assert_allclose(hi, [1.1, 0.1, 0.4], atol=1e-12)
    keys, _ = tree.voxels()
    centres = tree.key_to_coord(keys)
    assert (centres > lo).all()
    assert (centres < hi).all()


# -- 4. bad input -----------------------------------------------------------------------------


def test_empty_scan_is_allowed_and_changes_nothing() -> None:
    tree = VoxelOctree(0.1)
    assert tree.insert_scan(np.zeros((0, 3)), ORIGIN) == InsertStats(0, 0, 0, 0, 0, 0)
    assert len(tree) == 0
    tree.insert_scan(np.array([[1.05, 0.05, 0.05]]), ORIGIN)
    before = ours_voxels(tree)
    assert tree.insert_scan(np.zeros((0, 3)), (1.0, 2.0, 3.0)) == InsertStats(0, 0, 0, 0, 0, 0)
    assert tree.insert_endpoints(np.zeros((0, 3))) == InsertStats(0, 0, 0, 0, 0, 0)
    after = ours_voxels(tree)
    np.testing.assert_array_equal(before[0], after[0])
    np.testing.assert_array_equal(before[1], after[1])


def test_nonfinite_points_are_dropped_and_counted(fr079: Scan) -> None:
    points = fr079[0][::20].copy()
    rng = np.random.default_rng(1)
    bad = rng.choice(len(points), 60, replace=False)
    dirty = points.copy()
    for j, i in enumerate(bad):
        dirty[i, j % 3] = (np.nan, np.inf, -np.inf)[j % 3]
    clean = np.delete(dirty, bad, axis=0)
    a, b = VoxelOctree(0.1), VoxelOctree(0.1)
    sa = a.insert_scan(dirty, ORIGIN, max_range=8.0)
    sb = b.insert_scan(clean, ORIGIN, max_range=8.0)
    assert sa.dropped_nonfinite == 60
    assert sa.points == len(dirty)
    assert (sa.out_of_range, sa.beams_cut, sa.hits, sa.misses) == (
        sb.out_of_range,
        sb.beams_cut,
        sb.hits,
        sb.misses,
    )
    assert sb.dropped_nonfinite == 0
    for x, y in zip(ours_voxels(a), ours_voxels(b), strict=True):
        np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize(
    "origin",
    [(1e6, 0.0, 0.0), (0.0, -1e6, 0.0), (0.0, 0.0, 1638.45), (-1638.45, 0.0, 0.0)],
)
def test_origin_outside_the_key_range_raises(origin: tuple[float, float, float]) -> None:
    tree = VoxelOctree(0.05)  # the key range is +-1638.4 m
    with pytest.raises(InputError, match="key range"):
        tree.insert_scan(np.array([[1.0, 0.0, 0.0]]), origin)
    assert len(tree) == 0


@pytest.mark.parametrize(
    "origin", [(np.nan, 0.0, 0.0), (0.0, np.inf, 0.0), (0.0, 0.0), (0.0, 0.0, 0.0, 0.0)]
)
def test_origin_not_three_finite_numbers_raises(origin: tuple[float, ...]) -> None:
    with pytest.raises(InputError):
        VoxelOctree(0.1).insert_scan(np.array([[1.0, 0.0, 0.0]]), origin)  # type: ignore[arg-type]


@pytest.mark.parametrize("shape", [(5, 2), (5, 4), (3,), (5, 3, 1), (0,)])
def test_points_of_the_wrong_shape_raise(shape: tuple[int, ...]) -> None:
    tree = VoxelOctree(0.1)
    with pytest.raises(InputError, match=r"\(N, 3\)"):
        tree.insert_scan(np.zeros(shape), ORIGIN)
    with pytest.raises(InputError, match=r"\(N, 3\)"):
        tree.insert_endpoints(np.zeros(shape))


@pytest.mark.parametrize("resolution", [0.0, -0.1, math.nan, math.inf])
def test_resolution_must_be_positive(resolution: float) -> None:
    with pytest.raises(ValueError, match="resolution"):
        VoxelOctree(resolution)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"hit": 0.5},
        {"hit": 0.3},
        {"miss": 0.5},
        {"hit": 1.0},
        {"clamp_min": 0.9, "clamp_max": 0.2},
        {"occupancy": 0.0},
    ],
)
def test_sensor_model_rejects_bad_probabilities(kwargs: dict[str, float]) -> None:
    with pytest.raises(ValueError):
        SensorModel(**kwargs)


def test_custom_sensor_model_equals_octomap_with_the_same_model(octomap: ModuleType) -> None:
    model = SensorModel(hit=0.65, miss=0.45, clamp_min=0.12, clamp_max=0.97)
    scans = room_scans()[:4]
    ref = octomap.OcTree(0.1)
    ref.setProbHit(0.65)
    ref.setProbMiss(0.45)
    ref.setClampingThresMin(0.12)
    ref.setClampingThresMax(0.97)
    for points, origin in scans:
        ref.insertPointCloud(points, origin)
    ours = VoxelOctree(0.1, model)
    for points, origin in scans:
        ours.insert_scan(points, origin)
    assert ours.thresholds["hit"] == np.float32(ref.getProbHitLog())
    assert ours.thresholds["clamp_max"] == np.float32(ref.getClampingThresMaxLog())
    assert_identical(compare(ours, ref), "room, 4 scans, octomap_server's model")


# -- 5. property: small random scans ----------------------------------------------------------


@st.composite
def small_scans(draw: st.DrawFn) -> tuple[float, NDArray[np.float64], NDArray[np.float64], float]:
    """A resolution, an origin, up to 50 points and a max_range. Coordinates are either any
    float within a few metres or on a half- or quarter-voxel grid (faces, edges, corners and
    exact diagonals: the ties of the ray casting)."""
    res = draw(st.sampled_from([0.05, 0.1, 0.2]))

    def coordinate(centre: float) -> st.SearchStrategy[float]:
        return st.one_of(
            st.floats(-4.0, 4.0).map(lambda v: centre + v),
            st.integers(-80, 80).map(lambda k: centre + k * res / 4),
        )

    origin = np.array([draw(coordinate(0.0)) for _ in range(3)])
    n = draw(st.integers(0, 50))
    points = np.array([[draw(coordinate(float(c))) for c in origin] for _ in range(n)])
    max_range = draw(st.sampled_from([-1.0, -1.0, 0.0, 0.7, 2.5]))
    return res, origin, points.reshape(-1, 3), max_range


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(small_scans())
def test_small_random_scans_equal_octomap(
    scan: tuple[float, NDArray[np.float64], NDArray[np.float64], float],
) -> None:
    octomap = import_octomap()
    res, origin, points, max_range = scan
    ref = octomap_tree(octomap, res, [(points, origin)], max_range)
    ours = VoxelOctree(res)
    ours.insert_scan(points, origin, max_range=max_range)
    # empty when there are no points, or max_range is 0 (beams cut at the origin: no update)
    assert_identical(compare(ours, ref), f"random scan at {res} m", empty_ok=True)
