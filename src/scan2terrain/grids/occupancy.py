"""Occupancy values (-1, 0..100) to the three classes unknown/free/occupied, and back."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from scan2terrain.types import FREE, OCCUPIED, UNKNOWN


def to_trinary(
    data: NDArray[np.int8], *, occupied_above: float = 99.0, free_below: float = 1.0
) -> NDArray[np.int8]:
    """Classify occupancy values: ``> occupied_above`` occupied, ``0 <= v < free_below`` free,
    everything else (-1 and the values in between) unknown.

    With the defaults a map_server ``scale`` grid keeps 0 and 100 and its in-between values (the
    cells map_server itself was unsure of) become unknown; trinary grids pass unchanged. For
    ``raw`` maps pass the map's thresholds in percent.
    """
    if not 0 <= free_below <= occupied_above < OCCUPIED:
        raise ValueError(
            f"need 0 <= free_below ({free_below}) <= occupied_above ({occupied_above}) < 100"
        )
    out = np.full(data.shape, UNKNOWN, dtype=np.int8)
    out[(data >= 0) & (data < free_below)] = FREE
    out[data > occupied_above] = OCCUPIED
    return out


def invert_occupancy(data: NDArray[np.int8]) -> NDArray[np.int8]:
    """Swap free and occupied (``v -> 100 - v``); unknown stays unknown."""
    return np.where(data < 0, data, OCCUPIED - data.astype(np.int16)).astype(np.int8)


#: Ranks of the three classes, ordered so that unknown sits between free and occupied: what the
#: filters (as labels) and the preview (as "went up / went down") compare.
RANK_FREE, RANK_UNKNOWN, RANK_OCCUPIED = 0, 1, 2
_CLASS_OF_RANK = np.array([FREE, UNKNOWN, OCCUPIED], dtype=np.int8)


def to_rank(trinary: NDArray[np.int8]) -> NDArray[np.uint8]:
    """Trinary occupancy to ranks: free 0, occupied 2, anything else (unknown) 1."""
    rank = np.full(trinary.shape, RANK_UNKNOWN, dtype=np.uint8)
    rank[trinary == FREE] = RANK_FREE
    rank[trinary == OCCUPIED] = RANK_OCCUPIED
    return rank


def from_rank(rank: NDArray[np.uint8]) -> NDArray[np.int8]:
    """Ranks back to trinary occupancy (-1/0/100)."""
    out: NDArray[np.int8] = _CLASS_OF_RANK[rank]
    return out
