"""3D clean-up of occupied voxels: small connected components left out, the 3D analogue of
:mod:`scan2terrain.filters.speckle`'s 2D specks.

Voxels are given as integer keys, not as a dense grid: an octree's occupied voxels are a thin
shell (surfaces) over a bounding box that may span millions of voxels per axis, so a dense grid
(and ``scipy.ndimage.label``) is out. Instead each key gets an int64 code whose order is
(x, y, z) lexicographic (an axis spanning more than 2 N values is first compressed, its gaps
shortened to one empty value), the codes are sorted once, and each neighbouring column
(x + dx, y + dy) is one ``np.searchsorted`` of *sorted* queries (fast: each search starts where
the last one ended), its z +- 1 neighbours read beside the match. The edges found, less those
implied by others, form a sparse graph whose components ``scipy.sparse.csgraph`` labels.

10 M voxels (rough terrain and walls, or a solid block) take 3-5 s and 1.2 GB over the input on
2 cores (``benchmarks/bench_voxel_cleanup.py``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["remove_small_components"]

#: Neighbour columns (dx, dy) looked up per connectivity: half of them (the other half are the
#: same edges seen from the other end). The z neighbours of a column come from the same search.
_COLUMNS = {6: ((1, 0), (0, 1)), 18: ((1, 0), (0, 1), (1, 1), (1, -1))}
_COLUMNS[26] = _COLUMNS[18]

#: Largest box (voxels, padding included) whose (x, y, z) are packed into a code arithmetically;
#: beyond it (keys sparse over more than ~10^6 distinct values on every axis) the (x, y) columns
#: are ranked first, which costs one more sort. A module constant so that tests can force the
#: ranked path.
_MAX_LINEAR_CODE = 2**63 - 1


def remove_small_components(
    keys: NDArray[np.integer[Any]], min_voxels: int, *, connectivity: int = 26
) -> NDArray[np.bool_]:
    """Mask of the voxels to keep: those in connected components of at least ``min_voxels``.

    Parameters
    ----------
    keys : integer array, shape (N, 3)
        Distinct integer voxel coordinates (x, y, z), any int64 range: negative, or millions of
        voxels apart (no dense grid is allocated over their bounding box). Distinctness is
        checked when components are computed (not when ``min_voxels <= 1``).
    min_voxels : int
        Components with fewer voxels than this are dropped; ``min_voxels <= 1`` keeps all.
    connectivity : {6, 18, 26}
        Voxels touching by a face (6), a face or an edge (18), or a face, an edge or a corner
        (26, the default: the 3D analogue of the 8-connectivity of 2D speckle removal).

    Returns
    -------
    bool array, shape (N,)
        True for the voxels to keep, in the order of ``keys``. The same keys give the same mask
        (component sizes do not depend on the order of the search).

    Raises
    ------
    ValueError
        If ``keys`` is not an (N, 3) integer array or holds a key twice, ``min_voxels`` is not an
        integer, or ``connectivity`` is not 6, 18 or 26.
    """
    k = _check_keys(keys)
    if isinstance(min_voxels, bool) or not isinstance(min_voxels, (int, np.integer)):
        raise ValueError(f"min_voxels must be an integer, got {min_voxels!r}")
    if isinstance(connectivity, bool) or connectivity not in _COLUMNS:
        raise ValueError(f"connectivity must be 6, 18 or 26, got {connectivity!r}")
    n = len(k)
    keep = np.ones(n, dtype=bool)
    if min_voxels <= 1 or n == 0:
        return keep
    from scipy.sparse import coo_array  # deferred: importing scipy.sparse costs ~1 s
    from scipy.sparse.csgraph import connected_components

    sorted_codes, order, columns = _sorted_codes(k)
    if np.any(sorted_codes[1:] == sorted_codes[:-1]):
        raise ValueError("keys must be distinct: a voxel is listed twice")
    sources, targets = _edges(sorted_codes, columns, connectivity)
    graph = coo_array(
        (np.ones(len(sources), dtype=np.int8), (sources, targets)), shape=(n, n)
    ).tocsr()
    del sources, targets
    _, labels = connected_components(graph, directed=False)
    sizes = np.bincount(labels)
    keep[order] = sizes[labels] >= min_voxels
    return keep


def _check_keys(keys: Any) -> NDArray[np.int64]:
    arr = np.asarray(keys)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"keys must have shape (N, 3), got {arr.shape}")
    if arr.dtype.kind not in "iu":
        raise ValueError(f"keys must have an integer dtype, got {arr.dtype}")
    if arr.dtype == np.uint64 and arr.size and int(arr.max()) > np.iinfo(np.int64).max:
        raise ValueError("keys must fit in int64")
    return arr.astype(np.int64, copy=False)


class _Columns:
    """The (x, y) columns of the sorted voxels: the code of a voxel is ``column * dz + z``.

    ``shift(dx, dy)`` gives, for the voxels whose column (x + dx, y + dy) may hold voxels, their
    indices (ascending; None for all of them) and the code of (x + dx, y + dy, z), ascending too.
    """

    def __init__(
        self,
        sorted_codes: NDArray[np.int64],
        dz: int,
        dy: int,
        ranked: NDArray[np.int64] | None,
    ) -> None:
        self.codes = sorted_codes
        self.dz = dz
        self.dy = dy
        self.ranked = ranked  # sorted distinct x * dy + y of the columns, or None if packed

    def shift(self, dx: int, dy: int) -> tuple[NDArray[np.intp] | None, NDArray[np.int64]]:
        step = dx * self.dy + dy
        if self.ranked is None:  # packed: the column's code is x * dy + y itself
            return None, self.codes + step * self.dz
        # Ranked: look the neighbour column up among the columns that exist.
        table = self.ranked
        wanted = table + step
        at = np.minimum(np.searchsorted(table, wanted), len(table) - 1)
        neighbour = np.where(table[at] == wanted, at, -1)
        column, z = np.divmod(self.codes, self.dz)
        target = neighbour[column]
        sources = np.flatnonzero(target >= 0)
        return sources, target[sources] * self.dz + z[sources]


def _sorted_codes(keys: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.intp], _Columns]:
    """Sorted int64 codes of ``keys`` (x, y, z order), the sorting permutation, and the columns.

    Each axis is first shifted to start at 1 (0 and max + 1 stay free, so that neighbour codes
    never wrap into the next column); an axis spanning more than 2 N values is compressed by
    rank, gaps of more than one value becoming gaps of exactly two, which keeps adjacency.
    """
    n = len(keys)
    axes: list[NDArray[np.int64]] = []
    dims: list[int] = []
    for column in keys.T:
        lo, hi = int(column.min()), int(column.max())
        if hi - lo <= 2 * n:
            axes.append(column - lo + 1)
            dims.append(hi - lo + 3)
            continue
        perm = np.argsort(column)
        values = column[perm]
        # A wrapped difference (values more than 2**63 apart) is negative: a gap, as it should be.
        gap = np.diff(values)
        step = np.where(gap == 0, 0, np.where(gap == 1, 1, 2))
        compressed = np.empty(n, dtype=np.int64)
        compressed[perm] = np.concatenate(([1], 1 + np.cumsum(step)))
        axes.append(compressed)
        dims.append(int(compressed[perm[-1]]) + 2)
    x, y, z = axes
    dim_x, dim_y, dim_z = dims
    xy = x * dim_y + y  # < (2 N + 3)**2: fits for any N numpy can hold in memory here
    ranked: NDArray[np.int64] | None = None
    if dim_x * dim_y * dim_z <= _MAX_LINEAR_CODE:
        codes = xy * dim_z + z
    else:
        perm = np.argsort(xy)
        sorted_xy = xy[perm]
        first = np.concatenate(([True], sorted_xy[1:] != sorted_xy[:-1]))
        rank = np.empty(n, dtype=np.int64)
        rank[perm] = np.cumsum(first) - 1
        ranked = sorted_xy[first]
        codes = rank * dim_z + z
    order = np.argsort(codes)
    sorted_codes = codes[order]
    return sorted_codes, order, _Columns(sorted_codes, dim_z, dim_y, ranked)


def _edges(
    codes: NDArray[np.int64], columns: _Columns, connectivity: int
) -> tuple[NDArray[np.signedinteger[Any]], NDArray[np.signedinteger[Any]]]:
    """Edges (index pairs into ``codes``) enough to connect what ``connectivity`` connects.

    Edges implied by others are left out, which keeps the graph near 3 edges per voxel in
    solid regions instead of 13: (x+dx, y+dy, z+-1) is not linked when (x+dx, y+dy, z) exists
    (that voxel is linked, and its z neighbours are linked to it), nor an in-plane diagonal
    when one of the two face neighbours between them exists (both are linked to it).
    """
    n = len(codes)
    index = np.int32 if n < 2**31 else np.int64
    sources: list[NDArray[np.signedinteger[Any]]] = []
    targets: list[NDArray[np.signedinteger[Any]]] = []
    # (x, y, z + 1): the next code in sorted order.
    above = np.flatnonzero(codes[1:] == codes[:-1] + 1)
    sources.append(above.astype(index))
    targets.append((above + 1).astype(index))
    face: dict[
        tuple[int, int], NDArray[np.bool_]
    ] = {}  # (dx, dy) -> bool (N,): the voxel (x + dx, y + dy, z) exists
    for dx, dy in _COLUMNS[connectivity]:
        src, wanted = columns.shift(dx, dy)
        at = np.searchsorted(codes, wanted)
        found = codes[np.minimum(at, n - 1)] == wanted
        diagonal = abs(dx) + abs(dy) == 2
        if diagonal:  # linked through (x + dx, y, z) or (x, y + dy, z) if either exists
            through = face[dx, 0] | face[0, dy]
            link = found & ~(through if src is None else through[src])
        else:
            link = found
            face[dx, dy] = np.zeros(n, dtype=bool)
            face[dx, dy][np.flatnonzero(found) if src is None else src[found]] = True
            if (dx, dy) == (0, 1):  # the same links seen from the other end
                face[0, -1] = np.zeros(n, dtype=bool)
                face[0, -1][at[found]] = True
        hits = np.flatnonzero(link)
        sources.append((hits if src is None else src[hits]).astype(index))
        targets.append(at[hits].astype(index))
        if connectivity == 6 or (connectivity == 18 and diagonal):
            continue
        # (x + dx, y + dy, z +- 1), only where (x + dx, y + dy, z) is missing.
        missing = np.flatnonzero(~found)
        wanted, at = wanted[missing], at[missing]
        if src is not None:
            missing = src[missing]
        up = np.minimum(at, n - 1)  # not found: the next larger code, if any, sits at `at`
        down = np.maximum(at - 1, 0)
        for ok, where in ((codes[up] == wanted + 1, up), (codes[down] == wanted - 1, down)):
            sources.append(missing[ok].astype(index))
            targets.append(where[ok].astype(index))
    return np.concatenate(sources), np.concatenate(targets)
