"""3D clean-up of occupied voxels: small connected components left out (the 3D analogue of
filters/speckle.py's 2D specks)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

_OFFSETS = {
    6: [(1, 0, 0), (0, 1, 0), (0, 0, 1)],
    18: [
        o
        for o in np.ndindex(3, 3, 3)
        if 0 < sum(abs(c - 1) for c in o) <= 2 and (o[0], o[1], o[2]) > (1, 1, 1)
    ],
    26: [o for o in np.ndindex(3, 3, 3) if (o[0], o[1], o[2]) > (1, 1, 1)],
}


def remove_small_components(
    keys: NDArray[np.int64], min_voxels: int, *, connectivity: int = 26
) -> NDArray[np.bool_]:
    """Mask (N,) of the voxels to keep: those in connected components (6-, 18- or 26-connected)
    of at least ``min_voxels`` voxels; ``min_voxels <= 1`` keeps all. ``keys`` (N, 3) unique
    integer voxel coordinates, any range (no dense grid over their bounding box)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    k = np.asarray(keys)
    if k.ndim != 2 or k.shape[1] != 3:
        raise ValueError(f"keys must have shape (N, 3), got {k.shape}")
    if connectivity not in _OFFSETS:
        raise ValueError(f"connectivity must be 6, 18 or 26, got {connectivity}")
    if min_voxels <= 1 or len(k) == 0:
        return np.ones(len(k), bool)
    v = k.astype(np.int64) - k.min(axis=0) + 1
    dims = v.max(axis=0) + 2
    if float(np.prod(dims.astype(np.float64))) >= 2.0**62:
        raise ValueError("keys span too large a range")
    code = (v[:, 0] * dims[1] + v[:, 1]) * dims[2] + v[:, 2]
    order = np.argsort(code)
    sorted_code = code[order]
    rows, cols = [], []
    for o in _OFFSETS[connectivity]:
        step = np.array(o) - (1 if connectivity != 6 else 0)
        n = v + step
        c = (n[:, 0] * dims[1] + n[:, 1]) * dims[2] + n[:, 2]
        at = np.minimum(np.searchsorted(sorted_code, c), len(k) - 1)
        hit = sorted_code[at] == c
        rows.append(np.flatnonzero(hit))
        cols.append(order[at[hit]])
    r, c = np.concatenate(rows), np.concatenate(cols)
    graph = coo_matrix((np.ones(len(r), np.int8), (r, c)), shape=(len(k), len(k)))
    _, label = connected_components(graph, directed=False)
    size = np.bincount(label)
    keep: NDArray[np.bool_] = size[label] >= min_voxels
    return keep
