"""The ``.bt`` writer's kernel (for :mod:`scan2terrain.octree.bt`): the pruned tree serialised in
one depth-first pass over the voxels sorted in Morton order.

Each node's voxels are a contiguous run of the sorted codes, its children the runs that share
the next three bits. A node whose eight children are all leaves of one state becomes a leaf
itself (below the root), as ``OcTree::writeBinary``'s prune makes it; an inner node writes its
two bytes (2 bits a child: 0 none, 1 free, 2 occupied, 3 inner; child i in bits 2i, 2i+1)
before its children's, depth first, as OctoMap's ``writeBinaryNode`` does. A node is written
before its children are known, so its two bytes are reserved and filled in afterwards, and
given back when it becomes a leaf (its children, all leaves, wrote nothing).
"""

from __future__ import annotations

import numpy as np

from scan2terrain._numba import numba as nb

_JIT = {"nogil": True, "cache": True, "error_model": "numpy"}
TREE_DEPTH = 16


@nb.njit(**_JIT)
def _spread(k):
    """The 16 bits of ``k`` moved to every third bit (bit i to bit 3i)."""
    x = np.uint64(k)
    x = (x | (x << np.uint64(16))) & np.uint64(0x0000_FF00_00FF)
    x = (x | (x << np.uint64(8))) & np.uint64(0x0000_F00F_00F00F)
    x = (x | (x << np.uint64(4))) & np.uint64(0x00C3_0C30_C30C3)
    x = (x | (x << np.uint64(2))) & np.uint64(0x0249_2492_49249)
    return x


@nb.njit(**_JIT)
def sort_keys(keys, occupied):
    """Each voxel's sort key: its Morton code (the key bits interleaved, x lowest: the depth
    first order of OctoMap's children) shifted left once, its state in bit 0."""
    out = np.empty(keys.shape[0], dtype=np.uint64)
    for i in range(keys.shape[0]):
        code = _spread(keys[i, 0]) | (_spread(keys[i, 1]) << np.uint64(1))
        code |= _spread(keys[i, 2]) << np.uint64(2)
        out[i] = (code << np.uint64(1)) | np.uint64(occupied[i])
    return out


@nb.njit(**_JIT)
def repeats(packed):
    """Whether two neighbours of sorted ``packed`` are the same voxel (any state)."""
    for i in range(1, packed.shape[0]):
        if (packed[i] >> np.uint64(1)) == (packed[i - 1] >> np.uint64(1)):
            return True
    return False


@nb.njit(**_JIT)
def serialise(packed):
    """The pruned tree over ``packed`` (sorted ``morton << 1 | occupied``, distinct voxels, at
    least one): its data bytes and its node count (the root and every inner node's children).

    Depth first with an explicit stack of the open nodes (numba's cache mishandles recursive
    functions): per open node its depth, voxel run end, next child and where that child's run
    starts, its record so far, how many children it has, the first child's kind and whether
    every child has that kind, and where its two bytes go. Kinds: 0 none, 1 free leaf,
    2 occupied leaf, 3 inner."""
    out = np.empty(2 * (TREE_DEPTH * len(packed) + 1), dtype=np.uint8)
    size = TREE_DEPTH + 1
    depth = np.zeros(size, np.int64)
    end = np.zeros(size, np.int64)
    child = np.zeros(size, np.int64)
    start = np.zeros(size, np.int64)
    word = np.zeros(size, np.int64)
    present = np.zeros(size, np.int64)
    first = np.zeros(size, np.int64)
    uniform = np.zeros(size, np.bool_)
    mine = np.zeros(size, np.int64)
    at = 2
    nodes = 1
    top = 0  # the root: depth 0, every voxel, its bytes at 0
    end[0] = len(packed)
    uniform[0] = True
    while top >= 0:
        if child[top] == 8:  # every child seen: the node is a leaf or writes its record
            kind = 3
            if depth[top] >= 1 and uniform[top] and first[top] in (1, 2):
                at = mine[top]  # a leaf: its children were leaves, and wrote nothing
                kind = first[top]
            else:
                out[mine[top]] = word[top] & 0xFF
                out[mine[top] + 1] = word[top] >> 8
                nodes += present[top]
            top -= 1
            if top < 0:
                break
        else:
            c = child[top]
            shift = 3 * (TREE_DEPTH - 1 - depth[top]) + 1
            i = start[top]
            j = i
            while j < end[top] and (packed[j] >> shift) & 7 == c:
                j += 1
            if j > i and depth[top] + 1 < TREE_DEPTH:  # an inner child: open it
                top += 1
                depth[top] = depth[top - 1] + 1
                start[top] = i
                end[top] = j
                child[top] = 0
                word[top] = 0
                present[top] = 0
                first[top] = 0
                uniform[top] = True
                mine[top] = at
                at += 2
                start[top - 1] = j
                continue
            kind = 0
            if j > i:  # a voxel
                kind = 2 if packed[i] & 1 else 1
            start[top] = j
        # The kind of the parent's next child is known: record it.
        c = child[top]
        if c == 0:
            first[top] = kind
        elif kind != first[top]:
            uniform[top] = False
        word[top] |= kind << (2 * c)
        if kind != 0:
            present[top] += 1
        child[top] = c + 1
    return out[:at].copy(), nodes
