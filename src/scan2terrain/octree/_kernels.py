"""Compiled inner loops of the voxel octree (numba). Nothing here allocates Python objects.

Storage (see tree.py): voxels live in dense blocks of 8 x 8 x 8 found through an open-addressing
hash of block coordinates. Per block: ``values`` float32 log-odds (NaN = unknown) and ``bits``,
uint64 words, one bit per voxel: this scan's hits (words 0-7) and, per thread, its misses (words
8 + 8t .. 15 + 8t), so the marks of a whole scan stay in cache and threads never share a word.

A scan (1) finds the blocks its rays pass through (``flag_blocks``, every core), allocates them and
marks its hits (``alloc_flagged``, ``mark_hits``, serial); (2) casts the rays on every core,
setting miss bits (``cast_parallel``, each thread in its own words; the rare ray that meets an
unprepared block is redone serially by ``cast_serial``); (3) applies one log-odds update per marked
voxel of the blocks it touched, hits winning, block-parallel (``apply_blocks``). So each voxel is
updated once per scan and occupied wins, as in OctoMap's insertPointCloud. ``touched`` lists the
blocks the scan touched; ``stamp`` holds, per block, the last scan that touched it.

Ray casting reproduces OctoMap's ``computeRayKeys`` and ``computeUpdate`` (OcTreeBaseImpl.hxx,
OccupancyOcTreeBase.hxx) operation for operation, including which quantities are float32 and which
double, so the voxels visited are the ones OctoMap visits.

End points only (``insert_endpoints``, see "end points only" below) need no rays: points are
sorted by block into partitions (``count_points``, ``place_points``), each partition's distinct
voxels are grouped by block on a core of their own (``group_new_points``), and a block with few
voxels keeps them in the sparse store, a voxel-level open-addressing hash, instead of a 2 KB
block (see "the sparse store" below). A block is in the dense store or in the sparse one.
"""

from __future__ import annotations

import math
import os
import types
from typing import Any, NamedTuple

import numba as nb
import numpy as np

# numba tries TBB first; Open3D's wheel ships an older libtbb, and once Open3D is loaded numba
# finds that one, warns and falls back. OpenMP (then numba's own work queue) unless the user
# chose a threading layer.
if not any(k.startswith("NUMBA_THREADING_LAYER") for k in os.environ):
    nb.config.THREADING_LAYER_PRIORITY = ["omp", "workqueue", "tbb"]

TREE_MAX_VAL = 32768
KEY_LIMIT = 65536
EMPTY = np.int64(-1)
# Status codes returned by the insertion kernels.
DONE, NEED_BLOCKS, NEED_TOUCHED, NEED_TABLE = 0, 1, 2, 3
# counts[] of the insertion kernels: blocks in use, blocks touched this scan, scan stamp.
N_BLOCKS, N_TOUCHED, STAMP = 0, 1, 2

_JIT = {"nogil": True, "cache": True, "error_model": "numpy"}
# Helpers that take arrays and run once per point or voxel are inlined by numba (inline="always"):
# a call passing arrays counts references to them, which costs several times the work.

# Index of a word's lowest set bit: (bit * De Bruijn constant) >> 58 is unique per bit.
_DEBRUIJN_MUL = np.uint64(0x03F79D71B4CB0A89)
_DEBRUIJN = np.zeros(64, dtype=np.int64)
for _b in range(64):
    _DEBRUIJN[((1 << _b) * 0x03F79D71B4CB0A89 % (1 << 64)) >> 58] = _b


@nb.njit(**_JIT)
def block_id(bx: int, by: int, bz: int) -> np.int64:
    return (np.int64(bx) << 26) | (np.int64(by) << 13) | np.int64(bz)


@nb.njit(**_JIT)
def _hash(k: np.int64, mask: np.int64) -> np.int64:
    h = np.uint64(k) * np.uint64(0x9E3779B97F4A7C15)
    return np.int64(h >> np.uint64(20)) & mask


@nb.njit(**_JIT)
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


@nb.njit(**_JIT)
def table_insert(table_keys, table_slots, k, slot):
    mask = np.int64(table_keys.shape[0] - 1)
    i = _hash(k, mask)
    while table_keys[i] != EMPTY:
        i = (i + 1) & mask
    table_keys[i] = k
    table_slots[i] = slot


@nb.njit(**_JIT)
def rehash(block_xyz, n_blocks, capacity):
    """A new table of ``capacity`` (a power of two) holding blocks 0..n_blocks-1."""
    keys = np.full(capacity, EMPTY, dtype=np.int64)
    slots = np.empty(capacity, dtype=np.int32)
    for s in range(n_blocks):
        table_insert(keys, slots, block_id(block_xyz[s, 0], block_xyz[s, 1], block_xyz[s, 2]), s)
    return keys, slots


@nb.njit(**_JIT)
def coord_to_key(c: float, res_factor: float) -> int:
    """OctoMap's coordToKeyChecked: floor(c / res) + 32768, or -1 outside the key range."""
    scaled = math.floor(res_factor * c)
    if not (scaled >= -TREE_MAX_VAL and scaled < TREE_MAX_VAL):  # also rejects NaN
        return -1
    return int(scaled) + TREE_MAX_VAL


@nb.njit(**_JIT)
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


@nb.njit(**_JIT)
def _axis_start(k, s, o, d, resolution):
    """tMax and tDelta of one axis, as computeRayKeys computes them (double from float)."""
    if s == 0:
        big = 1.7976931348623157e308
        return big, big
    border = (np.float64(k - TREE_MAX_VAL) + 0.5) * resolution
    border += np.float64(np.float32(s * resolution * 0.5))
    return (border - np.float64(o)) / np.float64(d), resolution / np.float64(abs(d))


@nb.njit(**_JIT)
def _sign(d):
    return 1 if d > 0.0 else (-1 if d < 0.0 else 0)


@nb.njit(**_JIT)
def _room(span, counts, block_xyz, touched, table_keys):
    """DONE if ``span`` more voxels, each in a new block, fit the arrays, else what to grow."""
    if counts[N_BLOCKS] + span > block_xyz.shape[0]:
        return NEED_BLOCKS
    if counts[N_TOUCHED] + span > touched.shape[0]:
        return NEED_TOUCHED
    if 2 * (counts[N_BLOCKS] + span) > table_keys.shape[0]:
        return NEED_TABLE
    return DONE


@nb.njit(**_JIT)
def scan_rays(points, origin, max_range, resolution):
    """OctoMap's computeUpdate, per point: the ray's end and what to do with it.

    Returns ends float32 (N, 3) (the point, or the point pulled back to ``max_range``) and
    kind int8 (N,): bit 1 = the end point is a hit (beam within range, key valid), bit 2 = the
    ray clears (both ends in the key range and in different voxels). stats: [rays cast, beams
    cut at max_range, end points outside the key range].
    """
    res_factor = 1.0 / resolution
    ox, oy, oz = origin[0], origin[1], origin[2]
    okx = coord_to_key(np.float64(ox), res_factor)
    oky = coord_to_key(np.float64(oy), res_factor)
    okz = coord_to_key(np.float64(oz), res_factor)
    origin_ok = okx >= 0 and oky >= 0 and okz >= 0
    n = points.shape[0]
    ends = np.empty((n, 3), dtype=np.float32)
    kind = np.zeros(n, dtype=np.int8)
    stats = np.zeros(3, dtype=np.int64)
    mr = np.float32(max_range)
    for i in range(n):
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        # point3d arithmetic is float32; norm() squares and sums in float32, sqrt in double.
        dx = np.float32(px - ox)
        dy = np.float32(py - oy)
        dz = np.float32(pz - oz)
        dist = math.sqrt(np.float64(dx * dx + dy * dy + dz * dz))
        stats[0] += 1
        if max_range < 0.0 or dist <= max_range:
            ex, ey, ez = px, py, pz
            hit_ok = True
        else:
            # normalized() divides by (float) norm; new_end = origin + direction * (float) maxrange
            length = np.float32(dist)
            ex = np.float32(ox + np.float32(np.float32(dx / length) * mr))
            ey = np.float32(oy + np.float32(np.float32(dy / length) * mr))
            ez = np.float32(oz + np.float32(np.float32(dz / length) * mr))
            hit_ok = False
            stats[1] += 1
        ends[i, 0], ends[i, 1], ends[i, 2] = ex, ey, ez
        ekx = coord_to_key(np.float64(ex), res_factor)
        eky = coord_to_key(np.float64(ey), res_factor)
        ekz = coord_to_key(np.float64(ez), res_factor)
        end_ok = ekx >= 0 and eky >= 0 and ekz >= 0
        if hit_ok and not end_ok:
            stats[2] += 1
        k = 0
        if hit_ok and end_ok:
            k |= 1
        if origin_ok and end_ok and not (okx == ekx and oky == eky and okz == ekz):
            k |= 2
        kind[i] = k
    return ends, kind, stats


@nb.njit(**_JIT)
def block_bounds(origin, ends, resolution):
    """Min and max block coordinates (int64 (2, 3)) of the origin's and the ends' voxels."""
    res_factor = 1.0 / resolution
    out = np.empty((2, 3), dtype=np.int64)
    for a in range(3):
        b = coord_to_key(np.float64(origin[a]), res_factor) >> 3
        out[0, a] = b
        out[1, a] = b
    for i in range(ends.shape[0]):
        for a in range(3):
            k = coord_to_key(np.float64(ends[i, a]), res_factor)
            if k >= 0:
                b = k >> 3
                out[0, a] = min(out[0, a], b)
                out[1, a] = max(out[1, a], b)
    return out


@nb.njit(parallel=True, **_JIT)
def flag_blocks(origin, ends, kind, resolution, dense, box):
    """First pass of a scan, on every core: flag (-2) in ``dense`` every block of the scan's box
    that a ray's segment passes through or that holds a hit, by a DDA over blocks (8 voxels a
    step). ``dense`` is an int32 index over the scan's bounding box of blocks (``box`` = min
    block x, y, z and extents): -1 unused, -2 needed, >= 0 the block's slot. Threads only ever
    write -2 over -1, so they agree."""
    res_factor = 1.0 / resolution
    ox, oy, oz = origin[0], origin[1], origin[2]
    uo = (np.float64(ox) * res_factor + TREE_MAX_VAL) / 8.0
    vo = (np.float64(oy) * res_factor + TREE_MAX_VAL) / 8.0
    wo = (np.float64(oz) * res_factor + TREE_MAX_VAL) / 8.0
    x0, y0, z0, nx, ny, nz = box[0], box[1], box[2], box[3], box[4], box[5]
    for i in nb.prange(ends.shape[0]):
        if not kind[i]:
            continue
        ue = (np.float64(ends[i, 0]) * res_factor + TREE_MAX_VAL) / 8.0
        ve = (np.float64(ends[i, 1]) * res_factor + TREE_MAX_VAL) / 8.0
        we = (np.float64(ends[i, 2]) * res_factor + TREE_MAX_VAL) / 8.0
        ebx, eby, ebz = math.floor(ue), math.floor(ve), math.floor(we)
        if not kind[i] & 2:  # a hit only: its own block
            bx, by, bz = ebx, eby, ebz
        else:
            bx, by, bz = math.floor(uo), math.floor(vo), math.floor(wo)
        steps = abs(ebx - bx) + abs(eby - by) + abs(ebz - bz)
        du, dv, dw = ue - uo, ve - vo, we - wo
        sx, sy, sz = _sign(du), _sign(dv), _sign(dw)
        big = 1.7976931348623157e308
        tx = ((bx + (sx > 0)) - uo) / du if sx != 0 else big
        ty = ((by + (sy > 0)) - vo) / dv if sy != 0 else big
        tz = ((bz + (sz > 0)) - wo) / dw if sz != 0 else big
        ddx = 1.0 / abs(du) if sx != 0 else big
        ddy = 1.0 / abs(dv) if sy != 0 else big
        ddz = 1.0 / abs(dw) if sz != 0 else big
        for _ in range(steps + 1):
            ix, iy, iz = bx - x0, by - y0, bz - z0
            if 0 <= ix < nx and 0 <= iy < ny and 0 <= iz < nz:
                at = (ix * ny + iy) * nz + iz
                if dense[at] == -1:
                    dense[at] = -2
            if bx == ebx and by == eby and bz == ebz:
                break
            if tx < ty:
                if tx < tz:
                    bx += sx
                    tx += ddx
                else:
                    bz += sz
                    tz += ddz
            elif ty < tz:
                by += sy
                ty += ddy
            else:
                bz += sz
                tz += ddz


@nb.njit(**_JIT)
def alloc_flagged(
    dense, box, start, bits, block_xyz, stamp, table_keys, table_slots, counts, touched
):
    """Serial: give every flagged block of ``dense`` its slot (allocated if new, recorded as
    touched by this scan). Resumable: returns (next entry, DONE or NEED_*)."""
    ny, nz = box[4], box[5]
    for at in range(start, dense.shape[0]):
        if dense[at] != -2:
            continue
        status = _room(1, counts, block_xyz, touched, table_keys)
        if status != DONE:
            return at, status
        bx = box[0] + at // (ny * nz)
        by = box[1] + (at // nz) % ny
        bz = box[2] + at % nz
        dense[at] = _slot(
            block_id(bx, by, bz),
            bx,
            by,
            bz,
            block_xyz,
            stamp,
            table_keys,
            table_slots,
            counts,
            touched,
        )
    return dense.shape[0], DONE


@nb.njit(**_JIT)
def mark_hits(
    ends,
    kind,
    resolution,
    dense,
    box,
    start,
    bits,
    block_xyz,
    stamp,
    table_keys,
    table_slots,
    counts,
    touched,
):
    """Serial: set the hit bit of every end point that is a hit (its block found in ``dense``,
    or added if outside the scan's box). Resumable: returns (next index, DONE or NEED_*)."""
    res_factor = 1.0 / resolution
    x0, y0, z0, nx, ny, nz = box[0], box[1], box[2], box[3], box[4], box[5]
    for i in range(start, ends.shape[0]):
        if not kind[i] & 1:
            continue
        kx = coord_to_key(np.float64(ends[i, 0]), res_factor)
        ky = coord_to_key(np.float64(ends[i, 1]), res_factor)
        kz = coord_to_key(np.float64(ends[i, 2]), res_factor)
        hx, hy, hz = kx >> 3, ky >> 3, kz >> 3
        ix, iy, iz = hx - x0, hy - y0, hz - z0
        cs = -1
        if 0 <= ix < nx and 0 <= iy < ny and 0 <= iz < nz:
            cs = dense[(ix * ny + iy) * nz + iz]
        if cs < 0:
            status = _room(1, counts, block_xyz, touched, table_keys)
            if status != DONE:
                return i, status
            cs = _slot(
                block_id(hx, hy, hz),
                hx,
                hy,
                hz,
                block_xyz,
                stamp,
                table_keys,
                table_slots,
                counts,
                touched,
            )
        local = (kx & 7) | ((ky & 7) << 3) | ((kz & 7) << 6)
        bits[cs, local >> 6] |= np.uint64(1) << np.uint64(local & 63)
    return ends.shape[0], DONE


@nb.njit(**_JIT)
def _cast(
    ox,
    oy,
    oz,
    ex,
    ey,
    ez,
    resolution,
    alloc,
    plane,
    dense,
    box,
    bits,
    block_xyz,
    stamp,
    table_keys,
    table_slots,
    counts,
    touched,
):
    """OctoMap's computeRayKeys from o to e (float32), setting each voxel's miss bit in the
    words from ``plane`` on (each thread has its own, so no bit is lost to a race).

    Without ``alloc`` (the parallel pass) a voxel in a block not prepared for this scan stops
    the ray and returns False; with it (the serial fallback) such blocks are added (they are
    not entered in ``dense``, so each costs a hash lookup: the fallback is rare).
    """
    res_factor = 1.0 / resolution
    kx = coord_to_key(np.float64(ox), res_factor)
    ky = coord_to_key(np.float64(oy), res_factor)
    kz = coord_to_key(np.float64(oz), res_factor)
    ekx = coord_to_key(np.float64(ex), res_factor)
    eky = coord_to_key(np.float64(ey), res_factor)
    ekz = coord_to_key(np.float64(ez), res_factor)
    dx = np.float32(ex - ox)
    dy = np.float32(ey - oy)
    dz = np.float32(ez - oz)
    length = np.float32(math.sqrt(np.float64(dx * dx + dy * dy + dz * dz)))
    dx = dx / length
    dy = dy / length
    dz = dz / length
    sx, sy, sz = _sign(dx), _sign(dy), _sign(dz)
    tx, ddx = _axis_start(kx, sx, ox, dx, resolution)
    ty, ddy = _axis_start(ky, sy, oy, dy, resolution)
    tz, ddz = _axis_start(kz, sz, oz, dz, resolution)
    ck, cs = np.int64(-1), np.int64(-1)
    while True:
        # Mark (kx, ky, kz): the origin's voxel first, then each voxel the DDA steps into.
        # Written out rather than called: a call per voxel costs several times the step.
        bx, by, bz = kx >> 3, ky >> 3, kz >> 3
        bk = block_id(bx, by, bz)
        if bk != ck:
            ck = bk
            # This scan's blocks are found in ``dense``, an index over the scan's bounding box
            # of blocks filled by ``alloc_flagged``: one load instead of a trip to the hash table.
            ix, iy, iz = bx - box[0], by - box[1], bz - box[2]
            cs = -1
            if 0 <= ix < box[3] and 0 <= iy < box[4] and 0 <= iz < box[5]:
                cs = dense[(ix * box[4] + iy) * box[5] + iz]
            if cs < 0:
                if not alloc:
                    return False
                cs = _slot(
                    bk, bx, by, bz, block_xyz, stamp, table_keys, table_slots, counts, touched
                )
        local = (kx & 7) | ((ky & 7) << 3) | ((kz & 7) << 6)
        bits[cs, plane + (local >> 6)] |= np.uint64(1) << np.uint64(local & 63)
        # The minimum tMax, ties going to the later axis, exactly as computeRayKeys.
        if tx < ty:
            if tx < tz:
                kx += sx
                tx += ddx
            else:
                kz += sz
                tz += ddz
        elif ty < tz:
            ky += sy
            ty += ddy
        else:
            kz += sz
            tz += ddz
        if kx == ekx and ky == eky and kz == ekz:
            return True
        if min(min(tx, ty), tz) > length:  # noqa: PLW3301 (computeRayKeys' own form)
            return True


@nb.njit(parallel=True, **_JIT)
def cast_parallel(
    origin,
    ends,
    kind,
    resolution,
    planes,
    dense,
    box,
    bits,
    block_xyz,
    stamp,
    table_keys,
    table_slots,
    counts,
    touched,
):
    """The voxel pass over all rays, on every core; returns the rays left to the fallback.

    ``planes`` threads (at most the miss planes ``bits`` has); thread t takes chunks t, t + T,
    t + 2T ... of 256 rays and sets miss bits in its own words 8 + 8t .. 15 + 8t of each block:
    plain ORs, no atomics, no lost bits.
    """
    n = ends.shape[0]
    chunk = 256
    n_chunks = (n + chunk - 1) // chunk
    deferred = np.zeros(n, dtype=np.bool_)
    ox, oy, oz = origin[0], origin[1], origin[2]
    for t in nb.prange(planes):
        plane = 8 + 8 * t
        for c in range(t, n_chunks, planes):
            for i in range(c * chunk, min(n, (c + 1) * chunk)):
                if kind[i] & 2:
                    deferred[i] = not _cast(
                        ox,
                        oy,
                        oz,
                        ends[i, 0],
                        ends[i, 1],
                        ends[i, 2],
                        resolution,
                        False,
                        plane,
                        dense,
                        box,
                        bits,
                        block_xyz,
                        stamp,
                        table_keys,
                        table_slots,
                        counts,
                        touched,
                    )
    return np.flatnonzero(deferred)


@nb.njit(**_JIT)
def cast_serial(
    origin,
    ends,
    rays,
    start,
    resolution,
    dense,
    box,
    bits,
    block_xyz,
    stamp,
    table_keys,
    table_slots,
    counts,
    touched,
):
    """The voxel pass for ``rays`` (indices), adding blocks as needed; resumable."""
    res_factor = 1.0 / resolution
    ox, oy, oz = origin[0], origin[1], origin[2]
    for j in range(start, rays.shape[0]):
        i = rays[j]
        span = 4
        for a in range(3):
            span += abs(
                coord_to_key(np.float64(ends[i, a]), res_factor)
                - coord_to_key(np.float64(origin[a]), res_factor)
            )
        status = _room(span, counts, block_xyz, touched, table_keys)
        if status != DONE:
            return j, status
        _cast(
            ox,
            oy,
            oz,
            ends[i, 0],
            ends[i, 1],
            ends[i, 2],
            resolution,
            True,
            8,
            dense,
            box,
            bits,
            block_xyz,
            stamp,
            table_keys,
            table_slots,
            counts,
            touched,
        )
    return rays.shape[0], DONE


@nb.njit(parallel=True, **_JIT)
def apply_blocks(values, bits, touched, n_touched, model, all_hits):
    """OctoMap's updateNodeLogOdds once per marked voxel of the touched blocks (a hit where the
    hit bit is set, else a miss where any thread's miss bit is set; with ``all_hits``, as for
    end points only, every marked voxel is a hit), then clear the bits.
    Blocks are disjoint, so they go to the cores in parallel. Returns (hits, misses)."""
    lo_hit, lo_miss, cmin, cmax = model[0], model[1], model[2], model[3]
    hits = 0
    misses = 0
    for j in nb.prange(n_touched):
        cs = touched[j]
        for w in range(8):
            hit_word = bits[cs, w]
            any_word = hit_word
            for p in range(8 + w, bits.shape[1], 8):
                any_word |= bits[cs, p]
                bits[cs, p] = 0
            bits[cs, w] = 0
            if any_word == 0:
                continue
            if all_hits:
                hit_word = any_word
            rest = any_word
            while rest:  # each set bit, lowest first: cost follows the marks, not 64 per word
                bit = rest & (~rest + np.uint64(1))
                rest ^= bit
                b = _DEBRUIJN[(bit * _DEBRUIJN_MUL) >> np.uint64(58)]
                local = w * 64 + b
                v = values[cs, local]
                if math.isnan(v):
                    v = np.float32(0.0)  # a new OcTreeNode starts at log-odds 0
                if hit_word & bit:
                    v = np.float32(v + lo_hit)
                    hits += 1
                else:
                    v = np.float32(v + lo_miss)
                    misses += 1
                values[cs, local] = cmin if v < cmin else (cmax if v > cmax else v)
    return hits, misses


# --- the sparse store ----------------------------------------------------------------------------
#
# End points spread thinly (a few voxels per 8 x 8 x 8 block) would cost a 2 KB block per few
# voxels. insert_endpoints keeps such blocks in a voxel-level open-addressing hash instead:
#
# - the voxel table ``vt``: int64 entries (hits << 48) | (kx << 32) | (ky << 16) | kz, 0 = empty.
#   Only end points ever reach it, so a voxel's log-odds is a function of how many calls hit it:
#   ``lut[hits]``, hits saturating where the value stops changing (clamp_max);
# - the block table ``st``: int64 entries (voxels << 40) | block id, 0 = empty: how many voxels of
#   each such block the voxel table holds (known at once when the block turns dense).
#
# Both have a power-of-two capacity split into NREG regions of equal size; a block's region is the
# top bits of _fib(block id), and its voxels' entries and its count live in that region of each
# table (linear probing wraps within the region). ``sparse_counts[r]`` = (voxels, blocks) in
# region r. A block with DENSE_MIN voxels or more moves to the dense store (adopt_sparse).
#
# insert_endpoints sorts its points into NPART partitions (the top PART_BITS of the region: few
# enough write streams for one scattering pass), and the kernels take a partition per core:
# no two threads write one region, the layout does not depend on the number of threads, and the
# voxels of a partition are handled region by region, each region (512 KB of a 128 MB table) in
# cache.

NREG_BITS = 8
NREG = 1 << NREG_BITS
PART_BITS = 6
NPART = 1 << PART_BITS
HITS_SHIFT = 48
KEY_MASK = np.int64((1 << 48) - 1)
COUNT_SHIFT = 40
BLOCK_MASK = np.int64((1 << 39) - 1)
# Flags on the first voxel key of a block's run in group_new_points' output: the block goes to
# the dense store (the sign bit); the sparse store holds voxels of it to hand over; its hits are
# already in the sparse store (a block promoted after its hits: no bits to set).
DENSE_RUN = np.int64(-(1 << 63))
ADOPT_RUN = np.int64(1 << 62)
NO_BITS = np.int64(1 << 61)
# A block left for upsert_sparse with more than 9 voxels is written as a record, RECORD | its
# block id and then its 8 mask words, instead of its voxel keys.
RECORD = np.int64(1 << 60)
# count_points' classes of points that are not inserted (-1 - their column of its counts).
OUTSIDE = -(NPART + 2)
NONFINITE = -(NPART + 3)
#: Largest share of a region of the sparse store's tables in use (linear probing stays short).
SPARSE_LOAD = 0.7
#: Points per sub-bucket that group_new_points aims at: its hash and masks then fit in cache.
SUB_POINTS = 4096
#: Points per chunk of the partition histogram (fixed, so the partition is the same on any core
#: count).
CHUNK = 1 << 16


@nb.njit(**_JIT)
def _fib(x):
    """Fibonacci hashing (Knuth): x times 2**64 / golden ratio; its top bits are well spread,
    also for keys on a lattice, and it costs one multiplication (it runs for every point)."""
    return np.uint64(x) * np.uint64(0x9E3779B97F4A7C15)


@nb.njit(**_JIT)
def _region(bk):
    """Region of block ``bk``: the top NREG_BITS of _fib(bk)."""
    return np.int64(_fib(bk) >> np.uint64(64 - NREG_BITS))


@nb.njit(**_JIT)
def _home(k, skip, mask):
    """Slot of ``k`` within a region of ``mask + 1`` slots: the bits of _fib(k) below its top
    ``skip`` (block ids skip the bits that chose their region)."""
    return np.int64(_fib(k) >> np.uint64(40 - skip)) & mask


@nb.njit(**_JIT)
def voxel_key(kx, ky, kz):
    return (np.int64(kx) << 32) | (np.int64(ky) << 16) | np.int64(kz)


@nb.njit(**_JIT)
def key_block(key):
    """Block id of a voxel key (flags masked off)."""
    return block_id((key >> 35) & 8191, (key >> 19) & 8191, (key >> 3) & 8191)


@nb.njit(**_JIT)
def key_local(key):
    """Voxel index of a voxel key within its block."""
    return ((key >> 32) & 7) | (((key >> 16) & 7) << 3) | ((key & 7) << 6)


@nb.njit(**_JIT)
def _block_voxel_key(bk, local):
    kx = ((bk >> 26) << 3) | (local & 7)
    ky = (((bk >> 13) & 8191) << 3) | ((local >> 3) & 7)
    kz = ((bk & 8191) << 3) | (local >> 6)
    return voxel_key(kx, ky, kz)


@nb.njit(inline="always", **_JIT)
def _probe(table, k, kmask, r):
    """Index of the entry of region ``r`` whose bits ``kmask`` are ``k``, or of the empty slot
    where it would go (voxel keys: ``kmask`` KEY_MASK, block ids: BLOCK_MASK)."""
    size = table.shape[0] >> NREG_BITS
    mask = size - 1
    base = r * size
    i = _home(k, 0 if kmask == KEY_MASK else NREG_BITS, mask)
    while True:
        e = table[base + i]
        if e == 0 or (e & kmask) == k:
            return base + i
        i = (i + 1) & mask


@nb.njit(inline="always", **_JIT)
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
        h = _home(e & kmask, skip, mask)
        # e stays unless the hole i lies on its probe path from h to j (cyclically)
        if (i <= j and (h <= i or h > j)) or (i > j and h <= i and h > j):
            table[base + i] = e
            i = j
    table[base + i] = 0


@nb.njit(**_JIT)
def _popcount(x):
    x = x - ((x >> np.uint64(1)) & np.uint64(0x5555555555555555))
    x = (x & np.uint64(0x3333333333333333)) + ((x >> np.uint64(2)) & np.uint64(0x3333333333333333))
    x = (x + (x >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return np.int64((x * np.uint64(0x0101010101010101)) >> np.uint64(56))


@nb.njit(parallel=True, **_JIT)
def sparse_rehash(table, kmask, out):
    """Copy a sparse-store table into ``out`` (zeros, a larger power of two); entries keep their
    region, so the regions are rehashed on every core."""
    size = table.shape[0] >> NREG_BITS
    for r in nb.prange(NREG):
        for i in range(r * size, (r + 1) * size):
            e = table[i]
            if e != 0:
                out[_probe(out, e & kmask, kmask, r)] = e


@nb.njit(**_JIT)
def _adopt_block(cs, bx, by, bz, values, vt, st, sparse_counts, lut):
    """Move the sparse store's voxels of block (bx, by, bz) into dense block ``cs`` (values
    already NaN), if it has any."""
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
        at = _probe(vt, _block_voxel_key(bk, local), KEY_MASK, r)
        e = vt[at]
        if e != 0:
            values[cs, local] = lut[e >> HITS_SHIFT]
            _remove(vt, at, KEY_MASK)
            left -= 1


@nb.njit(**_JIT)
def adopt_sparse(slots, values, block_xyz, vt, st, sparse_counts, lut):
    """Dense blocks ``slots`` (values already NaN) take over their voxels from the sparse store."""
    for j in range(slots.shape[0]):
        cs = slots[j]
        bx, by, bz = block_xyz[cs, 0], block_xyz[cs, 1], block_xyz[cs, 2]
        _adopt_block(cs, bx, by, bz, values, vt, st, sparse_counts, lut)


@nb.njit(**_JIT)
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


# --- end points only -----------------------------------------------------------------------------


@nb.njit(parallel=True, **_JIT)
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


@nb.njit(parallel=True, **_JIT)
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


@nb.njit(**_JIT)
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


@nb.njit(parallel=True, **_JIT)
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


@nb.njit(**_JIT)
def _group_blocks(keys, start, b, tkeys, tidx, tpos, tbk, masks, nt):
    """Add the blocks of voxel keys ``keys[start:b]`` in order of first appearance (``tbk``, ``nt``
    so far) and each one's mask of voxels hit, through the hash ``tkeys`` (block id, -1 empty;
    homes from bits of _fib below those that chose the partition and sub-bucket) -> ``tidx``;
    ``tpos``: each block's slot, to empty the hash afterwards. Returns (index reached, blocks):
    it stops before a block that would fill the hash over half (grow the arrays and call again;
    they are not grown here, as numba would count references to arrays reassigned in a loop at
    every point)."""
    cap = tkeys.shape[0]
    last_bk, t = np.int64(-1), np.int64(-1)
    for i in range(start, b):
        key = keys[i]
        bk = key_block(key)
        if bk != last_bk:
            h = _home(bk, 16, cap - 1)
            while tkeys[h] != -1 and tkeys[h] != bk:
                h = (h + 1) & (cap - 1)
            if tkeys[h] == -1:
                if 2 * (nt + 1) > cap:
                    return i, nt
                tkeys[h] = bk
                tidx[h] = nt
                tpos[nt] = h
                tbk[nt] = bk
                masks[nt, :] = 0
                nt += 1
            last_bk, t = bk, tidx[h]
        local = key_local(key)
        masks[t, local >> 6] |= np.uint64(1) << np.uint64(local & 63)
    return b, nt


@nb.njit(inline="always", **_JIT)
def _hit_voxel(vt, key, r, max_hits):
    """One hit for voxel ``key`` (region ``r``) in the voxel table; 1 if it is new there."""
    at = _probe(vt, key, KEY_MASK, r)
    e = vt[at]
    if e == 0:
        vt[at] = (np.int64(1) << HITS_SHIFT) | key
        return 1
    if (e >> HITS_SHIFT) < max_hits:
        vt[at] = e + (np.int64(1) << HITS_SHIFT)
    return 0


@nb.njit(inline="always", **_JIT)
def _add_sparse(st, bk, r, held, new, sparse_counts):
    """Count ``new`` voxels of block ``bk`` (which had ``held``) in the block table."""
    if new == 0:
        return
    at = _probe(st, bk, BLOCK_MASK, r)
    if held == 0:
        st[at] = bk
        sparse_counts[r, 1] += 1
    st[at] += new << COUNT_SHIFT
    sparse_counts[r, 0] += new


@nb.njit(**_JIT)
def _place_blocks(
    keys, w, dbuf, dw, tbk, masks, nt, vt, st, sparse_counts, dense_min, max_hits, out
):
    """The ``nt`` blocks of :func:`_group_blocks`, region by region (in order of first appearance
    within one); see :func:`group_new_points`. Writes the runs going dense from ``keys[w]`` on
    and the blocks left for want of room from ``dbuf[dw]`` on; returns the indices after
    them."""
    sub = 1 << (NREG_BITS - PART_BITS)
    first = np.zeros(sub + 1, dtype=np.int64)  # a counting sort of the blocks by region
    region = np.empty(nt, dtype=np.int64)
    for u in range(nt):
        region[u] = _region(tbk[u])
        first[(region[u] & (sub - 1)) + 1] += 1
    for j in range(sub):
        first[j + 1] += first[j]
    order = np.empty(nt, dtype=np.int64)
    for u in range(nt):
        j = region[u] & (sub - 1)
        order[first[j]] = u
        first[j] += 1
    room_v = np.int64(SPARSE_LOAD * (vt.shape[0] >> NREG_BITS))
    room_s = np.int64(SPARSE_LOAD * (st.shape[0] >> NREG_BITS))
    for v in range(nt):
        u = order[v]
        bk, r = tbk[u], region[u]
        d = np.int64(0)
        for word in range(8):
            d += _popcount(masks[u, word])
        held = np.int64(0)
        at = _probe(st, bk, BLOCK_MASK, r)
        if st[at] != 0:
            held = st[at] >> COUNT_SHIFT
        flags = np.int64(0)
        if d >= dense_min:
            flags = DENSE_RUN | (ADOPT_RUN if held > 0 else np.int64(0))
            out[r, 2] += 1
        elif sparse_counts[r, 0] + d <= room_v and sparse_counts[r, 1] + 1 <= room_s:
            new = np.int64(0)
            for word in range(8):
                rest = masks[u, word]
                while rest:
                    bit = rest & (~rest + np.uint64(1))
                    rest ^= bit
                    local = word * 64 + _DEBRUIJN[(bit * _DEBRUIJN_MUL) >> np.uint64(58)]
                    new += _hit_voxel(vt, _block_voxel_key(bk, local), r, max_hits)
            _add_sparse(st, bk, r, held, new, sparse_counts)
            out[r, 3] += d
            if held + new >= dense_min:  # promoted: one key stands for the block
                keys[w] = _block_voxel_key(bk, 0) | DENSE_RUN | ADOPT_RUN | NO_BITS
                w += 1
                out[r, 2] += 1
            continue
        else:  # no room in the tables: left to upsert_sparse once they have grown
            out[r, 0] += d
            out[r, 1] += 1
            if d > 9:  # then the block had more than 9 points: there is room for a record
                dbuf[dw] = RECORD | bk
                for word in range(8):
                    dbuf[dw + 1 + word] = np.int64(masks[u, word])
                dw += 9
            else:
                dw = _write_block(dbuf, dw, bk, masks, u, np.int64(0))
            continue
        w = _write_block(keys, w, bk, masks, u, flags)
    return w, dw


@nb.njit(inline="always", **_JIT)
def _write_block(keys, w, bk, masks, u, flags):
    """The voxel keys of block ``bk`` (``masks[u]``) from ``keys[w]`` on, by index in the block,
    the first one with ``flags``; returns the index after the last."""
    for word in range(8):
        rest = masks[u, word]
        while rest:
            bit = rest & (~rest + np.uint64(1))
            rest ^= bit
            local = word * 64 + _DEBRUIJN[(bit * _DEBRUIJN_MUL) >> np.uint64(58)]
            keys[w] = _block_voxel_key(bk, local) | flags
            flags = 0
            w += 1
    return w


@nb.njit(inline="always", **_JIT)
def _item(keys, i, end):
    """The block of the item at ``keys[i]`` of group_new_points' output and the index after
    the item: a record (RECORD | block id, then 8 mask words) or a run of a block's voxel keys
    (flags on the first only)."""
    first = keys[i]
    if first & RECORD:
        return first & BLOCK_MASK, i + 9
    bk = key_block(first)
    j = i + 1
    while j < end and keys[j] >> HITS_SHIFT == 0 and key_block(keys[j]) == bk:
        j += 1
    return bk, j


@nb.njit(parallel=True, **_JIT)
def group_new_points(keys, seg, vt, st, sparse_counts, dense_min, max_hits, threads):
    """Partition by partition, on every core: each distinct voxel of the points' voxel keys
    (partition p's in ``keys[seg[p]:seg[p + 1]]``) once, block by block (blocks by region, then
    in order of first appearance). A block with ``dense_min`` voxels in this call goes to the
    dense store: its voxel keys are written over the points, the first one flagged DENSE_RUN (and
    ADOPT_RUN if the sparse store holds voxels of it). Each voxel of any other block takes a hit
    in the sparse store, if its region has room; a block reaching ``dense_min`` voxels there is
    promoted (one key flagged DENSE_RUN, ADOPT_RUN and NO_BITS). Blocks in a region without room
    are written unflagged after those (as voxel keys or a RECORD), for :func:`upsert_sparse`.
    Returns, per partition, the
    keys written (NPART, 2: the runs going dense, all) and per region (NREG, 4): voxels and
    blocks left for upsert_sparse (at most new to the tables), runs going dense, voxels hit.
    Thread t of ``threads`` takes partitions t, t + threads, ... with its own scratch arrays."""
    written = np.zeros((NPART, 2), dtype=np.int64)
    out = np.zeros((NREG, 4), dtype=np.int64)
    for t in nb.prange(threads):
        _group_partitions(
            t, threads, keys, seg, vt, st, sparse_counts, dense_min, max_hits, written, out
        )
    return written, out


@nb.njit(**_JIT)
def _sub_bucket(key, bits):
    """Sub-bucket of a voxel key within its partition: the ``bits`` of _fib(its block) below
    the partition's (so sub-buckets nest in regions)."""
    return np.int64((_fib(key_block(key)) << np.uint64(PART_BITS)) >> np.uint64(64 - bits))


@nb.njit(**_JIT)
def _group_partitions(
    t, threads, keys, seg, vt, st, sparse_counts, dense_min, max_hits, written, out
):
    """Thread t's part of :func:`group_new_points`: partitions t, t + threads, ... A partition
    with more than SUB_POINTS blocks is split into sub-buckets of about SUB_POINTS points (by
    block), so the grouping hash and masks stay in cache however few points each block has. A
    function of its own: numba's parallel loops mishandle arrays rebound in their body, as
    these grow."""
    cap = 2 * SUB_POINTS
    tkeys = np.full(cap, -1, dtype=np.int64)
    tidx = np.empty(cap, dtype=np.int64)
    tpos = np.empty(cap // 2, dtype=np.int64)
    tbk = np.empty(cap // 2, dtype=np.int64)
    masks = np.empty((cap // 2, 8), dtype=np.uint64)
    sbuf = np.empty(0, dtype=np.int64)  # the partition's keys by sub-bucket
    dbuf = np.empty(0, dtype=np.int64)  # blocks left for want of room
    for p in range(t, NPART, threads):
        a, b = seg[p], seg[p + 1]
        n = b - a
        if dbuf.shape[0] < n:
            sbuf = np.empty(n, dtype=np.int64)
            dbuf = np.empty(n, dtype=np.int64)
        # Written over the partition's keys (read by then), never more of them than points.
        w, dw = a, 0
        i, nt = _group_blocks(keys, a, b, tkeys, tidx, tpos, tbk, masks, 0)
        if i == b:  # the usual case: the partition's blocks fit the hash
            w, dw = _place_blocks(
                keys, w, dbuf, dw, tbk, masks, nt, vt, st, sparse_counts, dense_min, max_hits, out
            )
        for u in range(nt):
            tkeys[tpos[u]] = -1
        if i < b:  # many blocks: again, sub-bucket by sub-bucket (a counting sort into sbuf)
            bits = 1
            while (n >> bits) > SUB_POINTS and bits < 12:
                bits += 1
            starts = np.zeros((1 << bits) + 1, dtype=np.int64)
            for i in range(a, b):
                starts[_sub_bucket(keys[i], bits) + 1] += 1
            for j in range(1 << bits):
                starts[j + 1] += starts[j]
            at = starts[:-1].copy()
            for i in range(a, b):
                j = _sub_bucket(keys[i], bits)
                sbuf[at[j]] = keys[i]
                at[j] += 1
            for j in range(1 << bits):
                i, nt = starts[j], 0
                while True:
                    i, nt = _group_blocks(sbuf, i, starts[j + 1], tkeys, tidx, tpos, tbk, masks, nt)
                    if i == starts[j + 1]:
                        break
                    cap *= 4  # still over half full (a sub-bucket of few, busy blocks): grow
                    tkeys = np.full(cap, -1, dtype=np.int64)
                    tidx = np.empty(cap, dtype=np.int64)
                    tpos = np.empty(cap // 2, dtype=np.int64)
                    grown_bk = np.empty(cap // 2, dtype=np.int64)
                    grown_bk[:nt] = tbk[:nt]
                    tbk = grown_bk
                    grown = np.empty((cap // 2, 8), dtype=np.uint64)
                    grown[:nt] = masks[:nt]
                    masks = grown
                    for u in range(nt):
                        h = _home(tbk[u], 16, cap - 1)
                        while tkeys[h] != -1:
                            h = (h + 1) & (cap - 1)
                        tkeys[h] = tbk[u]
                        tidx[h] = u
                        tpos[u] = h
                w, dw = _place_blocks(
                    keys,
                    w,
                    dbuf,
                    dw,
                    tbk,
                    masks,
                    nt,
                    vt,
                    st,
                    sparse_counts,
                    dense_min,
                    max_hits,
                    out,
                )
                for u in range(nt):
                    tkeys[tpos[u]] = -1
        keys[w : w + dw] = dbuf[:dw]
        written[p, 0] = w - a
        written[p, 1] = w + dw - a


@nb.njit(parallel=True, **_JIT)
def upsert_sparse(keys, seg, written, vt, st, sparse_counts, dense_min, max_hits):
    """Partition by partition, on every core: one hit in the sparse store for each voxel of the
    blocks :func:`group_new_points` left for want of room (the tables must have room now); a
    block reaching ``dense_min`` voxels is promoted (its first word flagged DENSE_RUN, ADOPT_RUN
    and NO_BITS). Returns, per partition, the voxels hit and the blocks promoted (NPART, 2)."""
    hits = np.zeros((NPART, 2), dtype=np.int64)
    for p in nb.prange(NPART):
        i = seg[p] + written[p, 0]
        end = seg[p] + written[p, 1]
        while i < end:
            bk, j = _item(keys, i, end)
            r = _region(bk)
            held = np.int64(0)
            at = _probe(st, bk, BLOCK_MASK, r)
            if st[at] != 0:
                held = st[at] >> COUNT_SHIFT
            new = np.int64(0)
            if keys[i] & RECORD:
                for word in range(8):
                    rest = np.uint64(keys[i + 1 + word])
                    while rest:
                        bit = rest & (~rest + np.uint64(1))
                        rest ^= bit
                        local = word * 64 + _DEBRUIJN[(bit * _DEBRUIJN_MUL) >> np.uint64(58)]
                        new += _hit_voxel(vt, _block_voxel_key(bk, local), r, max_hits)
                        hits[p, 0] += 1
            else:
                for m in range(i, j):
                    new += _hit_voxel(vt, keys[m], r, max_hits)
                hits[p, 0] += j - i
            _add_sparse(st, bk, r, held, new, sparse_counts)
            if held + new >= dense_min:
                keys[i] |= DENSE_RUN | ADOPT_RUN | NO_BITS
                hits[p, 1] += 1
            i = j
    return hits


@nb.njit(**_JIT)
def alloc_dense_runs(
    keys,
    seg,
    ends,
    start,
    adopt,
    n_adopt,
    bits,
    block_xyz,
    stamp,
    table_keys,
    table_slots,
    counts,
    touched,
):
    """Serial: a dense block for every DENSE_RUN of :func:`group_new_points` among partition p's
    first ``ends[p]`` keys (allocated, touched by this call), its voxels' hit bits set unless
    NO_BITS; those flagged ADOPT_RUN are listed in ``adopt`` (``n_adopt[0]`` of them) for
    :func:`adopt_sparse`. Resumable: returns (next key, status)."""
    for p in range(NPART):
        i = max(seg[p], start)
        end = seg[p] + ends[p]
        while i < end:
            first = keys[i]
            bk, j = _item(keys, i, end)
            if first < 0:
                status = _room(1, counts, block_xyz, touched, table_keys)
                if status != DONE:
                    return i, status
                cs = _slot(
                    bk,
                    bk >> 26,
                    (bk >> 13) & 8191,
                    bk & 8191,
                    block_xyz,
                    stamp,
                    table_keys,
                    table_slots,
                    counts,
                    touched,
                )
                if not first & NO_BITS:
                    for m in range(i, j):
                        local = key_local(keys[m])
                        bits[cs, local >> 6] |= np.uint64(1) << np.uint64(local & 63)
                if first & ADOPT_RUN:
                    adopt[n_adopt[0]] = cs
                    n_adopt[0] += 1
            i = j
    return keys.shape[0], DONE


@nb.njit(**_JIT)
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
            out[i] = values[slot, (kx & 7) | ((ky & 7) << 3) | ((kz & 7) << 6)]
        else:
            e = vt[_probe(vt, voxel_key(kx, ky, kz), KEY_MASK, _region(bk))]
            if e != 0:
                out[i] = lut[e >> HITS_SHIFT]
    return out


@nb.njit(**_JIT)
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
            values[slot, :] = np.nan
            _adopt_block(slot, bx, by, bz, values, vt, st, sparse_counts, lut)
        values[slot, (kx & 7) | ((ky & 7) << 3) | ((kz & 7) << 6)] = logodds[i]


class Kernels(NamedTuple):
    """The kernels that run on every core, as one set: :data:`PARALLEL`, or :data:`SERIAL` (the
    same code compiled without threads) for small scans, where waking the threads costs more
    than the work, and much more when other processes hold the cores."""

    flag_blocks: Any
    cast_parallel: Any
    apply_blocks: Any
    count_points: Any
    place_points: Any
    mark_point_bits: Any
    group_new_points: Any
    upsert_sparse: Any
    sparse_rehash: Any


def _serial(dispatcher: Any) -> Any:
    """``dispatcher``'s Python function compiled without ``parallel`` (prange runs as range).
    A copy under its own name, so numba's on-disk cache keeps the two versions apart."""
    f = dispatcher.py_func
    g = types.FunctionType(f.__code__, f.__globals__, f.__name__ + "_serial", f.__defaults__)
    g.__qualname__ = f.__qualname__ + "_serial"
    g.__doc__ = f.__doc__
    return nb.njit(**_JIT)(g)


PARALLEL = Kernels(
    flag_blocks,
    cast_parallel,
    apply_blocks,
    count_points,
    place_points,
    mark_point_bits,
    group_new_points,
    upsert_sparse,
    sparse_rehash,
)
SERIAL = Kernels(*(_serial(k) for k in PARALLEL))
