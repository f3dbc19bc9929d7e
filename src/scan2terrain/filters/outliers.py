"""Statistical outlier removal for point clouds: the isolated returns (dust, rain, multipath,
mixed pixels at edges) that would otherwise become floating voxels.

The statistics are PCL's and Open3D's: for every point, the mean distance d to its k nearest
neighbours (other points); over the cloud, the mean m and the standard deviation s (N - 1) of
d. Points with d > m + std_ratio * s are outliers. A point far from everything has a large d; a
point on a surface, however sparse the surface, has a d close to m.

The k nearest neighbours of every point are the work, and Open3D, which the project already
ships (for the PCD and PLY files numpy cannot decode), does it with a compiled, multi-threaded
KD-tree, ``open3d.core.nns.NearestNeighborSearch``: 1 M points (k = 20) in 2.5 s on 2 cores,
where scipy's ``cKDTree.query(workers=-1)`` takes twice as long.

Open3D's own ``PointCloud.remove_statistical_outlier`` is not used: on Open3D 0.20 it drops
points it should keep. It takes a mean distance of 0 for "no neighbours", so it drops every
point of a cluster of k + 1 or more duplicates; and it keeps d < m + std_ratio * s strictly, so
when all mean distances are equal (two points, a regular lattice) it drops them all. Here the
statistics are computed in numpy from the neighbour distances and d <= m + std_ratio * s is
kept, up to the rounding of the coordinates (a lattice 0.1 m apart has mean distances 0.1 +-
1e-16, and a standard deviation of 1e-16 must not cut it in two).

Each point's neighbours are searched independently of the others and the sums run in a fixed
order, so the result is the same bit for bit whatever the number of threads.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["statistical_outliers"]

#: Query points per k-nearest-neighbour search: bounds the (chunk, k + 1) distance and index
#: arrays Open3D returns (16 bytes per neighbour) to tens of MB however large the cloud.
_CHUNK = 1 << 16

#: Relative rounding allowed on distances, as a share of the largest coordinate (x 64 the
#: float64 epsilon: 7e-8 m at UTM's 5e6 m, far below any scanner's noise).
_ROUNDING = 64 * float(np.finfo(np.float64).eps)


def statistical_outliers(
    points: NDArray[np.floating[Any] | np.integer[Any]],
    *,
    neighbours: int = 20,
    std_ratio: float = 2.0,
) -> NDArray[np.bool_]:
    """Mask of the points to keep: those not farther from their neighbours than most points.

    Parameters
    ----------
    points : real array, shape (N, 3)
        Point coordinates (metres), finite.
    neighbours : int
        k: the number of nearest other points whose mean distance is taken (PCL's ``MeanK``;
        Open3D's ``nb_neighbors`` counts the point itself, so it is k + 1). At least 1.
    std_ratio : float
        A point is an outlier if its mean distance is above the cloud's mean of them plus
        ``std_ratio`` times their standard deviation (sample, N - 1). Greater than 0.

    Returns
    -------
    bool array, shape (N,)
        True for the points to keep, in the order of ``points``. With ``neighbours`` points or
        fewer, no point has k neighbours to judge it by and all are kept. Duplicated points are
        neighbours at distance 0, like any other.

    Raises
    ------
    ValueError
        If ``points`` is not an (N, 3) real array of finite values, ``neighbours`` is not an
        integer >= 1, or ``std_ratio`` is not a finite number > 0.
    """
    arr = np.asarray(points)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {arr.shape}")
    if arr.dtype.kind not in "iuf":
        raise ValueError(f"points must have a real dtype, got {arr.dtype}")
    if isinstance(neighbours, bool) or not isinstance(neighbours, (int, np.integer)):
        raise ValueError(f"neighbours must be an integer, got {neighbours!r}")
    if neighbours < 1:
        raise ValueError(f"neighbours must be at least 1, got {neighbours}")
    if (
        isinstance(std_ratio, bool)
        or not isinstance(std_ratio, (int, float, np.integer, np.floating))
        or not math.isfinite(std_ratio)
        or std_ratio <= 0
    ):
        raise ValueError(f"std_ratio must be a finite number > 0, got {std_ratio!r}")
    xyz = np.ascontiguousarray(arr, dtype=np.float64)
    if not np.isfinite(xyz).all():
        raise ValueError("points must be finite (no NaN or infinity)")
    n = len(xyz)
    if n <= neighbours:
        return np.ones(n, dtype=bool)
    mean_distance = _mean_neighbour_distance(xyz, int(neighbours))
    threshold = mean_distance.mean() + float(std_ratio) * mean_distance.std(ddof=1)
    # Mean distances that differ only by the rounding of the coordinates are equal: without this
    # a regular lattice (0.1 m apart: distances 0.1 +- 1e-16) is cut in two by the noise.
    rounding = _ROUNDING * max(float(np.abs(xyz).max()), float(mean_distance.max()))
    keep: NDArray[np.bool_] = mean_distance <= threshold + rounding
    return keep


def _mean_neighbour_distance(xyz: NDArray[np.float64], k: int) -> NDArray[np.float64]:
    """Mean distance (N,) from each point to its ``k`` nearest others; needs N > k."""
    import open3d  # deferred: importing Open3D costs ~1.5 s

    core = open3d.core
    search = core.nns.NearestNeighborSearch(core.Tensor.from_numpy(xyz))
    search.knn_index()
    out = np.empty(len(xyz), dtype=np.float64)
    for start in range(0, len(xyz), _CHUNK):
        _, squared = search.knn_search(core.Tensor.from_numpy(xyz[start : start + _CHUNK]), k + 1)
        # Ascending, so column 0 is the point itself (or a duplicate of it: distance 0 either way).
        out[start : start + _CHUNK] = np.sqrt(squared.numpy()[:, 1:]).mean(axis=1)
    return out
