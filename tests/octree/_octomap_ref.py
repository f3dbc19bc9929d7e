"""OctoMap itself (octomap-python) as the reference for the voxel octree, voxel by voxel.

OctoMap prunes its tree: a leaf at depth d < 16 stands for the (2 ** (16 - d)) ** 3 voxels below
it, all holding its value. ``octomap_voxels`` expands every leaf to depth-16 voxels, so a
VoxelOctree (which stores voxels) and an OcTree compare voxel by voxel, log-odds included.
"""

from __future__ import annotations

import bz2
import importlib
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

import numba as nb
import numpy as np
import pytest
from numpy.typing import NDArray

from scan2terrain.octree.tree import VoxelOctree
from tests.fixtures import FR079

TREE_DEPTH = 16


def import_octomap() -> ModuleType:
    try:
        return importlib.import_module("octomap")
    except ImportError:  # pragma: no cover - depends on the environment
        pytest.fail("octomap-python is needed for these tests: pip install octomap-python")


def load_scan(path: Path = FR079) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """OctoMap's scan.dat text format: optional ``NODE x y z roll pitch yaw`` lines, then
    ``x y z`` per point. Returns (points float64 (N, 3), sensor origin (3,)); the origin is the
    first NODE's position, or (0, 0, 0) without one (FR-079 has none). Points are given in the
    world frame here: this reader is only for files with at most one pose at the origin."""
    rows: list[list[float]] = []
    origin = np.zeros(3)
    nodes = 0
    for line in bz2.decompress(path.read_bytes()).decode().splitlines():
        fields = line.split()
        if not fields:
            continue
        if fields[0] == "NODE":
            nodes += 1
            origin = np.array([float(v) for v in fields[1:4]])
            continue
        rows.append([float(v) for v in fields[:3]])
    if nodes > 1 or np.any(origin != 0):
        raise ValueError(f"{path}: this reader handles one scan at the origin only")
    return np.array(rows, dtype=np.float64), origin


def pack(keys: NDArray[Any]) -> NDArray[np.int64]:
    """Voxel keys (M, 3) as one int64 each, ordered like (x, y, z) lexicographically."""
    k = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
    return (k[:, 0] << 32) | (k[:, 1] << 16) | k[:, 2]


def unpack(packed: NDArray[np.int64]) -> NDArray[np.int64]:
    return np.stack([(packed >> 32) & 0xFFFF, (packed >> 16) & 0xFFFF, packed & 0xFFFF], axis=1)


def octomap_leaves_iterated(
    tree: Any,
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float32]]:
    """Every leaf of an OcTree through OctoMap's leaf iterator (a Python call per leaf: slow on
    millions of leaves): min-corner keys (L, 3), depths (L,), log-odds float32 (L,)."""
    rows: list[tuple[int, int, int, int]] = []
    values: list[float] = []
    add_row, add_value = rows.append, values.append
    for leaf in tree.begin_leafs():
        k = leaf.getKey()
        add_row((k[0], k[1], k[2], leaf.getDepth()))
        add_value(leaf.getValue())
    arr = np.array(rows, dtype=np.int64).reshape(-1, 4)
    depth = arr[:, 3]
    shift = (TREE_DEPTH - depth)[:, None]
    corner = (arr[:, :3] >> shift) << shift
    # getValue returns the node's float as a Python float: converting back is exact
    return corner, depth, np.array(values, dtype=np.float64).astype(np.float32)


@nb.njit(cache=True)
def _walk_ot(buf: NDArray[np.uint8], pos: int, n_nodes: int) -> Any:  # pragma: no cover - jit
    """Walk the node stream of an .ot file (OcTreeBaseImpl::writeNodesRecurs: per node, depth
    first, its float value, then a byte whose bit i says child i exists; child i is offset by
    half the node's side along x if i & 1, y if i & 2, z if i & 4). Returns, per node, the byte
    offset of its value, its depth, min-corner key and whether it is a leaf; and the end."""
    offset = np.empty(n_nodes, np.int64)
    depth = np.empty(n_nodes, np.int64)
    corner = np.zeros((n_nodes, 3), np.int64)
    leaf = np.empty(n_nodes, np.bool_)
    mask = np.zeros(TREE_DEPTH + 1, np.int64)
    nxt = np.zeros(TREE_DEPTH + 1, np.int64)
    at = np.zeros((TREE_DEPTH + 1, 3), np.int64)
    offset[0], depth[0], leaf[0] = pos, 0, buf[pos + 4] == 0
    mask[0] = buf[pos + 4]
    pos += 5
    n, d = 1, 0
    while d >= 0:
        i = nxt[d]
        while i < 8 and not (mask[d] >> i) & 1:
            i += 1
        if i == 8:
            d -= 1
            continue
        nxt[d] = i + 1
        half = 1 << (TREE_DEPTH - 1 - d)
        m = buf[pos + 4]
        offset[n], depth[n], leaf[n] = pos, d + 1, m == 0
        corner[n, 0] = at[d, 0] + (i & 1) * half
        corner[n, 1] = at[d, 1] + ((i >> 1) & 1) * half
        corner[n, 2] = at[d, 2] + ((i >> 2) & 1) * half
        pos += 5
        if m != 0:
            d += 1
            mask[d], nxt[d] = m, 0
            at[d] = corner[n]
        n += 1
    return offset[:n], depth[:n], corner[:n], leaf[:n], pos


def octomap_leaves(tree: Any) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float32]]:
    """Every leaf of an OcTree, read from OctoMap's own full-tree serialisation (``write``, the
    .ot format, which stores every node's float log-odds): min-corner keys (L, 3), depths (L,),
    log-odds float32 (L,). Same result as ``octomap_leaves_iterated``, without a Python call per
    leaf (tested against it)."""
    data = tree.write()
    head = data.index(b"\ndata\n") + len(b"\ndata\n")
    fields = dict(
        line.split(" ", 1) for line in data[:head].decode().splitlines() if " " in line[:9]
    )
    assert fields["id"] == "OcTree", fields
    size = int(fields["size"])
    if size == 0:
        assert len(data) == head
        return np.zeros((0, 3), np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32)
    buf = np.frombuffer(data, dtype=np.uint8)
    offset, depth, corner, leaf, end = _walk_ot(buf, head, size)
    assert len(offset) == size, (len(offset), size)
    assert end == len(data), (end, len(data))
    offset = offset[leaf]
    raw = buf[offset[:, None] + np.arange(4)].copy()
    values = raw.view("<f4").reshape(-1).astype(np.float32)
    return corner[leaf], depth[leaf], values


def octomap_voxels(tree: Any) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
    """Every known depth-16 voxel of an OcTree: packed keys (sorted) and log-odds float32."""
    corner, depth, value = octomap_leaves(tree)
    keys: list[NDArray[np.int64]] = []
    vals: list[NDArray[np.float32]] = []
    for d in np.unique(depth):
        sel = depth == d
        side = 1 << (TREE_DEPTH - int(d))
        offsets = np.indices((side, side, side)).reshape(3, -1).T.astype(np.int64)
        keys.append(pack((corner[sel][:, None, :] + offsets[None]).reshape(-1, 3)))
        vals.append(np.repeat(value[sel], side**3))
    if not keys:
        return np.zeros(0, np.int64), np.zeros(0, np.float32)
    packed, lo = np.concatenate(keys), np.concatenate(vals)
    order = np.argsort(packed)
    packed, lo = packed[order], lo[order]
    assert (np.diff(packed) > 0).all(), "OctoMap leaves overlap"
    return packed, lo


def ours_voxels(tree: VoxelOctree) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
    """Every known voxel of a VoxelOctree: packed keys (sorted) and log-odds."""
    keys, lo = tree.voxels()
    packed = pack(keys)
    order = np.argsort(packed)
    packed, lo = packed[order], lo[order]
    assert (np.diff(packed) > 0).all(), "VoxelOctree.voxels() repeats a voxel"
    return packed, lo


@dataclass(frozen=True)
class Agreement:
    """Voxel-by-voxel comparison over the union of the voxels either tree knows."""

    ours: int  #: voxels VoxelOctree knows
    reference: int  #: voxels OctoMap knows
    union: int
    common: int  #: known to both
    same_state: int  #: same unknown/free/occupied state (over the union)
    same_logodds: int  #: known to both with bit-identical float32 log-odds
    first_differences: str  #: a few differing voxels, for the failure message

    @property
    def state_fraction(self) -> float:
        return self.same_state / self.union if self.union else 1.0

    @property
    def logodds_fraction(self) -> float:
        return self.same_logodds / self.union if self.union else 1.0

    def __str__(self) -> str:
        return (
            f"union {self.union} voxels (ours {self.ours}, OctoMap {self.reference}, common "
            f"{self.common}): same state {self.same_state} ({100 * self.state_fraction:.4f}%), "
            f"same log-odds {self.same_logodds} ({100 * self.logodds_fraction:.4f}%)"
            + (f"; first differences: {self.first_differences}" if self.first_differences else "")
        )


def compare(ours: VoxelOctree, reference: Any, occupancy: float = 0.0) -> Agreement:
    """Compare a VoxelOctree with an OcTree voxel by voxel (state: 0 unknown, 1 free,
    2 occupied, occupied when log-odds >= ``occupancy``, as OctoMap's isNodeOccupied)."""
    ok, ov = ours_voxels(ours)
    rk, rv = octomap_voxels(reference)
    if np.array_equal(ok, rk):  # the usual case: no need to merge
        union, a, b = ok, ov, rv
    else:
        union = np.union1d(ok, rk)
        a = np.full(len(union), np.nan, dtype=np.float32)
        b = a.copy()
        a[np.searchsorted(union, ok)] = ov
        b[np.searchsorted(union, rk)] = rv

    def state(v: NDArray[np.float32]) -> NDArray[np.int8]:
        return np.where(np.isnan(v), 0, np.where(v >= occupancy, 2, 1)).astype(np.int8)

    same_state = state(a) == state(b)
    same_lo = a == b  # NaN != NaN: a voxel known to one tree only is a difference
    bad = np.flatnonzero(~same_lo)[:5]
    diffs = ", ".join(
        f"key {tuple(int(c) for c in unpack(union[i : i + 1])[0])}: ours {a[i]!r} OctoMap {b[i]!r}"
        for i in bad
    )
    return Agreement(
        ours=len(ok),
        reference=len(rk),
        union=len(union),
        common=int(np.count_nonzero(~np.isnan(a) & ~np.isnan(b))),
        same_state=int(same_state.sum()),
        same_logodds=int(same_lo.sum()),
        first_differences=diffs,
    )


def octomap_tree(
    octomap: ModuleType,
    resolution: float,
    scans: list[tuple[NDArray[np.float64], NDArray[np.float64]]],
    max_range: float = -1.0,
) -> Any:
    """An OcTree with ``scans`` ((points, origin) pairs) inserted by insertPointCloud."""
    tree = octomap.OcTree(resolution)
    for points, origin in scans:
        tree.insertPointCloud(
            np.ascontiguousarray(points, dtype=np.float64),
            np.ascontiguousarray(origin, dtype=np.float64),
            maxrange=max_range,
        )
    return tree


def our_tree(
    resolution: float,
    scans: list[tuple[NDArray[np.float64], NDArray[np.float64]]],
    max_range: float = -1.0,
) -> VoxelOctree:
    tree = VoxelOctree(resolution)
    for points, origin in scans:
        tree.insert_scan(points, origin, max_range=max_range)
    return tree


def octomap_endpoints(
    octomap: ModuleType, resolution: float, calls: list[Any], tree: Any = None
) -> Any:
    """OctoMap reference for insert_endpoints: per call, each distinct voxel (keys by
    OctoMap's own coordToKey) gets one updateNode(key, occupied=True); into ``tree`` if given
    (e.g. one with another sensor model), else a new OcTree."""
    tree = octomap.OcTree(resolution) if tree is None else tree
    for points in calls:
        keys = set()
        for p in np.asarray(points, dtype=np.float64):
            k = tree.coordToKey(p)
            keys.add((k[0], k[1], k[2]))
        for kx, ky, kz in sorted(keys):
            key = octomap.OcTreeKey()
            key[0], key[1], key[2] = kx, ky, kz
            tree.updateNode(key, True)
    return tree


def assert_identical(agreement: Agreement, label: str, *, empty_ok: bool = False) -> None:
    """The issue's bar (>= 99.99% same state and log-odds) and exact voxel-by-voxel equality."""
    print(f"\n{label}: {agreement}")
    assert empty_ok or agreement.union > 0, label
    assert agreement.state_fraction >= 0.9999, f"{label}: {agreement}"
    assert agreement.logodds_fraction >= 0.9999, f"{label}: {agreement}"
    # exact: the same set of known voxels, every log-odds bit-identical
    assert agreement.ours == agreement.reference == agreement.common == agreement.union, (
        f"{label}: {agreement}"
    )
    assert agreement.same_logodds == agreement.union, f"{label}: {agreement}"
