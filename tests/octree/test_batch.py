"""Many scans per kernel call (VoxelOctree.insert_scans, octree/_batch.py): the same voxels as
one insert_scan per scan, bit for bit, on the bundled laser recordings, with 1 and 2 threads;
and OctoMap's, scan for scan."""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from types import ModuleType
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from scan2terrain._numba import numba
from scan2terrain.config import load_config
from scan2terrain.errors import InputError
from scan2terrain.octree import _waves
from scan2terrain.octree.tree import PARALLEL_MIN_RAYS, InsertStats, VoxelOctree
from scan2terrain.readers.bag import open_bag
from scan2terrain.readers.scans import plan_bag, posed_scans
from scan2terrain.types import ScanCounts
from tests.fixtures import FIXTURES
from tests.octree._octomap_ref import (
    assert_identical,
    compare,
    import_octomap,
    octomap_tree,
)
from tests.octree.room import room_scans

SICK: dict[str, Any] = {"scans.topics": ["/sick_lms_1xx/scan"], "scans.fixed_frame": "cloud"}
#: (recording, config overrides): the bundled laser logs, posed as bag2world poses them.
RECORDINGS = {
    "carmen_mit_csail": ("logs/raw_carmen_mit_csail/mit-csail.clf.bz2", {}),
    "sick_lms1xx_tf": ("bags/bag1_sick_lms1xx_radar_tf", SICK),
    "sick_lms1xx_db3": ("bags/bag2_derived_sick_lms1xx_db3", SICK),
    "tb3_sim_odom": ("bags/bag1_fuse_tb3_sim_scan_odom", {}),
    "leg_tracker_fixed": (
        "bags/bag1_leg_tracker_room_scan",
        {"scans.pose": [0.0, 0.0, 0.3, 0.0, 0.0, 0.0]},
    ),
}

Scans = tuple[NDArray[np.float32], NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]


def recorded(name: str) -> Scans:
    """A recording's posed scans as bag2world reads them (no pose correction): points
    (float32, as the octree takes them), offsets, origins, max ranges."""
    rel, over = RECORDINGS[name]
    cfg = load_config(None, {"scans.correct": "off", **over})
    with open_bag([FIXTURES / rel]) as bag:
        plan = plan_bag(bag, cfg.scans, max_range=30.0)
        scans = list(posed_scans(bag, cfg.scans, plan, ScanCounts(), max_range=30.0))
    assert len(scans) > 50, name
    sizes = [len(s.points) for s in scans]
    offsets = np.zeros(len(scans) + 1, dtype=np.int64)
    np.cumsum(sizes, out=offsets[1:])
    points = np.concatenate([s.points for s in scans]).astype(np.float32)
    return (
        points,
        offsets,
        np.array([s.origin for s in scans]),
        np.array([s.max_range for s in scans]),
    )


@pytest.fixture(scope="module", params=sorted(RECORDINGS))
def recording(request: pytest.FixtureRequest) -> Scans:
    return recorded(request.param)


@pytest.fixture
def threads() -> Iterator[None]:
    before = numba.get_num_threads()
    yield
    numba.set_num_threads(before)


def one_at_a_time(resolution: float, scans: Scans) -> tuple[VoxelOctree, InsertStats]:
    points, offsets, origins, ranges = scans
    tree = VoxelOctree(resolution)
    total = np.zeros(6, dtype=np.int64)
    for s in range(len(origins)):
        st = tree.insert_scan(
            points[offsets[s] : offsets[s + 1]], origins[s], max_range=float(ranges[s])
        )
        total += (st.points, st.dropped_nonfinite, st.out_of_range, st.beams_cut, st.hits,
                  st.misses)  # fmt: skip
    return tree, InsertStats(*(int(v) for v in total))


def batched(resolution: float, scans: Scans, cuts: list[int]) -> tuple[VoxelOctree, InsertStats]:
    """insert_scans over the runs of scans between ``cuts`` (scan indices)."""
    points, offsets, origins, ranges = scans
    tree = VoxelOctree(resolution)
    total = np.zeros(6, dtype=np.int64)
    bounds = [0, *cuts, len(origins)]
    for a, b in itertools.pairwise(bounds):
        st = tree.insert_scans(
            points[offsets[a] : offsets[b]], offsets[a : b + 1] - offsets[a], origins[a:b],
            ranges[a:b],
        )  # fmt: skip
        total += (st.points, st.dropped_nonfinite, st.out_of_range, st.beams_cut, st.hits,
                  st.misses)  # fmt: skip
    return tree, InsertStats(*(int(v) for v in total))


def canonical(tree: VoxelOctree) -> tuple[NDArray[np.int64], NDArray[np.uint32]]:
    """Every known voxel's packed key, sorted, and its log-odds' bits."""
    keys, lo = tree.voxels()
    k = keys.astype(np.int64)
    packed = (k[:, 0] << 32) | (k[:, 1] << 16) | k[:, 2]
    order = np.argsort(packed)
    return packed[order], lo[order].view(np.uint32)


def assert_same_voxels(a: VoxelOctree, b: VoxelOctree) -> None:
    ka, va = canonical(a)
    kb, vb = canonical(b)
    assert len(ka) > 1000
    np.testing.assert_array_equal(ka, kb)
    np.testing.assert_array_equal(va, vb)  # bit for bit, NaN included


@pytest.mark.parametrize("n_threads", [1, 2])
def test_batched_equals_one_scan_at_a_time(recording: Scans, n_threads: int, threads: None) -> None:
    if numba.config.NUMBA_NUM_THREADS < 2:  # type: ignore[attr-defined]
        pytest.fail("needs numba with >= 2 threads (NUMBA_NUM_THREADS=2)")
    numba.set_num_threads(n_threads)
    n = len(recording[2])
    rng = np.random.default_rng(n)
    cuts = sorted({int(c) for c in rng.integers(1, n, size=5)})
    reference, ref_stats = one_at_a_time(0.05, recording)
    for how in ([], cuts, list(range(1, n))):  # one call; a few; one scan per call
        tree, stats = batched(0.05, recording, how)
        assert_same_voxels(reference, tree)
        assert stats == ref_stats
        # (insert_scan may hold a few more blocks: its first pass over blocks is conservative)
        assert tree.n_blocks <= reference.n_blocks


def test_batched_equals_octomap_scan_for_scan() -> None:
    """The room's ten lidar scans (3,200 rays each: the batch kernel's path) in one call give
    OctoMap's tree, voxel for voxel (a voxel hit by one scan and cleared by the next, and the
    robot waiting three scans at the start, so clamping is reached)."""
    octomap: ModuleType = import_octomap()
    scans = room_scans()
    assert max(len(p) for p, _ in scans) < PARALLEL_MIN_RAYS
    points = np.concatenate([p for p, _ in scans])
    offsets = np.concatenate([[0], np.cumsum([len(p) for p, _ in scans])])
    origins = np.array([o for _, o in scans])
    for max_range in (-1.0, 4.0):
        reference: Any = octomap_tree(octomap, 0.05, scans, max_range=max_range)
        tree = VoxelOctree(0.05)
        tree.insert_scans(points, offsets, origins, max_range)
        assert_identical(compare(tree, reference), f"room, batched, max_range {max_range}")


def test_a_large_scan_in_a_batch_takes_its_own_path_and_agrees() -> None:
    """Scans of PARALLEL_MIN_RAYS points or more in a batch go through insert_scan (threads,
    the box of bits) between the runs of small ones; the result is the same."""
    rng = np.random.default_rng(3)
    scans = room_scans()
    big = np.concatenate([scans[3][0], scans[4][0]])  # 6,400 rays from scan 4's origin
    assert len(big) >= PARALLEL_MIN_RAYS
    parts = [scans[0], scans[1], (big, scans[4][1]), scans[5], (rng.permutation(scans[6][0]),
             scans[6][1])]  # fmt: skip
    points = np.concatenate([p for p, _ in parts]).astype(np.float32)
    offsets = np.concatenate([[0], np.cumsum([len(p) for p, _ in parts])]).astype(np.int64)
    origins = np.array([o for _, o in parts])
    scans_ = (points, offsets, origins, np.full(len(parts), 5.0))
    reference, ref_stats = one_at_a_time(0.05, scans_)
    tree, stats = batched(0.05, scans_, [])
    assert_same_voxels(reference, tree)
    assert stats == ref_stats


def test_batched_after_end_points_adopts_the_sparse_store_like_insert_scan() -> None:
    """End points first (kept in the sparse store), then scans: new dense blocks must take over
    those voxels, as insert_scan's blocks do."""
    scans = room_scans()
    points = np.concatenate([p for p, _ in scans[2:]]).astype(np.float32)
    offsets = np.concatenate([[0], np.cumsum([len(p) for p, _ in scans[2:]])]).astype(np.int64)
    origins = np.array([o for _, o in scans[2:]])
    trees = [VoxelOctree(0.05), VoxelOctree(0.05)]
    for t in trees:
        t.insert_endpoints(scans[0][0][::7])
        assert t.n_sparse > 0
    for s in range(len(origins)):
        trees[0].insert_scan(points[offsets[s] : offsets[s + 1]], origins[s])
    trees[1].insert_scans(points, offsets, origins)
    assert_same_voxels(trees[0], trees[1])


def test_non_finite_points_are_dropped_per_scan_and_counted() -> None:
    scans = room_scans()[:4]
    parts = [p.copy() for p, _ in scans]
    parts[1][::50] = np.nan
    parts[2][7] = (np.inf, 0.0, 0.0)
    points = np.concatenate(parts).astype(np.float32)
    offsets = np.concatenate([[0], np.cumsum([len(p) for p in parts])]).astype(np.int64)
    data = (points, offsets, np.array([o for _, o in scans]), np.full(4, -1.0))
    reference, ref_stats = one_at_a_time(0.05, data)
    tree, stats = batched(0.05, data, [])
    assert stats == ref_stats
    assert stats.dropped_nonfinite == len(parts[1][::50]) + 1
    assert_same_voxels(reference, tree)


def test_growing_the_store_mid_batch_keeps_every_voxel() -> None:
    """One call that needs the store grown many times (blocks, the touched list, the hash
    table) resumes where it stopped: the CARMEN log, 1,988 scans, 43,760 blocks at 0.05 m from
    a store of 1,024."""
    scans = recorded("carmen_mit_csail")
    reference, _ = one_at_a_time(0.05, scans)
    tree, _ = batched(0.05, scans, [])
    assert tree.n_blocks > 40 * 1024
    assert_same_voxels(reference, tree)


def test_a_batch_over_the_memory_budget_is_refused() -> None:
    points, offsets, origins, ranges = recorded("carmen_mit_csail")
    tree = VoxelOctree(0.05, max_bytes=8 << 20)
    with pytest.raises(InputError, match="max_memory"):
        tree.insert_scans(points, offsets, origins, ranges)


@pytest.mark.parametrize(
    ("origin", "match"),
    [
        ((1e6, 0.0, 0.0), "scan 2: sensor origin .* key range"),
        ((0.0, np.nan, 0.0), "scan 2: .*finite"),
    ],
)
def test_an_origin_it_cannot_hold_is_refused_naming_the_scan(
    origin: tuple[float, float, float], match: str
) -> None:
    scans = room_scans()[:4]
    origins = np.array([o for _, o in scans])
    origins[2] = origin
    points = np.concatenate([p for p, _ in scans])
    offsets = np.concatenate([[0], np.cumsum([len(p) for p, _ in scans])])
    tree = VoxelOctree(0.05)
    with pytest.raises(InputError, match=match):
        tree.insert_scans(points, offsets, origins)
    assert len(tree) == 0  # refused before any scan went in


@pytest.mark.parametrize(
    ("offsets", "origins"),
    [([0, 5, 3, 10], (3, 3)), ([1, 10], (1, 3)), ([0, 9], (1, 3)), ([0, 5, 10], (3, 3))],
)
def test_offsets_and_origins_must_fit_the_points(
    offsets: list[int], origins: tuple[int, int]
) -> None:
    with pytest.raises(ValueError, match=r"offsets|origins"):
        VoxelOctree(0.1).insert_scans(np.ones((10, 3)), np.array(offsets), np.zeros(origins))


def test_empty_batch_and_empty_scans_change_nothing() -> None:
    tree = VoxelOctree(0.1)
    st = tree.insert_scans(np.zeros((0, 3)), np.array([0]), np.zeros((0, 3)))
    assert st == InsertStats(0, 0, 0, 0, 0, 0)
    st = tree.insert_scans(np.zeros((0, 3)), np.array([0, 0, 0]), np.zeros((2, 3)))
    assert st.points == 0 and len(tree) == 0


def test_a_scan_too_large_for_its_wave_scratch_goes_the_serial_way(threads: None) -> None:
    """Waves (two threads) cast each scan into a scratch of _waves.ROWS blocks; a scan of long
    beams in every direction needs more, and is cast the serial way in its place: the same
    voxels as one thread's serial path and as insert_scan."""
    rng = np.random.default_rng(11)
    parts, origins = [], []
    for i in range(5):
        d = rng.normal(size=(1500 if i in (1, 3) else 300, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        o = np.array([0.3 * i, 0.1, 0.05])
        parts.append(o + d * (25.0 if i in (1, 3) else 3.0))
        origins.append(o)
    points = np.concatenate(parts).astype(np.float32)
    offsets = np.concatenate([[0], np.cumsum([len(p) for p in parts])]).astype(np.int64)
    data = (points, offsets, np.array(origins), np.full(5, -1.0))
    reference, ref_stats = one_at_a_time(0.05, data)
    assert reference.n_blocks > 2 * _waves.ROWS  # scans 1 and 3 overflow a scratch
    serial = VoxelOctree._insert_serial
    calls: list[int] = []

    def counted(self: VoxelOctree, *args: Any) -> None:
        calls.append(len(args[2]))
        serial(self, *args)

    for n_threads in (2, 1):
        numba.set_num_threads(n_threads)
        calls.clear()
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(VoxelOctree, "_insert_serial", counted)
            tree, stats = batched(0.05, data, [])
        assert_same_voxels(reference, tree)
        assert stats == ref_stats
        assert calls == ([1, 1] if n_threads == 2 else [5])  # the two overflowed; all five
