"""Many small scans in one kernel call (numba): insert_scans' path for laser logs.

A laser log is thousands of scans of a few hundred beams. Cast one at a time, each scan pays a
round trip from Python to the kernels and back (the per-scan box, thread wake-ups, the
bookkeeping), several times the rays' own work. ``insert_batch`` runs the scans of a batch one
after the other inside one call, each exactly as insert_scan would: its end points and cut beams
(``scan_rays``), its hits marked, its rays cast (computeRayKeys' voxels, ``_raycast._cast``), then
one log-odds update per voxel it marked, hits winning, before the next scan starts. So every
voxel is updated at most once per scan, in the recording's order, and the values are the ones
one insert_scan per scan gives, bit for bit.

Serial: the path of one thread, and of a scan too large for _waves.py's scratch (with more
threads, insert_scans casts scans side by side in waves, with the same result). A scan's blocks
are found through a small direct-mapped cache of block -> slot in front of the hash table, its
entries valid for the scan that wrote them (a block's first touch in a scan goes through the
table, which records it as touched): a ray's next block is most often one an earlier ray of the
same scan entered.

The kernel is resumable: when the store is full it stops with a NEED_* status and ``state`` (the
scan, its phase, the ray) says where to go on once tree.py has grown the arrays.
"""

from __future__ import annotations

import numpy as np

from scan2terrain._numba import numba as nb
from scan2terrain.octree._raycast import dda_step, ray_start, scan_rays, update_word
from scan2terrain.octree._table import (
    DONE,
    JIT,
    N_TOUCHED,
    STAMP,
    _room,
    _slot,
    block_id,
    coord_to_key,
    stored,
)

#: state[]: the scan being inserted, its phase, the next hit or ray.
SCAN, PHASE, NEXT = 0, 1, 2
#: Phases of a scan: hits marked, rays cast, updates applied.
HITS, RAYS = 1, 2
#: Entries of the block cache (a power of two; 4 int64 each: 32 KB, L1's size).
CACHE = 1024
#: stats[]: points, beams cut at max_range, end points outside the key range, hits, misses.
N_STATS = 5


@nb.njit(**JIT)
def _mark_hits(ends, kind, resolution, start, storage):
    """Set the hit bit of every end point that is a hit, from ``start``; resumable."""
    bits, block_xyz, stamp, table_keys, table_slots, counts, touched = storage
    res_factor = 1.0 / resolution
    for i in range(start, ends.shape[0]):
        if not kind[i] & 1:
            continue
        status = _room(1, counts, block_xyz, touched, table_keys)
        if status != DONE:
            return i, status
        kx = coord_to_key(np.float64(ends[i, 0]), res_factor)
        ky = coord_to_key(np.float64(ends[i, 1]), res_factor)
        kz = coord_to_key(np.float64(ends[i, 2]), res_factor)
        bx, by, bz = kx >> 3, ky >> 3, kz >> 3
        bk = block_id(bx, by, bz)
        cs = _slot(bk, bx, by, bz, block_xyz, stamp, table_keys, table_slots, counts, touched)
        local = (kx & 7) | ((ky & 7) << 3) | ((kz & 7) << 6)
        bits[cs, local >> 6] |= np.uint64(1) << np.uint64(local & 63)
    return ends.shape[0], DONE


@nb.njit(**JIT)
def _cast_rays(origin, ends, kind, resolution, start, cache, storage):
    """computeRayKeys for every clearing ray from ``start``, setting miss bits (plane 8);
    resumable: a ray starts only when the blocks it could enter fit the store."""
    bits, block_xyz, stamp, table_keys, table_slots, counts, touched = storage
    res_factor = 1.0 / resolution
    ox, oy, oz = origin[0], origin[1], origin[2]
    for i in range(start, ends.shape[0]):
        if not kind[i] & 2:
            continue
        span = 4
        for a in range(3):
            span += abs(
                coord_to_key(np.float64(ends[i, a]), res_factor)
                - coord_to_key(np.float64(origin[a]), res_factor)
            )
        status = _room(span, counts, block_xyz, touched, table_keys)
        if status != DONE:
            return i, status
        ray = ray_start(ox, oy, oz, ends[i, 0], ends[i, 1], ends[i, 2], resolution)
        kx, ky, kz, ekx, eky, ekz, sx, sy, sz, tx, ty, tz, ddx, ddy, ddz, length = ray
        ck, cs = np.int64(-1), np.int64(-1)
        scan = counts[STAMP]
        while True:
            bx, by, bz = kx >> 3, ky >> 3, kz >> 3
            bk = block_id(bx, by, bz)
            if bk != ck:
                # The cache, written out: a call here, even inlined, costs more than the steps.
                ck = bk
                at = (bx * 73856093 ^ by * 19349663 ^ bz * 83492791) & (CACHE - 1)
                if cache[at, 0] == bk and cache[at, 2] == scan:  # one row: one cache line
                    cs = cache[at, 1]
                else:
                    cs = _slot(
                        bk, bx, by, bz, block_xyz, stamp, table_keys, table_slots, counts, touched
                    )
                    cache[at, 0] = bk
                    cache[at, 1] = cs
                    cache[at, 2] = scan
            local = (kx & 7) | ((ky & 7) << 3) | ((kz & 7) << 6)
            bits[cs, 8 + (local >> 6)] |= np.uint64(1) << np.uint64(local & 63)
            kx, ky, kz, tx, ty, tz = dda_step(kx, ky, kz, tx, ty, tz, sx, sy, sz, ddx, ddy, ddz)
            if kx == ekx and ky == eky and kz == ekz:
                break
            if min(min(tx, ty), tz) > length:  # noqa: PLW3301 (computeRayKeys' own form)
                break
    return ends.shape[0], DONE


@nb.njit(inline="always", **JIT)
def _popcount(x):
    x = x - ((x >> np.uint64(1)) & np.uint64(0x5555555555555555))
    x = (x & np.uint64(0x3333333333333333)) + ((x >> np.uint64(2)) & np.uint64(0x3333333333333333))
    x = (x + (x >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return np.int64((x * np.uint64(0x0101010101010101)) >> np.uint64(56))


@nb.njit(inline="always", **JIT)
def _update_all(values, cs, w, hit_word, any_word, model):
    """update_word's updates for all 64 voxels of a word at once, without branches (a word
    full of marks, as a planar scan's free space leaves them: one z layer of a block is one
    word): a voxel without a mark keeps its value, bit for bit."""
    lo_hit, lo_miss, cmin, cmax = model[0], model[1], model[2], model[3]
    for i in range(64):
        mark = (any_word >> np.uint64(i)) & np.uint64(1)
        hit = (hit_word >> np.uint64(i)) & np.uint64(1)
        old = values[w, cs, i]  # unknown is +0.0: log-odds 0, where a new node starts
        v = np.float32(old + (lo_hit if hit else lo_miss))
        v = cmin if v < cmin else (cmax if v > cmax else v)
        values[w, cs, i] = stored(v) if mark else old


#: From this many marks in a word, all 64 voxels are computed without branches.
DENSE_WORD = 12


@nb.njit(**JIT)
def _apply(values, bits, touched, n_touched, model, stats):
    """One update per marked voxel of the scan's blocks (apply_blocks, serial); bits cleared."""
    for j in range(n_touched):
        cs = touched[j]
        for w in range(8):
            hit_word = bits[cs, w]
            any_word = hit_word | bits[cs, 8 + w]
            if any_word == 0:
                continue
            bits[cs, w] = 0
            bits[cs, 8 + w] = 0
            n = _popcount(any_word)
            if n >= DENSE_WORD:
                h = _popcount(hit_word)
                _update_all(values, cs, w, hit_word, any_word, model)
                stats[3] += h
                stats[4] += n - h
            else:
                h, m = update_word(values, cs, w, hit_word, any_word, model)
                stats[3] += h
                stats[4] += m


@nb.njit(**JIT)
def insert_batch(
    points,
    offsets,
    origins,
    max_ranges,
    resolution,
    model,
    values,
    state,
    stats,
    cache,
    storage,
):
    """Insert scans ``state[SCAN]`` .. end in order: scan s is ``points[offsets[s]:offsets[s +
    1]]`` (float32) seen from ``origins[s]`` (float32, in the key range), beams cut at
    ``max_ranges[s]`` (< 0: none). ``storage`` is tree.py's (bits, block_xyz, stamp,
    table_keys, table_slots, counts, touched); ``stats`` (int64, N_STATS) is added to once per
    scan. Returns DONE, or the NEED_* status that stopped it (``state`` says where)."""
    bits, touched, counts = storage[0], storage[6], storage[5]
    n_scans = offsets.shape[0] - 1
    while state[SCAN] < n_scans:
        s = state[SCAN]
        pts = points[offsets[s] : offsets[s + 1]]
        origin = origins[s]
        ends, kind, rays = scan_rays(pts, origin, max_ranges[s], resolution)
        if state[PHASE] == 0:  # a new scan: its stamp, its counts
            counts[STAMP] += 1
            stats[0] += rays[0]
            stats[1] += rays[1]
            stats[2] += rays[2]
            state[PHASE] = HITS
            state[NEXT] = 0
        if state[PHASE] == HITS:
            at, status = _mark_hits(ends, kind, resolution, state[NEXT], storage)
            state[NEXT] = at
            if status != DONE:
                return status
            state[PHASE] = RAYS
            state[NEXT] = 0
        at, status = _cast_rays(origin, ends, kind, resolution, state[NEXT], cache, storage)
        state[NEXT] = at
        if status != DONE:
            return status
        _apply(values, bits, touched, counts[N_TOUCHED], model, stats)
        counts[N_TOUCHED] = 0
        state[SCAN] = s + 1
        state[PHASE] = 0
    return DONE
