"""End points only (numba): insert_endpoints' points sorted by block, no rays.

Points are sorted by block into partitions (``count_points``, ``place_points``, every core, a
chunk of points at a time). Points in blocks of the dense store set hit bits there
(``touch_points``, ``mark_point_bits``, then _raycast.apply_blocks with ``all_hits``); the voxel
keys of the others, partition by partition, go on to _group.py and the sparse store.
"""

from __future__ import annotations

import math

import numpy as np

from scan2terrain._numba import numba as nb
from scan2terrain.octree._sparse import NPART, NREG_BITS, PART_BITS, _region
from scan2terrain.octree._table import (
    DONE,
    EMPTY,
    JIT,
    N_TOUCHED,
    NEED_TOUCHED,
    STAMP,
    _hash,
    block_id,
    coord_to_key,
    voxel_key,
)

# count_points' classes of points that are not inserted (-1 - their column of its counts).
OUTSIDE = -(NPART + 2)
NONFINITE = -(NPART + 3)
#: Points per chunk of the partition histogram (fixed, so the partition is the same on any core
#: count).
CHUNK = 1 << 16


@nb.njit(parallel=True, **JIT)
def count_points(points, resolution, table_keys, table_slots, cls):
    """End points only, first pass, on every core, CHUNK points at a time (the table is only
    read). Each point's class into ``cls`` (int32): its block's slot in the dense store (>= 0),
    or -1 - its partition (block not in the dense store), or OUTSIDE (outside the key range) or
    NONFINITE; and per chunk how many points of each: columns 0..NPART-1 per partition, NPART
    dense, NPART + 1 outside, NPART + 2 non-finite (int64 (chunks, NPART + 3)). With an empty
    ``cls`` (a tree without dense blocks) the classes are only counted and no block is looked up.
    Written out, with no call per point (numba would count references to the arrays at each
    one); a run of points in one block probes the table once."""
    keep = cls.shape[0] > 0
    res_factor = 1.0 / resolution
    n = points.shape[0]
    n_chunks = (n + CHUNK - 1) // CHUNK
    hist = np.zeros((n_chunks, NPART + 3), dtype=np.int64)
    mask = np.int64(table_keys.shape[0] - 1)
    for c in nb.prange(n_chunks):
        ck, cs, col = np.int64(-3), np.int64(-1), np.int64(0)
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            x, y, z = points[i, 0], points[i, 1], points[i, 2]
            kx = coord_to_key(np.float64(x), res_factor)
            ky = coord_to_key(np.float64(y), res_factor)
            kz = coord_to_key(np.float64(z), res_factor)
            if kx < 0 or ky < 0 or kz < 0:
                finite = math.isfinite(x) and math.isfinite(y) and math.isfinite(z)
                col = NPART + 1 if finite else NPART + 2
                hist[c, col] += 1
                if keep:
                    cls[i] = -col - 1  # OUTSIDE or NONFINITE
                ck = -3
                continue
            k = block_id(kx >> 3, ky >> 3, kz >> 3)
            if k != ck:
                ck = k
                h = _hash(k, mask)
                cs = -1 - (_region(k) >> (NREG_BITS - PART_BITS))
                col = -1 - cs
                while keep:
                    tk = table_keys[h]
                    if tk == k:
                        cs = np.int64(table_slots[h])
                        col = np.int64(NPART)
                        break
                    if tk == EMPTY:
                        break
                    h = (h + 1) & mask
            if keep:
                cls[i] = cs
            hist[c, col] += 1
    return hist


@nb.njit(parallel=True, **JIT)
def place_points(points, resolution, cls, offsets, new, dense):
    """End points only, second pass, on every core: the voxel key of each point outside the
    dense store into ``new``, partition by partition (point order within one), and
    ``(slot << 9) | local`` of each point in the dense store into ``dense`` (point order).
    ``cls``: from :func:`count_points` (empty: no dense blocks); ``offsets[c]``: where chunk c's
    points go, per partition (columns 0..NPART-1) in ``new`` and (column NPART) in ``dense``;
    advanced."""
    res_factor = 1.0 / resolution
    n = points.shape[0]
    keep = cls.shape[0] > 0
    for c in nb.prange(offsets.shape[0]):
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            if keep:
                cs = np.int64(cls[i])
                if cs <= OUTSIDE:
                    continue
            kx = coord_to_key(np.float64(points[i, 0]), res_factor)
            ky = coord_to_key(np.float64(points[i, 1]), res_factor)
            kz = coord_to_key(np.float64(points[i, 2]), res_factor)
            if not keep:
                if kx < 0 or ky < 0 or kz < 0:
                    continue
                cs = -1 - (_region(block_id(kx >> 3, ky >> 3, kz >> 3)) >> (NREG_BITS - PART_BITS))
            if cs < 0:
                col = -1 - cs
                at = offsets[c, col]
                offsets[c, col] = at + 1
                new[at] = voxel_key(kx, ky, kz)
            else:
                at = offsets[c, NPART]
                offsets[c, NPART] = at + 1
                dense[at] = (cs << 9) | (kx & 7) | ((ky & 7) << 3) | ((kz & 7) << 6)


@nb.njit(**JIT)
def touch_points(dense, start, stamp, counts, touched):
    """End points only (serial): record every dense block the points hit (``dense``, from
    :func:`place_points`) as touched by this call. Resumable (it stops for room in
    ``touched``)."""
    scan = counts[STAMP]
    last = np.int64(-3)
    n = dense.shape[0]
    for i in range(start, n):
        s = dense[i] >> 9
        if s == last:
            continue
        last = s
        if stamp[s] != scan:
            if counts[N_TOUCHED] + 1 > touched.shape[0]:
                return i, NEED_TOUCHED
            stamp[s] = scan
            touched[counts[N_TOUCHED]] = s
            counts[N_TOUCHED] += 1
    return n, DONE


@nb.njit(parallel=True, **JIT)
def mark_point_bits(dense, planes, bits):
    """End points only, on every core: thread t sets the bits of its points in the dense store
    (``dense``, from :func:`place_points`) in its own words 8 + 8t .. 15 + 8t (chunks t, t + T,
    ...), so no bit is lost to a race; :func:`apply_blocks` with ``all_hits`` reads every plane
    as hits."""
    n = dense.shape[0]
    chunk = 4096
    n_chunks = (n + chunk - 1) // chunk
    for t in nb.prange(planes):
        plane = 8 + 8 * t
        for c in range(t, n_chunks, planes):
            for i in range(c * chunk, min(n, (c + 1) * chunk)):
                cs = dense[i] >> 9
                loc = dense[i] & 511
                bits[cs, plane + (loc >> 6)] |= np.uint64(1) << np.uint64(loc & 63)
