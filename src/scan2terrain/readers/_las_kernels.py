"""Compiled per-point loop of the LAS reader (numba)."""

from __future__ import annotations

from scan2terrain._numba import numba as nb


@nb.njit(nogil=True, cache=True, error_model="numpy")
def scaled_xyz(X, Y, Z, scales, offsets, origin, out):
    """out[i] = (X[i] * scale + offset) - origin per axis: laspy's coordinates (the same
    operations, in the same order) less a local origin, in one pass over the strided records
    (numpy's strided int32 -> float64 conversion alone costs 5x more)."""
    for i in range(X.shape[0]):
        out[i, 0] = (X[i] * scales[0] + offsets[0]) - origin[0]
        out[i, 1] = (Y[i] * scales[1] + offsets[1]) - origin[1]
        out[i, 2] = (Z[i] * scales[2] + offsets[2]) - origin[2]
