"""The voxel octree's compiled kernels (numba) as sets: :data:`PARALLEL` and :data:`SERIAL`.

The inner loops of the octree live in (nothing in them allocates Python objects):

- ``_table.py``: the dense store's block hash table, keys and what every kernel module shares;
- ``_raycast.py``: ray casting into the dense store (insert_scan) and the log-odds updates;
- ``_points.py``: end points only (insert_endpoints), the points sorted by block;
- ``_group.py``: end points only, the points outside the dense store grouped by block;
- ``_sparse.py``: the sparse store, and the queries by voxel key that read both stores.

The kernels that run on every core are collected here, also compiled without threads.
"""

from __future__ import annotations

import types
from typing import Any, NamedTuple

from scan2terrain._numba import numba as nb
from scan2terrain.octree._group import group_new_points, upsert_sparse
from scan2terrain.octree._points import count_points, mark_point_bits, place_points
from scan2terrain.octree._raycast import apply_blocks, cast_parallel, flag_blocks
from scan2terrain.octree._sparse import sparse_rehash
from scan2terrain.octree._table import JIT


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
    return nb.njit(**JIT)(g)


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
