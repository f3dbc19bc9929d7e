"""The occupied voxels of an octree's known voxels, pruned leaves (vertical runs) expanded."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError

#: Most occupied voxels expanded from runs (12 bytes each as keys; more in what is made of them).
MAX_VOXELS = 50_000_000


def occupied_voxels(
    keys: NDArray[np.uint16],
    occupied: NDArray[np.bool_],
    runs: NDArray[np.uint16] | None,
    source: Path,
    *,
    why: str,
) -> NDArray[np.uint16]:
    """Keys of every occupied voxel, runs (``grids.projection.leaf_columns``) expanded: counted
    first, and refused past :data:`MAX_VOXELS` naming ``why`` they were asked for."""
    picked = keys[occupied]
    if runs is None:
        count = len(picked)
    else:
        lengths = runs[occupied].astype(np.int64)
        count = int(lengths.sum())
    if count > MAX_VOXELS:
        raise InputError(
            source,
            f"{why}: the tree's occupied leaves hold {count} voxels, more than {MAX_VOXELS}",
        )
    if runs is None:
        return picked
    out = np.repeat(picked, lengths, axis=0)
    starts = np.cumsum(lengths) - lengths
    out[:, 2] += (np.arange(len(out)) - np.repeat(starts, lengths)).astype(np.uint16)
    return out
