"""Many small scans on every core (numba): insert_scans' parallel path, in waves.

A wave is a few consecutive scans (``SLOTS``, twice the threads). Their rays are cast at the
same time, each scan into a scratch of its own (``cast_wave``, every core): its blocks (a
small hash of block id -> row, valid for the scan that wrote it) and, per block, 8 hit words
and 8 miss words, occupied winning when applied; nothing of the tree is read or written. Then
the wave's scans are applied to the tree one after the other, in order (``apply_wave``,
serial): each block's slot found or allocated, one log-odds update per marked voxel. So each
voxel is updated at most once per scan, in the recording's order: the same values, bit for bit,
as _batch.py's serial path, with any number of threads (a scan's marks do not depend on which
thread cast it). A scan whose blocks overflow its scratch is cast the serial way instead.
"""

from __future__ import annotations

import numpy as np

from scan2terrain._numba import numba as nb
from scan2terrain.octree._batch import DENSE_WORD, _popcount, _update_all
from scan2terrain.octree._raycast import dda_step, ray_start, scan_rays, update_word
from scan2terrain.octree._table import (
    DONE,
    JIT,
    N_BLOCKS,
    NEED_BLOCKS,
    NEED_TABLE,
    block_id,
    coord_to_key,
    table_find,
    table_insert,
)

#: Blocks one scan may mark in its scratch (a 360-beam scan at 0.05 m marks a few hundred to a
#: few thousand); a scan needing more is cast the serial way. Scratches are zeroed memory, so
#: only the rows used take pages.
ROWS = 1 << 14
#: Entries of a scratch's block hash (a power of two, twice ROWS).
TABLE = ROWS * 2


@nb.njit(inline="always", **JIT)
def _row(tab, rows_key, rows_bits, n, bk, mark):
    """The scratch row of block ``bk`` for the scan stamped ``mark`` (added, its words zeroed,
    if new): returns (row, rows now used); -1 when the scratch is full."""
    mask = TABLE - 1
    h = np.int64((np.uint64(bk) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(20)) & mask
    while True:
        if tab[h, 2] != mark:  # free for this scan (0, or an earlier wave's entry: stale)
            if n >= ROWS:
                return -1, n
            tab[h, 0] = bk
            tab[h, 1] = n
            tab[h, 2] = mark
            rows_key[n] = bk
            rows_bits[n, :] = 0
            return n, n + 1
        if tab[h, 0] == bk:
            return tab[h, 1], n
        h = (h + 1) & mask


@nb.njit(**JIT)
def _cast_one(pts, origin, max_range, resolution, tab, rows_key, rows_bits, mark, stats):
    """One scan's hits and rays into its scratch; returns the rows used, or -1 if it overflowed.
    ``stats``: rays, beams cut, end points outside the key range."""
    ends, kind, rays = scan_rays(pts, origin, max_range, resolution)
    stats[0], stats[1], stats[2] = rays[0], rays[1], rays[2]
    res_factor = 1.0 / resolution
    n = 0
    for i in range(ends.shape[0]):
        if not kind[i] & 1:
            continue
        kx = coord_to_key(np.float64(ends[i, 0]), res_factor)
        ky = coord_to_key(np.float64(ends[i, 1]), res_factor)
        kz = coord_to_key(np.float64(ends[i, 2]), res_factor)
        r, n = _row(tab, rows_key, rows_bits, n, block_id(kx >> 3, ky >> 3, kz >> 3), mark)
        if r < 0:
            return -1
        local = (kx & 7) | ((ky & 7) << 3) | ((kz & 7) << 6)
        rows_bits[r, local >> 6] |= np.uint64(1) << np.uint64(local & 63)
    ox, oy, oz = origin[0], origin[1], origin[2]
    for i in range(ends.shape[0]):
        if not kind[i] & 2:
            continue
        ray = ray_start(ox, oy, oz, ends[i, 0], ends[i, 1], ends[i, 2], resolution)
        kx, ky, kz, ekx, eky, ekz, sx, sy, sz, tx, ty, tz, ddx, ddy, ddz, length = ray
        ck, r = np.int64(-1), -1
        while True:
            bk = block_id(kx >> 3, ky >> 3, kz >> 3)
            if bk != ck:
                ck = bk
                r, n = _row(tab, rows_key, rows_bits, n, bk, mark)
                if r < 0:
                    return -1
            local = (kx & 7) | ((ky & 7) << 3) | ((kz & 7) << 6)
            rows_bits[r, 8 + (local >> 6)] |= np.uint64(1) << np.uint64(local & 63)
            kx, ky, kz, tx, ty, tz = dda_step(kx, ky, kz, tx, ty, tz, sx, sy, sz, ddx, ddy, ddz)
            if kx == ekx and ky == eky and kz == ekz:
                break
            if min(min(tx, ty), tz) > length:  # noqa: PLW3301 (computeRayKeys' own form)
                break
    return n


@nb.njit(parallel=True, **JIT)
def cast_wave(points, offsets, origins, max_ranges, first, n, resolution, scratch, marks, out):
    """Scans ``first`` .. ``first + n - 1`` (n at most the scratches), scan first + j into
    scratch j on any thread: ``scratch`` = (tables (S, TABLE, 3) int64, row block ids (S,
    ROWS) int64, row words (S, ROWS, 16) uint64). ``marks[j]`` stamps scratch j's table
    entries (the caller makes it new each wave). ``out[j]``: rows used (-1: overflowed), rays,
    beams cut, end points outside the key range."""
    tabs, keys, words = scratch
    for j in nb.prange(n):
        s = first + j
        pts = points[offsets[s] : offsets[s + 1]]
        out[j, 0] = _cast_one(
            pts, origins[s], max_ranges[s], resolution, tabs[j], keys[j], words[j], marks[j],
            out[j, 1:],
        )  # fmt: skip


@nb.njit(**JIT)
def apply_wave(
    n, out, scratch, at, values, model, block_xyz, stamp, table_keys, table_slots, counts,
    stats,
):  # fmt: skip
    """The wave's scans applied in order from ``at`` = (scan, row), each row's block found or
    allocated, one update per marked voxel (hits winning). Stops at a scan that overflowed
    (``out[j, 0]`` -1: the caller casts it the serial way and goes on after it) or when the store
    is full; returns DONE, the NEED_* status, or -1 for an overflowed scan (``at`` says where).
    ``stats``: hits, misses added."""
    _, keys, words = scratch
    while at[0] < n:
        j = at[0]
        if out[j, 0] < 0:
            return -1
        for r in range(at[1], out[j, 0]):
            bk = keys[j, r]
            cs = table_find(table_keys, table_slots, bk)
            if cs < 0:
                if counts[N_BLOCKS] + 1 > block_xyz.shape[0]:
                    at[1] = r
                    return NEED_BLOCKS
                if 2 * (counts[N_BLOCKS] + 1) > table_keys.shape[0]:
                    at[1] = r
                    return NEED_TABLE
                cs = counts[N_BLOCKS]
                counts[N_BLOCKS] += 1
                block_xyz[cs, 0] = bk >> 26
                block_xyz[cs, 1] = (bk >> 13) & 8191
                block_xyz[cs, 2] = bk & 8191
                stamp[cs] = -1
                table_insert(table_keys, table_slots, bk, cs)
            for w in range(8):
                hit_word = words[j, r, w]
                any_word = hit_word | words[j, r, 8 + w]
                if any_word == 0:
                    continue
                hits = _popcount(hit_word)
                marked = _popcount(any_word)
                if marked >= DENSE_WORD:
                    _update_all(values, cs, w, hit_word, any_word, model)
                else:
                    update_word(values, cs, w, hit_word, any_word, model)
                stats[0] += hits
                stats[1] += marked - hits
        at[0] = j + 1
        at[1] = 0
    return DONE


@nb.njit(**JIT)
def insert_waves(
    points, offsets, origins, max_ranges, resolution, scratch, out, state, values, model,
    block_xyz, stamp, table_keys, table_slots, counts, stats,
):  # fmt: skip
    """Every scan in waves of ``out.shape[0]``, from where ``state`` = (first scan of the wave,
    phase: 0 cast it / 1 apply it, scan and row reached, the last wave's stamp) says, in one
    call (no Python, and no GIL, between waves). Returns DONE, a NEED_* status (grow, call
    again), or -1: scan ``state[0] + state[2]`` overflowed its scratch (the caller inserts it
    the serial way, moves state[2] past it, sets state[3] = 0 and calls again). ``stats``:
    rays, beams cut, end points outside the key range, hits, misses."""
    n_scans = offsets.shape[0] - 1
    slots = out.shape[0]
    marks = np.empty(slots, dtype=np.int64)
    at = np.empty(2, dtype=np.int64)
    hits = np.zeros(2, dtype=np.int64)
    while state[0] < n_scans:
        first = state[0]
        n = min(slots, n_scans - first)
        if state[1] == 0:
            state[4] += 1
            marks[:] = state[4]
            cast_wave(points, offsets, origins, max_ranges, first, n, resolution, scratch, marks,
                      out)  # fmt: skip
            state[1] = 1
            state[2] = 0
            state[3] = 0
        at[0], at[1] = state[2], state[3]
        hits[:] = 0
        status = apply_wave(
            n, out, scratch, at, values, model, block_xyz, stamp, table_keys, table_slots,
            counts, hits,
        )  # fmt: skip
        state[2], state[3] = at[0], at[1]
        stats[3] += hits[0]
        stats[4] += hits[1]
        if status != DONE:
            return status
        for j in range(n):
            if out[j, 0] >= 0:
                stats[0] += out[j, 1]
                stats[1] += out[j, 2]
                stats[2] += out[j, 3]
        state[0] = first + n
        state[1] = 0
    return DONE
