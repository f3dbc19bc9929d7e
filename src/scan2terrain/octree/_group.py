"""End points only (numba): the points outside the dense store, grouped by block into a store.

Each partition's distinct voxels (voxel keys from _points.place_points) are grouped by block on a
core of their own (``group_new_points``): a block with few voxels keeps them in the sparse store
(_sparse.py), one with DENSE_MIN voxels or more goes to the dense store (``alloc_dense_runs``;
the sparse store's voxels of it follow, _sparse.adopt_sparse). Blocks met while the sparse store's
tables are full wait for them to grow (``upsert_sparse``).
"""

from __future__ import annotations

import numpy as np

from scan2terrain._numba import numba as nb
from scan2terrain.octree._sparse import (
    BLOCK_MASK,
    COUNT_SHIFT,
    HITS_SHIFT,
    NPART,
    NREG,
    NREG_BITS,
    PART_BITS,
    SPARSE_LOAD,
    _probe,
    _region,
    add_sparse,
    fib,
    hit_voxel,
    home,
)
from scan2terrain.octree._table import (
    DEBRUIJN,
    DEBRUIJN_MUL,
    DONE,
    JIT,
    _room,
    _slot,
    block_voxel_key,
    key_block,
    key_local,
)

# Flags on the first voxel key of a block's run in group_new_points' output: the block goes to
# the dense store (the sign bit); the sparse store holds voxels of it to hand over; its hits are
# already in the sparse store (a block promoted after its hits: no bits to set).
DENSE_RUN = np.int64(-(1 << 63))
ADOPT_RUN = np.int64(1 << 62)
NO_BITS = np.int64(1 << 61)
# A block left for upsert_sparse with more than 9 voxels is written as a record, RECORD | its
# block id and then its 8 mask words, instead of its voxel keys.
RECORD = np.int64(1 << 60)
#: Points per sub-bucket that group_new_points aims at: its hash and masks then fit in cache.
SUB_POINTS = 4096


@nb.njit(**JIT)
def _popcount(x):
    x = x - ((x >> np.uint64(1)) & np.uint64(0x5555555555555555))
    x = (x & np.uint64(0x3333333333333333)) + ((x >> np.uint64(2)) & np.uint64(0x3333333333333333))
    x = (x + (x >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return np.int64((x * np.uint64(0x0101010101010101)) >> np.uint64(56))


@nb.njit(**JIT)
def _group_blocks(keys, start, b, tkeys, tidx, tpos, tbk, masks, nt):
    """Add the blocks of voxel keys ``keys[start:b]`` in order of first appearance (``tbk``, ``nt``
    so far) and each one's mask of voxels hit, through the hash ``tkeys`` (block id, -1 empty;
    homes from bits of fib below those that chose the partition and sub-bucket) -> ``tidx``;
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
            h = home(bk, 16, cap - 1)
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


@nb.njit(**JIT)
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
                    local = word * 64 + DEBRUIJN[(bit * DEBRUIJN_MUL) >> np.uint64(58)]
                    new += hit_voxel(vt, block_voxel_key(bk, local), r, max_hits)
            add_sparse(st, bk, r, held, new, sparse_counts)
            out[r, 3] += d
            if held + new >= dense_min:  # promoted: one key stands for the block
                keys[w] = block_voxel_key(bk, 0) | DENSE_RUN | ADOPT_RUN | NO_BITS
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


@nb.njit(inline="always", **JIT)
def _write_block(keys, w, bk, masks, u, flags):
    """The voxel keys of block ``bk`` (``masks[u]``) from ``keys[w]`` on, by index in the block,
    the first one with ``flags``; returns the index after the last."""
    for word in range(8):
        rest = masks[u, word]
        while rest:
            bit = rest & (~rest + np.uint64(1))
            rest ^= bit
            local = word * 64 + DEBRUIJN[(bit * DEBRUIJN_MUL) >> np.uint64(58)]
            keys[w] = block_voxel_key(bk, local) | flags
            flags = 0
            w += 1
    return w


@nb.njit(inline="always", **JIT)
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


@nb.njit(parallel=True, **JIT)
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
    Each partition is a loop iteration with scratch arrays of its own, handed to the threads as
    they ask (under numba.parallel_chunksize(1): a thread whose core another process holds
    delays one partition, not a share of them), so nothing depends on ``threads`` (kept for the
    kernel's signature) or on which thread takes a partition."""
    written = np.zeros((NPART, 2), dtype=np.int64)
    out = np.zeros((NREG, 4), dtype=np.int64)
    for p in nb.prange(NPART):
        _group_partitions(
            p, NPART, keys, seg, vt, st, sparse_counts, dense_min, max_hits, written, out
        )
    return written, out


@nb.njit(**JIT)
def _sub_bucket(key, bits):
    """Sub-bucket of a voxel key within its partition: the ``bits`` of fib(its block) below
    the partition's (so sub-buckets nest in regions)."""
    return np.int64((fib(key_block(key)) << np.uint64(PART_BITS)) >> np.uint64(64 - bits))


@nb.njit(**JIT)
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
                        h = home(tbk[u], 16, cap - 1)
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


@nb.njit(parallel=True, **JIT)
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
                        local = word * 64 + DEBRUIJN[(bit * DEBRUIJN_MUL) >> np.uint64(58)]
                        new += hit_voxel(vt, block_voxel_key(bk, local), r, max_hits)
                        hits[p, 0] += 1
            else:
                for m in range(i, j):
                    new += hit_voxel(vt, keys[m], r, max_hits)
                hits[p, 0] += j - i
            add_sparse(st, bk, r, held, new, sparse_counts)
            if held + new >= dense_min:
                keys[i] |= DENSE_RUN | ADOPT_RUN | NO_BITS
                hits[p, 1] += 1
            i = j
    return hits


@nb.njit(**JIT)
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
