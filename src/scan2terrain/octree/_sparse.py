"""The sparse store (numba): blocks with few known voxels, kept voxel by voxel.

End points spread thinly (a few voxels per 8 x 8 x 8 block) would cost a 2 KB block per few
voxels. insert_endpoints keeps such blocks in a voxel-level open-addressing hash instead:

- the voxel table ``vt``: int64 entries (hits << 48) | (kx << 32) | (ky << 16) | kz, 0 = empty.
  Only end points ever reach it, so a voxel's log-odds is a function of how many calls hit it:
  ``lut[hits]``, hits saturating where the value stops changing (clamp_max);
- the block table ``st``: int64 entries (voxels << 40) | block id, 0 = empty: how many voxels of
  each such block the voxel table holds (known at once when the block turns dense).

Both have a power-of-two capacity split into NREG regions of equal size; a block's region is the
top bits of fib(block id), and its voxels' entries and its count live in that region of each
table (linear probing wraps within the region). ``sparse_counts[r]`` = (voxels, blocks) in
region r. A block with DENSE_MIN voxels or more moves to the dense store (adopt_sparse). A block
is in the dense store or in the sparse one.

insert_endpoints sorts its points into NPART partitions (the top PART_BITS of the region: few
enough write streams for one scattering pass), and the kernels take a partition per core:
no two threads write one region, the layout does not depend on the number of threads, and the
voxels of a partition are handled region by region, each region (512 KB of a 128 MB table) in
cache.

Here: the tables (probing, removal, rehashing, a voxel's hit), the hand-over of a block's voxels
to the dense store, and the queries by voxel key, which read both stores (``lookup``,
``set_values``). The points reach the store through _points.py and _group.py.
"""

from __future__ import annotations

import math

import numpy as np

from scan2terrain._numba import numba as nb
from scan2terrain.octree._table import (
    JIT,
    KEY_LIMIT,
    block_id,
    block_voxel_key,
    loaded,
    stored,
    table_find,
    table_insert,
    voxel_key,
)

NREG_BITS = 8
NREG = 1 << NREG_BITS
PART_BITS = 6
NPART = 1 << PART_BITS
HITS_SHIFT = 48
KEY_MASK = np.int64((1 << 48) - 1)
COUNT_SHIFT = 40
BLOCK_MASK = np.int64((1 << 39) - 1)
#: Largest share of a region of the sparse store's tables in use (linear probing stays short).
SPARSE_LOAD = 0.7


@nb.njit(**JIT)
def fib(x):
    """Fibonacci hashing (Knuth): x times 2**64 / golden ratio; its top bits are well spread,
    also for keys on a lattice, and it costs one multiplication (it runs for every point)."""
    return np.uint64(x) * np.uint64(0x9E3779B97F4A7C15)


@nb.njit(**JIT)
def _region(bk):
    """Region of block ``bk``: the top NREG_BITS of fib(bk)."""
    return np.int64(fib(bk) >> np.uint64(64 - NREG_BITS))


@nb.njit(**JIT)
def home(k, skip, mask):
    """Slot of ``k`` within a region of ``mask + 1`` slots: the bits of fib(k) below its top
    ``skip`` (block ids skip the bits that chose their region)."""
    return np.int64(fib(k) >> np.uint64(40 - skip)) & mask


@nb.njit(inline="always", **JIT)
def _probe(table, k, kmask, r):
    """Index of the entry of region ``r`` whose bits ``kmask`` are ``k``, or of the empty slot
    where it would go (voxel keys: ``kmask`` KEY_MASK, block ids: BLOCK_MASK)."""
    size = table.shape[0] >> NREG_BITS
    mask = size - 1
    base = r * size
    i = home(k, 0 if kmask == KEY_MASK else NREG_BITS, mask)
    while True:
        e = table[base + i]
        if e == 0 or (e & kmask) == k:
            return base + i
        i = (i + 1) & mask


@nb.njit(inline="always", **JIT)
def _remove(table, at, kmask):
    """Empty entry ``at``; entries after it in its probe run move back (no tombstones)."""
    size = table.shape[0] >> NREG_BITS
    mask = size - 1
    base = at - (at & mask)
    skip = 0 if kmask == KEY_MASK else NREG_BITS
    i = at & mask
    j = i
    while True:
        j = (j + 1) & mask
        e = table[base + j]
        if e == 0:
            break
        h = home(e & kmask, skip, mask)
        # e stays unless the hole i lies on its probe path from h to j (cyclically)
        if (i <= j and (h <= i or h > j)) or (i > j and h <= i and h > j):
            table[base + i] = e
            i = j
    table[base + i] = 0


@nb.njit(parallel=True, **JIT)
def sparse_rehash(table, kmask, out):
    """Copy a sparse-store table into ``out`` (zeros, a larger power of two); entries keep their
    region, so the regions are rehashed on every core."""
    size = table.shape[0] >> NREG_BITS
    for r in nb.prange(NREG):
        for i in range(r * size, (r + 1) * size):
            e = table[i]
            if e != 0:
                out[_probe(out, e & kmask, kmask, r)] = e


@nb.njit(**JIT)
def _adopt_block(cs, bx, by, bz, values, vt, st, sparse_counts, lut):
    """Move the sparse store's voxels of block (bx, by, bz) into dense block ``cs`` (new:
    every voxel unknown), if it has any."""
    bk = block_id(bx, by, bz)
    r = _region(bk)
    at = _probe(st, bk, BLOCK_MASK, r)
    if st[at] == 0:
        return
    left = st[at] >> COUNT_SHIFT
    _remove(st, at, BLOCK_MASK)
    sparse_counts[r, 0] -= left
    sparse_counts[r, 1] -= 1
    for local in range(512):
        if left == 0:
            break
        at = _probe(vt, block_voxel_key(bk, local), KEY_MASK, r)
        e = vt[at]
        if e != 0:
            values[local >> 6, cs, local & 63] = lut[e >> HITS_SHIFT]  # > 0: no -0.0 needed
            _remove(vt, at, KEY_MASK)
            left -= 1


@nb.njit(**JIT)
def adopt_sparse(slots, values, block_xyz, vt, st, sparse_counts, lut):
    """New dense blocks ``slots`` take over their voxels from the sparse store."""
    for j in range(slots.shape[0]):
        cs = slots[j]
        bx, by, bz = block_xyz[cs, 0], block_xyz[cs, 1], block_xyz[cs, 2]
        _adopt_block(cs, bx, by, bz, values, vt, st, sparse_counts, lut)


@nb.njit(**JIT)
def sparse_voxels(vt, lut, n):
    """The sparse store's ``n`` voxels: keys uint16 (n, 3) and log-odds float32 (n,), in
    table order."""
    keys = np.empty((n, 3), dtype=np.uint16)
    lo = np.empty(n, dtype=np.float32)
    j = 0
    for i in range(vt.shape[0]):
        e = vt[i]
        if e != 0:
            keys[j, 0] = (e >> 32) & 0xFFFF
            keys[j, 1] = (e >> 16) & 0xFFFF
            keys[j, 2] = e & 0xFFFF
            lo[j] = lut[e >> HITS_SHIFT]
            j += 1
    return keys, lo


@nb.njit(inline="always", **JIT)
def hit_voxel(vt, key, r, max_hits):
    """One hit for voxel ``key`` (region ``r``) in the voxel table; 1 if it is new there."""
    at = _probe(vt, key, KEY_MASK, r)
    e = vt[at]
    if e == 0:
        vt[at] = (np.int64(1) << HITS_SHIFT) | key
        return 1
    if (e >> HITS_SHIFT) < max_hits:
        vt[at] = e + (np.int64(1) << HITS_SHIFT)
    return 0


@nb.njit(inline="always", **JIT)
def add_sparse(st, bk, r, held, new, sparse_counts):
    """Count ``new`` voxels of block ``bk`` (which had ``held``) in the block table."""
    if new == 0:
        return
    at = _probe(st, bk, BLOCK_MASK, r)
    if held == 0:
        st[at] = bk
        sparse_counts[r, 1] += 1
    st[at] += new << COUNT_SHIFT
    sparse_counts[r, 0] += new


@nb.njit(**JIT)
def lookup(keys, values, table_keys, table_slots, vt, lut):
    """Log-odds of voxel keys (int64 (N, 3)), from the dense store or else the sparse store's
    voxel table ``vt``; NaN where unknown."""
    n = keys.shape[0]
    out = np.full(n, np.nan, dtype=np.float32)
    for i in range(n):
        kx, ky, kz = keys[i, 0], keys[i, 1], keys[i, 2]
        if kx < 0 or ky < 0 or kz < 0 or kx >= KEY_LIMIT or ky >= KEY_LIMIT or kz >= KEY_LIMIT:
            continue
        bk = block_id(kx >> 3, ky >> 3, kz >> 3)
        slot = table_find(table_keys, table_slots, bk)
        if slot >= 0:
            out[i] = loaded(values[kz & 7, slot, (kx & 7) | ((ky & 7) << 3)])
        else:
            e = vt[_probe(vt, voxel_key(kx, ky, kz), KEY_MASK, _region(bk))]
            if e != 0:
                out[i] = lut[e >> HITS_SHIFT]
    return out


@nb.njit(**JIT)
def set_values(
    keys, logodds, values, block_xyz, table_keys, table_slots, counts, vt, st, sparse_counts, lut
):
    """Write log-odds at voxel keys (int64 (N, 3)), creating blocks (a new block first takes over
    the sparse store's voxels of it); arrays must have room."""
    for i in range(keys.shape[0]):
        kx, ky, kz = keys[i, 0], keys[i, 1], keys[i, 2]
        bx, by, bz = kx >> 3, ky >> 3, kz >> 3
        k = block_id(bx, by, bz)
        slot = table_find(table_keys, table_slots, k)
        if slot < 0:
            slot = counts[0]
            counts[0] += 1
            block_xyz[slot, 0] = bx
            block_xyz[slot, 1] = by
            block_xyz[slot, 2] = bz
            table_insert(table_keys, table_slots, k, slot)
            _adopt_block(slot, bx, by, bz, values, vt, st, sparse_counts, lut)
        v = logodds[i]  # NaN: unknown, +0.0 in the store
        values[kz & 7, slot, (kx & 7) | ((ky & 7) << 3)] = 0.0 if math.isnan(v) else stored(v)
