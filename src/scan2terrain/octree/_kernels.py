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


@nb.njit(parallel=True, **_JIT)
def point_blocks(points, resolution):
    """Block id (-1 outside the key range) and voxel index within its block of every point,
    computed on every core."""
    res_factor = 1.0 / resolution
    n = points.shape[0]
    bk = np.empty(n, dtype=np.int64)
    local = np.empty(n, dtype=np.int16)
    for i in nb.prange(n):
        kx = coord_to_key(np.float64(points[i, 0]), res_factor)
        ky = coord_to_key(np.float64(points[i, 1]), res_factor)
        kz = coord_to_key(np.float64(points[i, 2]), res_factor)
        if kx < 0 or ky < 0 or kz < 0:
            bk[i] = -1
            local[i] = 0
        else:
            bk[i] = block_id(kx >> 3, ky >> 3, kz >> 3)
            local[i] = (kx & 7) | ((ky & 7) << 3) | ((kz & 7) << 6)
    return bk, local


@nb.njit(parallel=True, **_JIT)
def find_point_slots(bk, table_keys, table_slots):
    """End points only, first pass, on every core (the table is only read): the slot of each
    point's block, -1 if the block is not allocated yet, -2 for a point outside the key range.
    The hash probe is written out: a call per point costs more than the probe."""
    n = bk.shape[0]
    slots = np.empty(n, dtype=np.int32)
    mask = np.int64(table_keys.shape[0] - 1)
    chunk = 4096
    for c in nb.prange((n + chunk - 1) // chunk):
        ck, cs = np.int64(-3), np.int32(-1)
        for i in range(c * chunk, min(n, (c + 1) * chunk)):
            k = bk[i]
            if k < 0:
                slots[i] = -2
                continue
            if k != ck:
                ck = k
                h = _hash(k, mask)
                cs = np.int32(-1)
                while True:
                    tk = table_keys[h]
                    if tk == k:
                        cs = table_slots[h]
                        break
                    if tk == EMPTY:
                        break
                    h = (h + 1) & mask
            slots[i] = cs
    return slots


@nb.njit(**_JIT)
def settle_points(
    bk, slots, start, bits, block_xyz, stamp, table_keys, table_slots, counts, touched, stats
):
    """End points only, second pass (serial): allocate the blocks :func:`find_point_slots` did
    not find, fill in their slots, and record every block as touched by this call; resumable.
    stats += [points inserted, 0, points outside the key range]."""
    scan = counts[STAMP]
    ck, cs = np.int64(-3), np.int64(-1)
    n = bk.shape[0]
    for i in range(start, n):
        s = slots[i]
        if s == -2:
            stats[2] += 1
            continue
        k = bk[i]
        if k != ck:
            if s < 0:  # perhaps allocated by an earlier point of this pass: probe, inline
                mask = np.int64(table_keys.shape[0] - 1)
                h = _hash(k, mask)
                while True:
                    tk = table_keys[h]
                    if tk == k:
                        s = table_slots[h]
                        break
                    if tk == EMPTY:
                        break
                    h = (h + 1) & mask
            if s < 0 or stamp[s] != scan:
                status = _room(1, counts, block_xyz, touched, table_keys)
                if status != DONE:
                    return i, status
                s = _slot(
                    k,
                    k >> 26,
                    (k >> 13) & 8191,
                    k & 8191,
                    block_xyz,
                    stamp,
                    table_keys,
                    table_slots,
                    counts,
                    touched,
                )
            ck, cs = k, s
        slots[i] = cs
        stats[0] += 1
    return n, DONE


@nb.njit(parallel=True, **_JIT)
def mark_point_bits(slots, local, planes, bits):
    """End points only, third pass, on every core: thread t sets each of its points' bits in
    its own words 8 + 8t .. 15 + 8t (chunks t, t + T, ...), so no bit is lost to a race;
    :func:`apply_blocks` with ``all_hits`` reads every plane as hits."""
    n = slots.shape[0]
    chunk = 4096
    n_chunks = (n + chunk - 1) // chunk
    for t in nb.prange(planes):
        plane = 8 + 8 * t
        for c in range(t, n_chunks, planes):
            for i in range(c * chunk, min(n, (c + 1) * chunk)):
                cs = slots[i]
                if cs >= 0:
                    loc = local[i]
                    bits[cs, plane + (loc >> 6)] |= np.uint64(1) << np.uint64(loc & 63)


@nb.njit(**_JIT)
def lookup(keys, values, table_keys, table_slots):
    """Log-odds of voxel keys (int64 (N, 3)); NaN where unknown."""
    n = keys.shape[0]
    out = np.full(n, np.nan, dtype=np.float32)
    for i in range(n):
        kx, ky, kz = keys[i, 0], keys[i, 1], keys[i, 2]
        if kx < 0 or ky < 0 or kz < 0 or kx >= KEY_LIMIT or ky >= KEY_LIMIT or kz >= KEY_LIMIT:
            continue
        slot = table_find(table_keys, table_slots, block_id(kx >> 3, ky >> 3, kz >> 3))
        if slot >= 0:
            out[i] = values[slot, (kx & 7) | ((ky & 7) << 3) | ((kz & 7) << 6)]
    return out


@nb.njit(**_JIT)
def set_values(keys, logodds, values, block_xyz, table_keys, table_slots, counts):
    """Write log-odds at voxel keys (int64 (N, 3)), creating blocks; arrays must have room."""
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
        values[slot, (kx & 7) | ((ky & 7) << 3) | ((kz & 7) << 6)] = logodds[i]


class Kernels(NamedTuple):
    """The kernels that run on every core, as one set: :data:`PARALLEL`, or :data:`SERIAL` (the
    same code compiled without threads) for small scans, where waking the threads costs more
    than the work, and much more when other processes hold the cores."""

    flag_blocks: Any
    cast_parallel: Any
    apply_blocks: Any
    point_blocks: Any
    find_point_slots: Any
    mark_point_bits: Any


def _serial(dispatcher: Any) -> Any:
    """``dispatcher``'s Python function compiled without ``parallel`` (prange runs as range).
    A copy under its own name, so numba's on-disk cache keeps the two versions apart."""
    f = dispatcher.py_func
    g = types.FunctionType(f.__code__, f.__globals__, f.__name__ + "_serial", f.__defaults__)
    g.__qualname__ = f.__qualname__ + "_serial"
    g.__doc__ = f.__doc__
    return nb.njit(**_JIT)(g)


PARALLEL = Kernels(
    flag_blocks, cast_parallel, apply_blocks, point_blocks, find_point_slots, mark_point_bits
)
SERIAL = Kernels(*(_serial(k) for k in PARALLEL))
