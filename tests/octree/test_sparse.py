"""The sparse store of ``insert_endpoints``: blocks with few voxels kept in a voxel-level hash.

Whatever way a block takes (dense at once, sparse, promoted to dense when it fills, taken over by
``insert_scan`` or ``set_voxels``), every answer must equal the dense store's (a tree whose every
block is dense: DENSE_MIN = 0, the octree before the sparse store) and OctoMap's, voxel for voxel
and bit for bit.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from types import ModuleType

import numba
import numpy as np
import pytest
from numpy.typing import NDArray

from scan2terrain.octree import tree as tree_module
from scan2terrain.octree.bt import bt_bytes
from scan2terrain.octree.tree import DENSE_MIN, SensorModel, VoxelOctree
from tests.octree._octomap_ref import (
    assert_identical,
    compare,
    import_octomap,
    octomap_endpoints,
    ours_voxels,
    pack,
)
from tests.octree.room import room_scans

Maker = Callable[..., VoxelOctree]


@pytest.fixture(scope="module")
def octomap() -> ModuleType:
    return import_octomap()


@pytest.fixture
def all_dense(monkeypatch: pytest.MonkeyPatch) -> Maker:
    """Makes trees whose every block is dense (DENSE_MIN 0): the store without the sparse one."""

    def make(resolution: float, model: SensorModel | None = None) -> VoxelOctree:
        with monkeypatch.context() as m:
            m.setattr(tree_module, "DENSE_MIN", 0)
            return VoxelOctree(resolution, model)

    return make


@pytest.fixture
def threads() -> Iterator[None]:
    before = numba.get_num_threads()
    yield
    numba.set_num_threads(before)


def assert_same(ours: VoxelOctree, ref: VoxelOctree, label: str) -> None:
    """The same known voxels with bit-identical log-odds, and the same answers to queries."""
    ok, ov = ours_voxels(ours)
    rk, rv = ours_voxels(ref)
    np.testing.assert_array_equal(ok, rk, err_msg=label)
    np.testing.assert_array_equal(ov.view(np.uint32), rv.view(np.uint32), err_msg=label)
    assert len(ours) == len(ref) == len(ok), label
    rng = np.random.default_rng(len(ok))
    lo, hi = ref.bounds() or (np.zeros(3), np.ones(3))
    queries = rng.uniform(lo - 0.5, hi + 0.5, (2000, 3))
    if len(ok):  # known voxels too, not only (mostly unknown) random places
        keys, _ = ref.voxels()
        queries = np.vstack([queries, ref.key_to_coord(keys[rng.integers(0, len(keys), 2000)])])
    np.testing.assert_array_equal(
        ours.logodds_at(queries).view(np.uint32), ref.logodds_at(queries).view(np.uint32)
    )


def box(rng: np.random.Generator, n: int, lo: float, hi: float) -> NDArray[np.float64]:
    return rng.uniform(lo, hi, (n, 3))


def test_sparse_and_dense_stores_agree(all_dense: Maker) -> None:
    """Calls of every density, into one tree: sparse blocks, dense blocks, blocks of a call that
    the sparse store already holds, and blocks promoted when they reach DENSE_MIN voxels."""
    rng = np.random.default_rng(1)
    calls = [
        box(rng, 20_000, -20.0, 20.0),  # ~1 point per block: sparse
        box(rng, 30_000, -1.0, 1.0),  # ~100 voxels per block: dense at once
        box(rng, 100_000, -5.0, 5.0),  # ~50 per block: sparse, promoted by the next call
        box(rng, 100_000, -5.0, 5.0),
        box(rng, 500, -20.0, 20.0),  # a small call (serial kernels)
    ]
    calls.append(np.vstack([calls[0], calls[1], calls[2][::7]]))  # all of them again
    ours, ref = VoxelOctree(0.1), all_dense(0.1)
    assert ref.n_sparse == 0
    sparse_seen = 0
    for i, points in enumerate(calls):
        blocks_before = ours.n_blocks
        assert ours.insert_endpoints(points) == ref.insert_endpoints(points)
        assert_same(ours, ref, f"call {i}")
        sparse_seen = max(sparse_seen, ours.n_sparse)
        if i == 3:  # the second 100k call filled blocks the first left sparse
            assert ours.n_blocks > blocks_before
    assert ref.n_sparse == 0
    assert sparse_seen > 100_000
    assert 0 < ours.n_blocks < ref.n_blocks / 2


def test_endpoints_equal_octomap_through_promotions(octomap: ModuleType) -> None:
    """OctoMap's updateNode once per distinct voxel and call: the same log-odds, also where a
    block moved from the sparse to the dense store between calls and where hits clamp."""
    rng = np.random.default_rng(2)
    base = box(rng, 6000, -1.5, 1.5)
    calls = [base[:2000], base, base[1000:], box(rng, 3000, -8.0, 8.0), base[:2000] + 0.03]
    calls += [base[:2000]] * 3  # clamping at clamp_max in the sparse store
    ref = octomap_endpoints(octomap, 0.1, calls)
    ours = VoxelOctree(0.1)
    stores = []
    for points in calls:
        distinct = len(np.unique(ours.coord_to_key(points), axis=0))
        assert ours.insert_endpoints(points).hits == distinct
        stores.append((ours.n_blocks, ours.n_sparse))
    assert_identical(compare(ours, ref), "end points through promotions")
    assert stores[0][1] > 0  # sparse at first
    assert stores[-1][0] > stores[0][0]  # then some blocks dense
    _, lo = ours.voxels()
    assert lo.max() == np.float32(ours.thresholds["clamp_max"])


def test_endpoints_then_scans_then_endpoints_equal_octomap(octomap: ModuleType) -> None:
    """insert_scan on a tree whose voxels are partly in the sparse store: the blocks its rays
    reach take those voxels over first, then end points land in dense blocks again."""
    rng = np.random.default_rng(3)
    first = box(rng, 4000, 0.2, 7.8) * np.array([1.0, 0.75, 0.375])  # inside the room
    scans = room_scans()[:4]
    ref = octomap_endpoints(octomap, 0.1, [first])
    ours = VoxelOctree(0.1)
    ours.insert_endpoints(first)
    held = ours.n_sparse
    assert held > 3000
    for points, origin in scans:
        ref.insertPointCloud(points, origin)
        ours.insert_scan(points, origin)
    assert ours.n_sparse < held  # voxels taken over by blocks the rays reached
    assert_identical(compare(ours, ref), "end points, then 4 room scans")
    again = np.vstack([first[::2], scans[0][0]])
    for kx, ky, kz in sorted({tuple(k) for k in ours.coord_to_key(again).tolist()}):
        key = octomap.OcTreeKey()
        key[0], key[1], key[2] = kx, ky, kz
        ref.updateNode(key, True)
    ours.insert_endpoints(again)
    assert_identical(compare(ours, ref), "then end points again")


def test_set_voxels_takes_over_sparse_voxels(all_dense: Maker) -> None:
    rng = np.random.default_rng(4)
    points = box(rng, 50_000, -6.0, 6.0)
    ours, ref = VoxelOctree(0.1), all_dense(0.1)
    for tree in (ours, ref):
        tree.insert_endpoints(points)
    near = rng.integers(32700, 32800, (500, 3))
    keys = np.vstack([ours.coord_to_key(points[:3000] + 0.05), near])
    values = rng.uniform(-1.5, 2.5, len(keys)).astype(np.float32)
    for tree in (ours, ref):
        tree.set_voxels(keys, values)
        tree.insert_endpoints(points[::3])
    assert_same(ours, ref, "set_voxels on sparse voxels, then end points")


def test_queries_after_sparse_insertion(all_dense: Maker) -> None:
    rng = np.random.default_rng(5)
    points = np.vstack([box(rng, 40_000, -10.0, 10.0), box(rng, 20_000, 2.0, 3.0)])
    ours, ref = VoxelOctree(0.1), all_dense(0.1)
    for tree in (ours, ref):
        tree.insert_endpoints(points)
        tree.insert_endpoints(points[::4])
    assert ours.n_sparse > 30_000
    assert ours.n_blocks > 0
    assert_same(ours, ref, "queries")
    ours_bounds, ref_bounds = ours.bounds(), ref.bounds()
    assert ours_bounds is not None
    assert ref_bounds is not None
    for a, b in zip(ours_bounds, ref_bounds, strict=True):
        np.testing.assert_array_equal(a, b)
    for depth in (0, 3, 10, 13, 14, 15, 16):
        (ka, la), (kb, lb) = ours.at_depth(depth), ref.at_depth(depth)
        oa, ob = np.argsort(pack(ka)), np.argsort(pack(kb))
        np.testing.assert_array_equal(ka[oa], kb[ob])
        np.testing.assert_array_equal(la[oa], lb[ob])
    (ka, occ_a), (kb, occ_b) = ours.occupied_and_free(), ref.occupied_and_free()
    assert bt_bytes(resolution=0.1, keys=ka, occupied=occ_a) == bt_bytes(
        resolution=0.1, keys=kb, occupied=occ_b
    )


def hit_values(model: SensorModel, calls: int) -> NDArray[np.float32]:
    """Log-odds after 0..calls hits from unknown, float32 and clamped as OctoMap computes."""
    hit = np.float32(math.log(model.hit / (1 - model.hit)))
    cmin = np.float32(math.log(model.clamp_min / (1 - model.clamp_min)))
    cmax = np.float32(math.log(model.clamp_max / (1 - model.clamp_max)))
    out = np.full(calls + 1, np.nan, dtype=np.float32)
    v = np.float32(0.0)
    for i in range(1, calls + 1):
        v = np.float32(min(max(np.float32(v + hit), cmin), cmax))
        out[i] = v
    return out


def test_one_point_per_block_over_many_blocks() -> None:
    """~One point per block over 400k blocks (partitions of more blocks than the grouping hash
    holds at once), three calls: each voxel's log-odds follows the number of calls hitting it.
    And the memory: a few tens of bytes a voxel, where dense blocks would take ~2 KB each."""
    rng = np.random.default_rng(6)
    points = box(rng, 400_000, -150.0, 150.0) * np.array([1.0, 1.0, 0.05])
    calls = [points, points[::2], points]
    tree = VoxelOctree(0.1)
    for c in calls:
        tree.insert_endpoints(c)
    hits: dict[int, int] = {}
    for c in calls:
        for k in np.unique(pack(tree.coord_to_key(c))).tolist():
            hits[k] = hits.get(k, 0) + 1
    expect_keys = np.array(sorted(hits), dtype=np.int64)
    expect = hit_values(tree.model, 3)[[hits[k] for k in expect_keys.tolist()]]
    keys, lo = ours_voxels(tree)
    np.testing.assert_array_equal(keys, expect_keys)
    np.testing.assert_array_equal(lo, expect)
    assert tree.n_sparse == len(keys) > 390_000
    assert tree.n_blocks == 0
    assert tree.memory_bytes() < 48 * len(keys)


@pytest.mark.parametrize(
    ("hit", "sparse"),
    [(0.7, True), (0.99, True), (0.501, False)],
    ids=["default", "clamped-at-once", "over-255-hits"],
)
def test_sensor_models_equal_octomap(octomap: ModuleType, hit: float, sparse: bool) -> None:
    """The sparse store counts hits up to where the value stops changing (clamp_max); a model
    that needs more than 255 hits to get there keeps every block dense."""
    model = SensorModel(hit=hit)
    rng = np.random.default_rng(7)
    base = box(rng, 3000, -4.0, 4.0)
    calls = [base, base[:1500], base, base[::3]]
    ref = octomap.OcTree(0.1)
    ref.setProbHit(hit)
    ref = octomap_endpoints(octomap, 0.1, calls, ref)
    ours = VoxelOctree(0.1, model)
    for points in calls:
        ours.insert_endpoints(points)
    assert (ours.n_sparse > 0) == sparse
    assert_identical(compare(ours, ref), f"end points, hit {hit}")


def test_sparse_insertion_is_deterministic(threads: None) -> None:
    """1 and 2 numba threads: the same voxels, in the same order, bit for bit."""
    if numba.config.NUMBA_NUM_THREADS < 2:  # type: ignore[attr-defined]
        pytest.fail("needs numba with >= 2 threads (set NUMBA_NUM_THREADS=2) to run in parallel")
    rng = np.random.default_rng(8)
    calls = [box(rng, 300_000, -15.0, 15.0), box(rng, 200_000, -3.0, 3.0)]
    results = []
    for n in (1, 2, 1, 2):
        numba.set_num_threads(n)
        tree = VoxelOctree(0.1)
        for points in calls:
            tree.insert_endpoints(points)
        results.append(tree.voxels())
    for keys, lo in results[1:]:
        np.testing.assert_array_equal(keys, results[0][0])
        np.testing.assert_array_equal(lo.view(np.uint32), results[0][1].view(np.uint32))


def test_sparse_memory_is_far_below_dense_blocks(all_dense: Maker) -> None:
    """200k points, ~6 per block: the sparse store takes a small fraction of what the dense
    blocks would, and only a few tens of bytes a voxel."""
    points = box(np.random.default_rng(9), 200_000, -20.0, 20.0) * np.array([1.0, 1.0, 0.25])
    ours, ref = VoxelOctree(0.1), all_dense(0.1)
    for tree in (ours, ref):
        tree.insert_endpoints(points)
    assert ours.n_blocks == 0
    assert ours.memory_bytes() < 0.1 * ref.memory_bytes()
    assert ours.memory_bytes() < 48 * len(ours)
    assert DENSE_MIN >= 32  # a dense block (~2.3 KB) is worth it from about a hundred voxels
