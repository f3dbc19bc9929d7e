"""What the octree's kernels (numba) share: the dense store's block hash table and voxel keys.

Storage (see tree.py): voxels live in dense blocks of 8 x 8 x 8 found through an open-addressing
hash of block coordinates (``block_id`` -> slot). Per block: ``values[w, slot, i]`` float32
log-odds of voxel w * 64 + i (layer w = z; +0.0 = unknown, a log-odds of 0 stored as -0.0: see
``known``, ``stored``, ``loaded``) and ``bits``, uint64 words, one bit per voxel: this scan's hits
(words 0-7) and, per thread, its misses (words 8 + 8t .. 15 + 8t), so the marks of a whole scan
stay in cache and threads never share a word. The insertion kernels allocate blocks (``_slot``)
while ``_room`` says they fit, else stop with a NEED_* status: tree.py grows the arrays and resumes
them.

Also here: OctoMap's coordinate -> key, the voxel keys (``voxel_key``, ``key_block``,
``key_local``), the numba options of every kernel and the threading layer. numba's cache sees
edits to a kernel's own file only: after changing a function or constant here, clear the
cached kernels of the modules that use it (their ``__pycache__/*.nbi`` and ``*.nbc`` files).
"""

from __future__ import annotations

import math

import numpy as np

from scan2terrain._numba import numba as nb

TREE_MAX_VAL = 32768
KEY_LIMIT = 65536
EMPTY = np.int64(-1)
# Status codes returned by the insertion kernels.
DONE, NEED_BLOCKS, NEED_TOUCHED, NEED_TABLE = 0, 1, 2, 3
# counts[] of the insertion kernels: blocks in use, blocks touched this scan, scan stamp.
N_BLOCKS, N_TOUCHED, STAMP = 0, 1, 2
#: counts[WANTED]: blocks a kernel that ran out of room still needs at most (0: unknown), so
#: the store grows once to fit instead of doubling again and again (alloc_box sets it).
WANTED = 3

JIT = {"nogil": True, "cache": True, "error_model": "numpy"}
# Helpers that take arrays and run once per point or voxel are inlined by numba (inline="always"):
# a call passing arrays counts references to them, which costs several times the work.

# Index of a word's lowest set bit: (bit * De Bruijn constant) >> 58 is unique per bit.
DEBRUIJN_MUL = np.uint64(0x03F79D71B4CB0A89)
DEBRUIJN = np.zeros(64, dtype=np.int64)
for _b in range(64):
    DEBRUIJN[((1 << _b) * 0x03F79D71B4CB0A89 % (1 << 64)) >> 58] = _b


@nb.njit(**JIT)
def block_id(bx: int, by: int, bz: int) -> np.int64:
    return (np.int64(bx) << 26) | (np.int64(by) << 13) | np.int64(bz)


@nb.njit(**JIT)
def _hash(k: np.int64, mask: np.int64) -> np.int64:
    h = np.uint64(k) * np.uint64(0x9E3779B97F4A7C15)
    return np.int64(h >> np.uint64(20)) & mask


@nb.njit(**JIT)
def table_find(table_keys, table_slots, k):
    """Slot of block id ``k`` or -1."""
    mask = np.int64(table_keys.shape[0] - 1)
    i = _hash(k, mask)
    while True:
        tk = table_keys[i]
        if tk == k:
            return table_slots[i]
        if tk == EMPTY:
            return -1
        i = (i + 1) & mask


@nb.njit(**JIT)
def table_insert(table_keys, table_slots, k, slot):
    mask = np.int64(table_keys.shape[0] - 1)
    i = _hash(k, mask)
    while table_keys[i] != EMPTY:
        i = (i + 1) & mask
    table_keys[i] = k
    table_slots[i] = slot


@nb.njit(**JIT)
def rehash(block_xyz, n_blocks, capacity):
    """A new table of ``capacity`` (a power of two) holding blocks 0..n_blocks-1."""
    keys = np.full(capacity, EMPTY, dtype=np.int64)
    slots = np.empty(capacity, dtype=np.int32)
    for s in range(n_blocks):
        table_insert(keys, slots, block_id(block_xyz[s, 0], block_xyz[s, 1], block_xyz[s, 2]), s)
    return keys, slots


@nb.njit(**JIT)
def coord_to_key(c: float, res_factor: float) -> int:
    """OctoMap's coordToKeyChecked: floor(c / res) + 32768, or -1 outside the key range."""
    scaled = math.floor(res_factor * c)
    if not (scaled >= -TREE_MAX_VAL and scaled < TREE_MAX_VAL):  # also rejects NaN
        return -1
    return int(scaled) + TREE_MAX_VAL


@nb.njit(**JIT)
def _slot(k, bx, by, bz, block_xyz, stamp, table_keys, table_slots, counts, touched):
    """Slot of block ``k`` (allocated if new), recorded as touched by this scan."""
    cs = table_find(table_keys, table_slots, k)
    if cs < 0:
        cs = counts[N_BLOCKS]
        counts[N_BLOCKS] += 1
        block_xyz[cs, 0] = bx
        block_xyz[cs, 1] = by
        block_xyz[cs, 2] = bz
        stamp[cs] = -1
        table_insert(table_keys, table_slots, k, cs)
    if stamp[cs] != counts[STAMP]:
        stamp[cs] = counts[STAMP]
        touched[counts[N_TOUCHED]] = cs
        counts[N_TOUCHED] += 1
    return cs


@nb.njit(**JIT)
def _room(span, counts, block_xyz, touched, table_keys):
    """DONE if ``span`` more voxels, each in a new block, fit the arrays, else what to grow."""
    if counts[N_BLOCKS] + span > block_xyz.shape[0]:
        return NEED_BLOCKS
    if counts[N_TOUCHED] + span > touched.shape[0]:
        return NEED_TOUCHED
    if 2 * (counts[N_BLOCKS] + span) > table_keys.shape[0]:
        return NEED_TABLE
    return DONE


@nb.njit(**JIT)
def voxel_key(kx, ky, kz):
    return (np.int64(kx) << 32) | (np.int64(ky) << 16) | np.int64(kz)


@nb.njit(**JIT)
def key_block(key):
    """Block id of a voxel key (flags masked off)."""
    return block_id((key >> 35) & 8191, (key >> 19) & 8191, (key >> 3) & 8191)


@nb.njit(**JIT)
def key_local(key):
    """Voxel index of a voxel key within its block."""
    return ((key >> 32) & 7) | (((key >> 16) & 7) << 3) | ((key & 7) << 6)


@nb.njit(**JIT)
def block_voxel_key(bk, local):
    kx = ((bk >> 26) << 3) | (local & 7)
    ky = (((bk >> 13) & 8191) << 3) | ((local >> 3) & 7)
    kz = ((bk & 8191) << 3) | (local >> 6)
    return voxel_key(kx, ky, kz)


@nb.njit(inline="always", **JIT)
def known(v):
    """Whether a stored value is a known voxel's: +0.0 (all bits zero, as np.zeros leaves
    memory) is unknown; a log-odds of 0 is stored as -0.0 (``stored``)."""
    return v != 0 or math.copysign(1.0, v) < 0


@nb.njit(inline="always", **JIT)
def stored(v):
    """A log-odds as the dense store holds it (0 as -0.0: +0.0 means unknown)."""
    return np.float32(-0.0) if v == 0 else v


@nb.njit(inline="always", **JIT)
def loaded(v):
    """A stored value as a log-odds: NaN if unknown, 0 as +0.0."""
    if v == 0:
        return np.float32(0.0) if math.copysign(1.0, v) < 0 else np.float32(np.nan)
    return v


@nb.njit(**JIT)
def dense_voxels(values, block_xyz, n_blocks):
    """The dense store's known voxels: keys uint16 (M, 3) and log-odds float32 (M,), block by
    block, each block's in local order (x fastest, then y, z). Two passes (count, then fill): no
    mask, index or int64 key temporaries over every voxel of every block."""
    m = 0
    for b in range(n_blocks):
        for w in range(8):
            for i in range(64):
                m += known(values[w, b, i])
    keys = np.empty((m, 3), dtype=np.uint16)
    lo = np.empty(m, dtype=np.float32)
    j = 0
    for b in range(n_blocks):
        x0, y0, z0 = block_xyz[b, 0] * 8, block_xyz[b, 1] * 8, block_xyz[b, 2] * 8
        for w in range(8):
            for i in range(64):
                v = values[w, b, i]
                if known(v):
                    local = w * 64 + i
                    keys[j, 0] = x0 + (local & 7)
                    keys[j, 1] = y0 + ((local >> 3) & 7)
                    keys[j, 2] = z0 + (local >> 6)
                    lo[j] = loaded(v)
                    j += 1
    return keys, lo
