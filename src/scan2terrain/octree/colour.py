"""The mean colour of the points in each voxel: :class:`VoxelColours`.

Points are put in voxels by the octree's own rule (OctoMap's ``coordToKey`` of a float32
``point3d``, :func:`scan2terrain.octree.keys.coord_cell`: ``floor(double(float32(x)) * (1.0 /
resolution)) + KEY_OFFSET`` per axis), so the colour of a key is the colour of the points that
made that voxel. Sums are integers, so the result does not depend on the order or the chunks
in which points are added.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from scan2terrain.octree.keys import KEY_OFFSET

__all__ = ["GREY", "VoxelColours"]

#: Colour of a voxel no coloured point fell in (RGB).
GREY = (128, 128, 128)

_KEY_RANGE = 2 * KEY_OFFSET  # keys are 0..65535 per axis


class VoxelColours:
    """Per-voxel sums of the red, green and blue of the points added, and their counts.

    Parameters
    ----------
    resolution : float
        Voxel edge, metres: the octree's resolution.

    Notes
    -----
    :meth:`add` sums each call's points per voxel at once (a sort, no loop per point) and keeps
    the result as a run; runs are merged when they hold more voxels than the merged table, and
    before :meth:`mean`, so adding a cloud chunk by chunk costs O(N log N) overall. Memory: 40
    bytes per coloured voxel.
    """

    def __init__(self, resolution: float) -> None:
        resolution = float(resolution)
        if not (resolution > 0 and np.isfinite(resolution)):
            raise ValueError(f"resolution must be a positive number of metres, got {resolution}")
        self.resolution = resolution
        self._inv = 1.0 / resolution  # as the octree computes it: 1.0 / resolution in double
        # The merged table: packed keys, sorted and unique; sums (M, 3) and counts (M,).
        self._keys = np.zeros(0, dtype=np.int64)
        self._sums = np.zeros((0, 3), dtype=np.int64)
        self._counts = np.zeros(0, dtype=np.int64)
        self._runs: list[tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]] = []
        self._pending = 0

    def __len__(self) -> int:
        """Voxels that got at least one coloured point."""
        self._merge()
        return len(self._keys)

    @property
    def points(self) -> int:
        """Points counted so far (those inside the key range)."""
        return int(self._counts.sum()) + sum(int(c.sum()) for _, _, c in self._runs)

    def add(self, points: NDArray[np.floating], rgb: NDArray[np.uint8]) -> None:
        """Count the colours ``rgb`` (N, 3) uint8 of ``points`` (N, 3) metres, in the octree's
        frame (float64 or float32). Points that are not finite or fall outside the key range
        (+-32768 voxels) are not counted, as the octree drops them."""
        pts = np.asarray(points)
        colours = np.asarray(rgb)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"points must be (N, 3), got shape {pts.shape}")
        if colours.shape != pts.shape:
            raise ValueError(f"rgb must be (N, 3) like points {pts.shape}, got {colours.shape}")
        if colours.dtype != np.uint8:
            raise ValueError(f"rgb must be uint8, got {colours.dtype}")
        if len(pts) == 0:
            return
        packed = self._packed_keys(pts)
        inside = packed >= 0
        if not inside.all():
            packed, colours = packed[inside], colours[inside]
            if len(packed) == 0:
                return
        order = np.argsort(packed, kind="stable")
        keys, sums, counts = _reduce(packed[order], colours[order].astype(np.int64))
        self._runs.append((keys, sums, counts))
        self._pending += len(keys)
        if self._pending > len(self._keys):
            self._merge()

    def mean(self, keys: NDArray[np.integer]) -> NDArray[np.uint8]:
        """The mean colour of each key's points, (M, 3) uint8 for ``keys`` (M, 3) (uint16 voxel
        keys, as the octree gives them): each channel's sum over count, rounded half up; the
        neutral grey :data:`GREY` for keys no coloured point fell in."""
        k = np.asarray(keys)
        if k.ndim != 2 or k.shape[1] != 3:
            raise ValueError(f"keys must be (M, 3), got shape {k.shape}")
        out = np.empty((len(k), 3), dtype=np.uint8)
        out[:] = GREY
        self._merge()
        if len(k) == 0 or len(self._keys) == 0:
            return out
        k64 = k.astype(np.int64)
        valid = ((k64 >= 0) & (k64 < _KEY_RANGE)).all(axis=1)
        packed = np.where(valid, _pack(k64), -1)
        at = np.minimum(np.searchsorted(self._keys, packed), len(self._keys) - 1)
        found = valid & (self._keys[at] == packed)
        counts = self._counts[at[found]][:, None]
        # Rounded half up in integers: floor((2 sum + count) / (2 count)).
        out[found] = (2 * self._sums[at[found]] + counts) // (2 * counts)
        return out

    def _packed_keys(self, pts: NDArray[np.floating]) -> NDArray[np.int64]:
        """One int64 per point: ``(kx << 32) | (ky << 16) | kz``, or -1 outside the key range or
        for a non-finite point."""
        with np.errstate(over="ignore", invalid="ignore"):  # inf and NaN fall outside
            cells = np.floor(pts.astype(np.float32).astype(np.float64) * self._inv)
            ok = ((cells >= -KEY_OFFSET) & (cells < KEY_OFFSET)).all(axis=1)
        k = np.zeros(cells.shape, dtype=np.int64)
        k[ok] = cells[ok].astype(np.int64) + KEY_OFFSET
        return np.where(ok, _pack(k), -1)

    def _merge(self) -> None:
        """Fold the runs into the merged table."""
        if not self._runs:
            return
        keys = np.concatenate([self._keys, *(r[0] for r in self._runs)])
        sums = np.concatenate([self._sums, *(r[1] for r in self._runs)])
        counts = np.concatenate([self._counts, *(r[2] for r in self._runs)])
        order = np.argsort(keys, kind="stable")
        self._keys, self._sums, self._counts = _reduce(keys[order], sums[order], counts[order])
        self._runs, self._pending = [], 0


def _pack(k: NDArray[np.int64]) -> NDArray[np.int64]:
    """(M, 3) keys 0..65535 -> one int64 each, ordered as (x, y, z)."""
    packed: NDArray[np.int64] = (k[:, 0] << 32) | (k[:, 1] << 16) | k[:, 2]
    return packed


def _reduce(
    keys: NDArray[np.int64], sums: NDArray[np.int64], counts: NDArray[np.int64] | None = None
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """Rows of sorted ``keys`` summed per key: (unique keys, sums (U, 3), counts (U,)); each row
    counts 1 where ``counts`` is None."""
    starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
    if counts is None:
        counts = np.diff(np.r_[starts, len(keys)]).astype(np.int64)
    else:
        counts = np.add.reduceat(counts, starts)
    return keys[starts], np.add.reduceat(sums, starts, axis=0), counts
