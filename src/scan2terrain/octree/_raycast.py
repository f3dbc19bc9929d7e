"""The dense store's ray casting (numba): OctoMap's insertPointCloud, one scan at a time.

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

import numpy as np

from scan2terrain._numba import numba as nb
from scan2terrain.octree._table import (
    DEBRUIJN,
    DEBRUIJN_MUL,
    DONE,
    JIT,
    TREE_MAX_VAL,
    _room,
    _slot,
    block_id,
    coord_to_key,
    stored,
)


@nb.njit(**JIT)
def _axis_start(k, s, o, d, resolution):
    """tMax and tDelta of one axis, as computeRayKeys computes them (double from float)."""
    if s == 0:
        big = 1.7976931348623157e308
        return big, big
    border = (np.float64(k - TREE_MAX_VAL) + 0.5) * resolution
    border += np.float64(np.float32(s * resolution * 0.5))
    return (border - np.float64(o)) / np.float64(d), resolution / np.float64(abs(d))


@nb.njit(**JIT)
def _sign(d):
    return 1 if d > 0.0 else (-1 if d < 0.0 else 0)


@nb.njit(inline="always", **JIT)
def ray_start(ox, oy, oz, ex, ey, ez, resolution):
    """computeRayKeys' set-up from o to e (float32): the keys of o and of e, the step of each
    axis, its tMax and tDelta, and the ray's length (float32). Shared by the two casts (dense
    store, box of bits); inlined, so a ray costs no call."""
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
    return kx, ky, kz, ekx, eky, ekz, sx, sy, sz, tx, ty, tz, ddx, ddy, ddz, length


@nb.njit(inline="always", **JIT)
def dda_step(kx, ky, kz, tx, ty, tz, sx, sy, sz, ddx, ddy, ddz):
    """One step of the DDA along the axis of the minimum tMax, ties going to the later axis,
    exactly as computeRayKeys (for voxels, and for blocks in flag_blocks)."""
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
    return kx, ky, kz, tx, ty, tz


@nb.njit(**JIT)
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


@nb.njit(**JIT)
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


@nb.njit(parallel=True, **JIT)
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
            bx, by, bz, tx, ty, tz = dda_step(bx, by, bz, tx, ty, tz, sx, sy, sz, ddx, ddy, ddz)


@nb.njit(**JIT)
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


@nb.njit(**JIT)
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


@nb.njit(**JIT)
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
    start = ray_start(ox, oy, oz, ex, ey, ez, resolution)
    kx, ky, kz, ekx, eky, ekz, sx, sy, sz, tx, ty, tz, ddx, ddy, ddz, length = start
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
        kx, ky, kz, tx, ty, tz = dda_step(kx, ky, kz, tx, ty, tz, sx, sy, sz, ddx, ddy, ddz)
        if kx == ekx and ky == eky and kz == ekz:
            return True
        if min(min(tx, ty), tz) > length:  # noqa: PLW3301 (computeRayKeys' own form)
            return True


@nb.njit(parallel=True, **JIT)
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


@nb.njit(**JIT)
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


@nb.njit(inline="always", **JIT)
def update_word(values, cs, w, hit_word, any_word, model):
    """OctoMap's updateNodeLogOdds once per voxel of word ``w`` of block ``cs`` marked in
    ``any_word``: a hit where ``hit_word`` has its bit, else a miss. Returns (hits, misses).
    Shared by the dense store's bits (``apply_blocks``) and a scan's box (_raybox.apply_box)."""
    lo_hit, lo_miss, cmin, cmax = model[0], model[1], model[2], model[3]
    hits = 0
    misses = 0
    rest = any_word
    while rest:  # each set bit, lowest first: cost follows the marks, not 64 per word
        bit = rest & (~rest + np.uint64(1))
        rest ^= bit
        i = DEBRUIJN[(bit * DEBRUIJN_MUL) >> np.uint64(58)]
        # Unknown is +0.0 (_table.known): a new OcTreeNode starts at log-odds 0 anyway.
        v = values[w, cs, i]
        if hit_word & bit:
            v = np.float32(v + lo_hit)
            hits += 1
        else:
            v = np.float32(v + lo_miss)
            misses += 1
        values[w, cs, i] = stored(cmin if v < cmin else (cmax if v > cmax else v))
    return hits, misses


@nb.njit(parallel=True, **JIT)
def apply_blocks(values, bits, touched, n_touched, model, all_hits):
    """OctoMap's updateNodeLogOdds once per marked voxel of the touched blocks (a hit where the
    hit bit is set, else a miss where any thread's miss bit is set; with ``all_hits``, as for
    end points only, every marked voxel is a hit), then clear the bits.
    Blocks are disjoint, so they go to the cores in parallel. Returns (hits, misses)."""
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
            h, m = update_word(values, cs, w, any_word if all_hits else hit_word, any_word, model)
            hits += h
            misses += m
    return hits, misses
