"""The explicit policy for unknown cells: floor, wall, or a height of their own."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from scan2terrain.config import UNKNOWN_POLICIES, UnknownPolicy
from scan2terrain.types import OCCUPIED, UNKNOWN


def unknown_level(policy: UnknownPolicy, *, wall_height: float, unknown_height: float) -> float:
    """The height in metres an unknown cell gets under ``policy``."""
    if policy == "free":
        return 0.0
    if policy == "obstacle":
        return wall_height
    if policy == "height":
        return unknown_height
    raise ValueError(f"policy must be one of {UNKNOWN_POLICIES}, got {policy!r}")


def occupancy_to_heights(
    trinary: NDArray[np.int8],
    *,
    wall_height: float,
    policy: UnknownPolicy = "free",
    unknown_height: float = 0.0,
) -> NDArray[np.float32]:
    """Trinary occupancy (-1/0/100) to ground heights in metres: free 0, occupied ``wall_height``,
    unknown as ``policy`` says (see :func:`unknown_level`)."""
    if not wall_height > 0:
        raise ValueError(f"wall_height must be > 0, got {wall_height}")
    level = unknown_level(policy, wall_height=wall_height, unknown_height=unknown_height)
    out = np.zeros(trinary.shape, dtype=np.float32)
    out[trinary == OCCUPIED] = wall_height
    out[trinary == UNKNOWN] = level
    return out
