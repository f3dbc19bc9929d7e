"""Ray casting into the scan's own box of bits (numba): insert_scan's path for large scans.

The rays of one scan from one origin mark their voxels in a bit array of the scan's own: the
blocks (8 x 8 x 8 voxels) of the bounding box of the origin and the ray ends, with one block of
margin, row ``((bx * nby) + by) * nbz + bz`` (8 words, 512 bits) for block (bx, by, bz) of the
box, in planes: ``bits[0]`` the hits, ``bits[1 + t]`` thread t's misses (each thread writes
its own memory: no bit lost, no cache line shared). A step of a ray then costs its key
arithmetic and one OR: no block id, no look-up of the block's slot, no pass to find the
blocks first. After the rays, the blocks with a bit get their slot in the dense store
(``alloc_box``, in box order) and one log-odds update per marked voxel, hits winning
(``apply_box``, which leaves the bits zeroed), as OctoMap's insertPointCloud.

The voxels visited are computeRayKeys' own (the same arithmetic as ``_raycast._cast``). A ray
that would step out of the box (rounding can carry a ray a voxel past its end; a block of
margin holds that) is counted, and the caller casts the whole scan again the dense store's way.
"""

from __future__ import annotations

import numpy as np

from scan2terrain._numba import numba as nb
from scan2terrain.octree._raycast import dda_step, ray_start, update_word
from scan2terrain.octree._table import (
    DONE,
    JIT,
    WANTED,
    _room,
    _slot,
    block_id,
    coord_to_key,
)


@nb.njit(**JIT)
def _ray(ox, oy, oz, ex, ey, ez, resolution, lo, nbk, bits, plane):
    """computeRayKeys from o to e (float32), setting each voxel's bit in its block's row of
    ``plane``; False if the ray would leave the box (nothing more set)."""
    nx, ny, nz = np.uint64(nbk[0] * 8), np.uint64(nbk[1] * 8), np.uint64(nbk[2] * 8)
    start = ray_start(ox, oy, oz, ex, ey, ez, resolution)
    kx, ky, kz, ekx, eky, ekz, sx, sy, sz, tx, ty, tz, ddx, ddy, ddz, length = start
    # Keys relative to the box's corner (lo: a block corner, so block = key >> 3 there too).
    kx, ky, kz = kx - lo[0], ky - lo[1], kz - lo[2]
    ekx, eky, ekz = ekx - lo[0], eky - lo[1], ekz - lo[2]
    nby, nbz = nbk[1], nbk[2]
    while True:
        row = ((kx >> 3) * nby + (ky >> 3)) * nbz + (kz >> 3)
        local = (kx & 7) | ((ky & 7) << 3) | ((kz & 7) << 6)
        bits[plane, row, local >> 6] |= np.uint64(1) << np.uint64(local & 63)
        kx, ky, kz, tx, ty, tz = dda_step(kx, ky, kz, tx, ty, tz, sx, sy, sz, ddx, ddy, ddz)
        if np.uint64(kx) >= nx or np.uint64(ky) >= ny or np.uint64(kz) >= nz:
            return False  # out of the box (unsigned: below 0 too)
        if kx == ekx and ky == eky and kz == ekz:
            return True
        if min(min(tx, ty), tz) > length:  # noqa: PLW3301 (computeRayKeys' own form)
            return True


@nb.njit(parallel=True, **JIT)
def cast_box(origin, ends, kind, resolution, lo, nbk, bits):
    """Every clearing ray's miss bits, on every core: chunks of 256 rays, handed to the threads
    as they ask (numba.parallel_chunksize(1) around the call: a thread whose core is taken by
    another process holds up one chunk, not a share of the scan); thread t writes plane 1 + t.
    Then every hit's hit bit. Returns how many rays would have left the box (0: the bits are
    complete)."""
    n = ends.shape[0]
    chunk = 256
    n_chunks = (n + chunk - 1) // chunk
    left = np.zeros(n_chunks, dtype=np.int64)
    ox, oy, oz = origin[0], origin[1], origin[2]
    for c in nb.prange(n_chunks):
        plane = 1 + nb.get_thread_id()
        for i in range(c * chunk, min(n, (c + 1) * chunk)):
            if kind[i] & 2 and not _ray(
                ox, oy, oz, ends[i, 0], ends[i, 1], ends[i, 2], resolution, lo, nbk, bits, plane
            ):
                left[c] += 1
    res_factor = 1.0 / resolution
    nby, nbz = nbk[1], nbk[2]
    for i in range(n):
        if kind[i] & 1:  # the hit's voxel is in the box: the box holds every end
            kx = coord_to_key(np.float64(ends[i, 0]), res_factor) - lo[0]
            ky = coord_to_key(np.float64(ends[i, 1]), res_factor) - lo[1]
            kz = coord_to_key(np.float64(ends[i, 2]), res_factor) - lo[2]
            row = ((kx >> 3) * nby + (ky >> 3)) * nbz + (kz >> 3)
            local = (kx & 7) | ((ky & 7) << 3) | ((kz & 7) << 6)
            bits[0, row, local >> 6] |= np.uint64(1) << np.uint64(local & 63)
    return left.sum()


@nb.njit(**JIT)
def alloc_box(
    bits, lo, nbk, start, rows, block_xyz, stamp, table_keys, table_slots, counts, touched
):
    """Serial, in box order: every block of the box with a bit gets its slot in the dense store
    (allocated if new, recorded as touched by this scan) in ``rows`` (-1: no bit). Resumable:
    returns (next row, DONE or NEED_*)."""
    nby, nbz = nbk[1], nbk[2]
    bx0, by0, bz0 = lo[0] >> 3, lo[1] >> 3, lo[2] >> 3
    for row in range(start, bits.shape[1]):
        if not _marked(bits, row):
            rows[row] = -1
            continue
        status = _room(1, counts, block_xyz, touched, table_keys)
        if status != DONE:
            counts[WANTED] = _marked_rows(bits, row)  # at most this many more blocks
            return row, status
        bx = bx0 + row // (nby * nbz)
        by = by0 + (row // nbz) % nby
        bz = bz0 + row % nbz
        rows[row] = _slot(
            block_id(bx, by, bz), bx, by, bz, block_xyz, stamp, table_keys, table_slots,
            counts, touched,
        )  # fmt: skip
    return bits.shape[1], DONE


@nb.njit(inline="always", **JIT)
def _marked(bits, row):
    """Whether ``row`` of the box has a bit in some plane."""
    marked = np.uint64(0)
    for p in range(bits.shape[0]):
        for w in range(8):
            marked |= bits[p, row, w]
    return marked != 0


@nb.njit(**JIT)
def _marked_rows(bits, start):
    """Rows from ``start`` on with a bit in some plane."""
    n = 0
    for row in range(start, bits.shape[1]):
        n += _marked(bits, row)
    return n


@nb.njit(parallel=True, **JIT)
def apply_box(values, bits, rows, model):
    """OctoMap's updateNodeLogOdds once per marked voxel of the box (a hit where the hit bit is
    set, else a miss), into the dense store's block ``rows[row]``, clearing the bits (every
    marked row has a block: the bits are all zero again). Blocks are disjoint, so they go to
    the cores in parallel. Returns (hits, misses)."""
    hits = 0
    misses = 0
    for row in nb.prange(bits.shape[1]):
        cs = rows[row]
        if cs < 0:
            continue
        for w in range(8):
            hit_word = bits[0, row, w]
            bits[0, row, w] = 0
            any_word = hit_word
            for p in range(1, bits.shape[0]):
                any_word |= bits[p, row, w]
                bits[p, row, w] = 0
            h, m = update_word(values, cs, w, hit_word, any_word, model)
            hits += h
            misses += m
    return hits, misses
