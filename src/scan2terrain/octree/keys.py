"""OctoMap's voxel keys: 16 bits per axis, ``key = floor(coord / resolution) + KEY_OFFSET``.

The one place the key convention is written down; the octree, ``.bt`` files, the grid projection
and the pipeline all use it.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

#: Key of the voxel holding coordinate 0 (OctoMap's tree_max_val): the map spans
#: +-KEY_OFFSET * resolution.
KEY_OFFSET = 32768


def key_to_coord(
    keys: NDArray[np.integer] | NDArray[np.floating], resolution: float
) -> NDArray[np.float64]:
    """Voxel centres of ``keys`` (any shape), metres: ``(key - KEY_OFFSET + 0.5) * resolution``."""
    return (np.asarray(keys, dtype=np.float64) - KEY_OFFSET + 0.5) * resolution
