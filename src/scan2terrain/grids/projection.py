"""Voxels -> 2D grids: occupancy projection, 2.5D column statistics, ground and hole filling.

The voxels come from the voxel octree as arrays: ``keys`` (M, 3) OctoMap keys
(``key = floor(coord / resolution) + 32768``; the voxel's centre is
``(key - 32768 + 0.5) * resolution`` metres), ``occupied`` bool (M,) (occupied or free; unknown
voxels are absent) and the voxel ``resolution`` in metres.

Every grid made here has the voxel resolution, yaw 0 and its origin on a voxel boundary, so the
key column ``(kx, ky)`` is exactly the cell ``(row, col) = (ky - ky0, kx - kx0)``; grids made from
the same voxels with the same ``bounds`` line up cell for cell.

A z band ``[z_min, z_max]`` selects voxels by their *centre* height, as octomap_server's
``occupancy_min_z``/``occupancy_max_z`` do.

Pruned trees: a ``.bt`` leaf above the voxel depth is a cube of ``s`` voxels a side (one free
leaf of an octomap_server map can cover 256^3 = 16.7 M voxels). :func:`leaf_columns` turns
each such cube into ``s x s`` vertical *runs* of ``s`` voxels, and the projections take
``runs`` (the length of the run each key starts): every number they return is the one the
expanded voxels would give, from ``s^2`` rows instead of ``s^3``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from scan2terrain.octree.keys import KEY_OFFSET, key_to_coord
from scan2terrain.types import FREE, OCCUPIED, UNKNOWN, HeightGrid, OccupancyGrid, Pose2D

_KEY_MAX = 65535
#: Tolerance, in cells, when snapping a metric box onto voxel boundaries.
_SNAP_TOL = 1e-6
STATS = ("max", "min", "mean")
METRICS = ("euclidean", "chebyshev")

Bounds = tuple[float, float, float, float]


@dataclass(frozen=True)
class _Columns:
    """The grid frame chosen for a voxel set and the voxels' cell indices within it."""

    flat: NDArray[np.intp]  # (M,) row * W + col; 0 for voxels outside the grid
    inside: NDArray[np.bool_] | None  # (M,) voxels inside the grid; None = all of them
    kz: NDArray[np.uint16]  # (M,) lowest z key of the run
    top: NDArray[np.uint16]  # (M,) highest z key of the run (= kz for single voxels)
    occupied: NDArray[np.bool_]  # (M,)
    shape: tuple[int, int]
    origin: Pose2D


def leaf_columns(
    keys: NDArray[Any], depth: NDArray[Any], occupied: NDArray[Any], *, max_rows: int = 50_000_000
) -> tuple[NDArray[np.uint16], NDArray[np.bool_], NDArray[np.uint16]]:
    """Leaves of a pruned tree (lowest key (L, 3), tree depth (L,), state (L,)) as vertical runs:
    ``(keys, occupied, runs)`` for the projections, ``s x s`` runs of ``s`` voxels per leaf of
    side ``s = 2 ** (16 - depth)``. Raises ValueError past ``max_rows`` runs."""
    keys = np.asarray(keys, dtype=np.uint16)
    depth = np.asarray(depth)
    occupied = np.asarray(occupied, dtype=np.bool_)
    side = np.left_shift(1, 16 - depth.astype(np.int64))
    total = int((side * side).sum())
    if total > max_rows:
        raise ValueError(f"the tree's {len(keys)} leaves make {total} columns, over {max_rows}")
    out_keys, out_occ, out_runs = [], [], []
    for s in np.unique(side).tolist():
        pick = side == s
        grid = np.indices((s, s), dtype=np.uint16).reshape(2, -1).T
        k = np.repeat(keys[pick], s * s, axis=0)
        k[:, :2] += np.tile(grid, (int(pick.sum()), 1))
        out_keys.append(k)
        out_occ.append(np.repeat(occupied[pick], s * s))
        out_runs.append(np.full(len(k), s, dtype=np.uint16) if s < 65536 else None)
    if any(r is None for r in out_runs):
        raise ValueError("a leaf covers the whole key space")
    return (
        np.concatenate(out_keys),
        np.concatenate(out_occ),
        np.concatenate([r for r in out_runs if r is not None]),
    )


def _check_resolution(resolution: float) -> float:
    res = float(resolution)
    if not (res > 0 and math.isfinite(res)):
        raise ValueError(f"resolution must be a positive number of metres, got {resolution}")
    return res


def _check_band(z_min: float, z_max: float) -> None:
    if math.isnan(z_min) or math.isnan(z_max) or z_min > z_max:
        raise ValueError(f"need z_min <= z_max (metres), got z_min={z_min}, z_max={z_max}")


def _check_voxels(
    keys: NDArray[Any], occupied: NDArray[Any]
) -> tuple[NDArray[np.uint16], NDArray[np.bool_]]:
    keys = np.asarray(keys)
    occupied = np.asarray(occupied)
    if keys.ndim != 2 or keys.shape[1] != 3:
        raise ValueError(f"keys must have shape (M, 3), got {keys.shape}")
    if occupied.shape != (keys.shape[0],):
        raise ValueError(
            f"occupied must have shape ({keys.shape[0]},) to match keys, got {occupied.shape}"
        )
    if occupied.dtype != np.bool_:
        # Refuse log-odds or probabilities: their truth value is not "occupied".
        raise ValueError(f"occupied must be a bool array, got {occupied.dtype}")
    if keys.shape[0] == 0:
        raise ValueError("no voxels: keys is empty, there is nothing to project")
    if keys.dtype != np.uint16:
        if not np.issubdtype(keys.dtype, np.integer):
            raise ValueError(f"keys must be integer OctoMap keys, got {keys.dtype}")
        if keys.min() < 0 or keys.max() > _KEY_MAX:
            raise ValueError(f"keys must lie in 0..{_KEY_MAX} (16-bit OctoMap keys)")
        keys = keys.astype(np.uint16)
    return keys, occupied


def _key_range(lo_m: float, hi_m: float, res: float, name: str) -> tuple[int, int]:
    """The keys of the voxel columns overlapping [lo_m, hi_m) metres, snapped outwards."""
    if not (math.isfinite(lo_m) and math.isfinite(hi_m) and hi_m > lo_m):
        raise ValueError(f"bounds: need finite {name}_min < {name}_max, got {lo_m}, {hi_m}")
    # The tolerance keeps e.g. 0.3 / 0.1 = 2.9999999999999996 on boundary 3.
    k0 = math.floor(lo_m / res + _SNAP_TOL) + KEY_OFFSET
    k1 = math.ceil(hi_m / res - _SNAP_TOL) - 1 + KEY_OFFSET
    return k0, max(k0, k1)


def _columns(
    keys: NDArray[Any],
    occupied: NDArray[Any],
    res: float,
    bounds: Bounds | None,
    runs: NDArray[Any] | None = None,
) -> _Columns:
    keys16, occ = _check_voxels(keys, occupied)
    kz = keys16[:, 2]
    top = kz  # the same object when there are no runs (the fast paths test `is`)
    if runs is not None:
        runs = np.asarray(runs)
        if runs.shape != (len(keys16),) or (len(runs) and int(runs.min()) < 1):
            raise ValueError("runs must hold one length >= 1 per key")
        top64 = keys16[:, 2].astype(np.int64) + runs - 1
        if len(top64) and int(top64.max()) > _KEY_MAX:
            raise ValueError(f"runs reach past z key {_KEY_MAX}")
        top = top64.astype(np.uint16)
    kx, ky = keys16[:, 0], keys16[:, 1]  # uint16 views: one int array below, not two
    inside: NDArray[np.bool_] | None = None
    if bounds is None:
        kx0, kx1 = int(kx.min()), int(kx.max())
        ky0, ky1 = int(ky.min()), int(ky.max())
    else:
        if len(bounds) != 4:
            raise ValueError(f"bounds must be (x_min, y_min, x_max, y_max), got {bounds}")
        x_min, y_min, x_max, y_max = (float(b) for b in bounds)
        kx0, kx1 = _key_range(x_min, x_max, res, "x")
        ky0, ky1 = _key_range(y_min, y_max, res, "y")
        # The box's key range may lie beyond 0..65535: compare as wider integers.
        xk, yk = kx.astype(np.int64), ky.astype(np.int64)
        inside = (xk >= kx0) & (xk <= kx1) & (yk >= ky0) & (yk <= ky1)
        del xk, yk
    width, height = kx1 - kx0 + 1, ky1 - ky0 + 1
    flat = ky.astype(np.intp)  # (ky - ky0) * width + kx - kx0, in place
    flat -= ky0
    flat *= width
    flat += kx
    flat -= kx0
    if inside is not None:
        flat[~inside] = 0  # any valid cell: callers never let these voxels count
    origin = Pose2D((kx0 - KEY_OFFSET) * res, (ky0 - KEY_OFFSET) * res, 0.0)
    return _Columns(flat, inside, kz, top, occ, (height, width), origin)


def _key_centres(res: float) -> NDArray[np.float64]:
    """Centre height (metres) of every possible z key, for exact table look-ups."""
    return key_to_coord(np.arange(_KEY_MAX + 1), res)


def _band_keys(res: float, z_min: float, z_max: float) -> tuple[int, int]:
    """The lowest and highest z key whose voxel centre lies in [z_min, z_max] (lo > hi: none).
    Centres grow with the key, so the keys in the band are one interval."""
    centres = _key_centres(res)
    inside = np.flatnonzero((centres >= z_min) & (centres <= z_max))
    if len(inside) == 0:
        return 1, 0
    return int(inside[0]), int(inside[-1])


def _select(cols: _Columns, res: float, z_min: float, z_max: float) -> NDArray[np.bool_]:
    """Voxels (runs) inside the grid with a voxel centre z in [z_min, z_max]."""
    if cols.top is cols.kz:  # single voxels: one exact table look-up on the 16-bit key
        centres = _key_centres(res)
        sel: NDArray[np.bool_] = ((centres >= z_min) & (centres <= z_max))[cols.kz]
    else:
        lo, hi = _band_keys(res, z_min, z_max)
        sel = (cols.kz <= hi) & (cols.top >= lo)
    if cols.inside is not None:
        sel &= cols.inside
    return sel


def project_occupancy(
    keys: NDArray[Any],
    occupied: NDArray[Any],
    resolution: float,
    *,
    z_min: float = -math.inf,
    z_max: float = math.inf,
    bounds: Bounds | None = None,
    runs: NDArray[Any] | None = None,
) -> OccupancyGrid:
    """Project voxels onto a 2D occupancy grid, as octomap_server's projected map does.

    A column is occupied (100) if any occupied voxel's centre z lies in ``[z_min, z_max]``, else
    free (0) if any free voxel's does, else unknown (-1).

    Parameters
    ----------
    keys : integer array, shape (M, 3)
        OctoMap keys (uint16; other integer types must hold values in 0..65535).
    occupied : bool array, shape (M,)
        Occupied (True) or free (False) voxel.
    resolution : float
        Voxel side in metres; also the cell side of the grid.
    z_min, z_max : float
        Height band in metres, inclusive, tested against voxel centres.
    bounds : (x_min, y_min, x_max, y_max), optional
        Metric box in metres. The grid covers every voxel column that overlaps the box (the box
        is snapped outwards onto voxel boundaries); voxels outside are ignored and columns
        without voxels are unknown. Without ``bounds`` the grid is the x/y bounding box of *all*
        voxels, not only those in the band, so that grids projected with different bands (and
        :func:`column_stats`) from the same voxels share one frame.
    runs : integer array, shape (M,), optional
        Each key starts a vertical run of this many voxels of its state (see
        :func:`leaf_columns`); default one voxel each.

    Returns
    -------
    OccupancyGrid
        int8 (H, W), yaw 0, ``origin`` on a voxel boundary: cell (row, col) is key column
        (kx0 + col, ky0 + row).

    Raises
    ------
    ValueError
        No voxels, mismatched shapes, a bad band, resolution or box.
    """
    res = _check_resolution(resolution)
    _check_band(z_min, z_max)
    cols = _columns(keys, occupied, res, bounds, runs)
    sel = _select(cols, res, z_min, z_max)
    h, w = cols.shape
    # Rank each voxel 0 (outside band), 1 (free), 2 (occupied); a column takes its highest rank.
    # One scatter-max over all voxels is ~3x faster than masking and scattering twice.
    rank = sel.view(np.uint8) + (sel & cols.occupied).view(np.uint8)
    best = np.zeros(h * w, dtype=np.uint8)
    np.maximum.at(best, cols.flat, rank)
    data = np.array([UNKNOWN, FREE, OCCUPIED], dtype=np.int8)[best]
    return OccupancyGrid(data.reshape(h, w), res, cols.origin)


@dataclass(frozen=True)
class ColumnStats:
    """Per-column statistics of the occupied voxels' centre heights (the 2.5D view).

    Attributes
    ----------
    max_z, min_z, mean_z : float32 arrays, shape (H, W)
        Highest, lowest and mean centre z (metres) of the occupied voxels in each column; NaN
        where the column has none.
    count : int32 array, shape (H, W)
        Number of occupied voxels in the column.
    known : bool array, shape (H, W)
        Columns with at least one occupied voxel (``count > 0``).
    resolution : float
        Cell side in metres (the voxel resolution).
    origin : Pose2D
        Lower-left corner of cell (0, 0), yaw 0, on a voxel boundary.
    """

    max_z: NDArray[np.float32]
    min_z: NDArray[np.float32]
    mean_z: NDArray[np.float32]
    count: NDArray[np.int32]
    known: NDArray[np.bool_]
    resolution: float
    origin: Pose2D

    def __post_init__(self) -> None:
        shape = self.known.shape
        if len(shape) != 2 or any(
            a.shape != shape for a in (self.max_z, self.min_z, self.mean_z, self.count)
        ):
            raise ValueError("max_z, min_z, mean_z, count and known must be 2D, of one shape")
        _check_resolution(self.resolution)

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.known.shape[0]), int(self.known.shape[1]))

    def to_height_grid(
        self, stat: str = "max", ground: NDArray[np.floating[Any]] | None = None
    ) -> HeightGrid:
        """A height grid of one statistic (``"max"``, ``"min"`` or ``"mean"``).

        With ``ground`` (float (H, W) array, metres, e.g. from :func:`estimate_ground`) the
        heights are above ground, ``z - ground``, and cells where ``ground`` is not finite become
        unknown. Unknown cells hold NaN.
        """
        if stat not in STATS:
            raise ValueError(f"stat must be one of {STATS}, got {stat!r}")
        z = {"max": self.max_z, "min": self.min_z, "mean": self.mean_z}[stat]
        known = self.known.copy()
        if ground is None:
            heights = z.copy()
        else:
            g = np.asarray(ground)
            if g.shape != self.shape:
                raise ValueError(f"ground must have shape {self.shape}, got {g.shape}")
            known &= np.isfinite(g)
            with np.errstate(invalid="ignore"):
                heights = (z.astype(np.float64) - g).astype(np.float32)
        heights[~known] = np.nan
        return HeightGrid(heights, known, self.resolution, self.origin)


def column_stats(
    keys: NDArray[Any],
    occupied: NDArray[Any],
    resolution: float,
    *,
    z_min: float = -math.inf,
    z_max: float = math.inf,
    bounds: Bounds | None = None,
    runs: NDArray[Any] | None = None,
) -> ColumnStats:
    """Max, min, mean centre height and count of the occupied voxels in each column.

    Only occupied voxels whose centre z lies in ``[z_min, z_max]`` count; free voxels only
    widen the grid. The grid frame is chosen exactly as in :func:`project_occupancy` (bounding
    box of all voxels, or ``bounds``), so the two grids line up cell for cell; ``runs`` as
    there (a run counts as its voxels inside the band).

    Raises
    ------
    ValueError
        No voxels, mismatched shapes, a bad band, resolution or box.
    """
    res = _check_resolution(resolution)
    _check_band(z_min, z_max)
    cols = _columns(keys, occupied, res, bounds, runs)
    sel = _select(cols, res, z_min, z_max)
    sel &= cols.occupied
    flat = cols.flat[sel]
    h, w = cols.shape
    n = h * w
    # Work on the integer keys: the centre is monotonic in the key, so the extreme centre is the
    # centre of the extreme key, and the sums stay exact (65535 * 2**37 < 2**53).
    if runs is None:  # single voxels (the octree's): no clipping, the fast path
        lo16 = hi16 = cols.kz[sel]
        count = np.bincount(flat, minlength=n)
        ksum = np.bincount(flat, weights=lo16, minlength=n)
    else:
        # Each run clipped to the band: keys lo..hi, all inside it; a run's key sum is
        # (lo + hi) * length / 2, an integer.
        lo_band, hi_band = _band_keys(res, z_min, z_max)
        lo = np.maximum(cols.kz[sel], lo_band).astype(np.int64)
        hi = np.minimum(cols.top[sel], hi_band).astype(np.int64)
        length = hi - lo + 1
        count = np.bincount(flat, weights=length, minlength=n).astype(np.int64)
        ksum = np.bincount(flat, weights=(lo + hi) * length // 2, minlength=n)
        lo16, hi16 = lo.astype(np.uint16), hi.astype(np.uint16)
    known = count > 0
    kmax = np.zeros(n, dtype=np.uint16)
    kmin = np.full(n, _KEY_MAX, dtype=np.uint16)
    np.maximum.at(kmax, flat, hi16)
    np.minimum.at(kmin, flat, lo16)
    centres = _key_centres(res)

    def grid(values: NDArray[np.float64]) -> NDArray[np.float32]:
        out = np.where(known, values, np.nan).astype(np.float32)
        return out.reshape(h, w)

    with np.errstate(invalid="ignore", divide="ignore"):
        kmean = ksum / count
    return ColumnStats(
        max_z=grid(centres[kmax]),
        min_z=grid(centres[kmin]),
        mean_z=grid(key_to_coord(kmean, res)),
        count=count.astype(np.int32).reshape(h, w),
        known=known.reshape(h, w),
        resolution=res,
        origin=cols.origin,
    )


def _window_cells(window_m: float, res: float) -> int:
    """An odd window side in cells (odd so that the filter is centred on the cell)."""
    if not (window_m > 0 and math.isfinite(window_m)):
        raise ValueError(f"window_m must be a positive number of metres, got {window_m}")
    k = max(1, round(window_m / res))
    return k if k % 2 else k + 1


def _nearest_known(
    values: NDArray[np.float32], known: NDArray[np.bool_], sampling: float
) -> tuple[NDArray[np.float32], NDArray[np.float64]]:
    """Every cell's value taken from its nearest known cell, and the distance to it."""
    from scipy import ndimage

    dist, (rows, cols) = ndimage.distance_transform_edt(
        ~known, sampling=sampling, return_distances=True, return_indices=True
    )
    return values[rows, cols], dist


def estimate_ground(stats: ColumnStats, *, window_m: float = 2.0) -> NDArray[np.float32]:
    """A ground height (metres) for every cell, to get heights above ground.

    Method: take the lowest occupied voxel centre of each column (``min_z``), fill columns
    without one from their nearest column with one (Euclidean distance), then apply a grey-scale
    morphological opening (a min filter followed by a max filter) over a square window of about
    ``window_m`` metres (rounded to an odd number of cells). The opening removes everything
    narrower than the window that stands up from the floor (boxes, furniture, people) and leaves
    planes, slopes included, unchanged.

    Limits: objects wider than the window count as ground; a surface under an object is
    estimated from the floor beside it (errors up to slope x object width); within half a window
    of the grid's edge an upward slope is flattened (up to slope x ``window_m`` / 2); a spurious
    voxel below the floor makes a pit the opening keeps.

    Returns
    -------
    float32 array, shape ``stats.shape``

    Raises
    ------
    ValueError
        ``window_m`` not positive, or no column has an occupied voxel.
    """
    k = _window_cells(window_m, stats.resolution)
    if not stats.known.any():
        raise ValueError("cannot estimate the ground: no column has an occupied voxel")
    from scipy import ndimage

    lowest = stats.min_z
    if not stats.known.all():
        lowest, _ = _nearest_known(lowest, stats.known, 1.0)
    ground = ndimage.grey_opening(lowest, size=(k, k), mode="nearest")
    return np.asarray(ground, dtype=np.float32)


def fill_nearest(grid: HeightGrid, *, max_distance_m: float | None = None) -> HeightGrid:
    """Fill unknown cells with the height of the nearest known cell (CloudCompare's "nearest").

    Distances are between cell centres, in metres; with ``max_distance_m`` a cell farther than
    that from every known cell stays unknown. Known cells keep their heights. Ties between
    equally near cells are broken by scipy's exact Euclidean distance transform.

    Returns
    -------
    HeightGrid
        A new grid whose ``known`` includes the filled cells.
    """
    if max_distance_m is not None and not max_distance_m >= 0:
        raise ValueError(f"max_distance_m must be >= 0 metres or None, got {max_distance_m}")
    heights = grid.heights.copy()
    known = grid.known.copy()
    if known.all() or not known.any():
        return HeightGrid(heights, known, grid.resolution, grid.origin)
    nearest, dist = _nearest_known(grid.heights, grid.known, grid.resolution)
    fill = ~known
    if max_distance_m is not None:
        # A relative tolerance so that a distance of exactly max_distance_m counts.
        fill &= dist <= max_distance_m * (1 + 1e-9)
    heights[fill] = nearest[fill]
    known |= fill
    return HeightGrid(heights, known, grid.resolution, grid.origin)


def fill_idw(
    grid: HeightGrid, *, window: int = 3, power: float = 2.0, metric: str = "euclidean"
) -> HeightGrid:
    """Fill unknown cells by inverse-distance weighting of the known cells near them.

    An unknown cell gets ``sum(w_i h_i) / sum(w_i)`` over the known cells i in the
    ``(2 * window + 1)^2`` cells centred on it, with ``w_i = d_i ** -power`` and ``d_i`` the
    distance in cells (``"euclidean"``, or ``"chebyshev"`` = max(|drow|, |dcol|)). This is how
    PDAL's writers.gdal fills empty cells with ``window_size``; PDAL itself uses
    ``metric="chebyshev"``, ``power=1``. Only the original known cells are donors (filled cells
    never feed others), cells with no known cell in their window stay unknown, and known cells
    keep their heights. Every filled value is a weighted mean of its donors, so it lies within
    their range.

    Returns
    -------
    HeightGrid
        A new grid whose ``known`` includes the filled cells.
    """
    if isinstance(window, bool) or not isinstance(window, (int, np.integer)) or window < 1:
        raise ValueError(f"window must be an integer >= 1 (cells), got {window!r}")
    if not (power >= 0 and math.isfinite(power)):
        raise ValueError(f"power must be a finite number >= 0, got {power}")
    if metric not in METRICS:
        raise ValueError(f"metric must be one of {METRICS}, got {metric!r}")
    from scipy import ndimage

    known = grid.known
    offsets = np.arange(-window, window + 1, dtype=np.float64)
    du, dv = np.meshgrid(offsets, offsets)
    d = np.hypot(du, dv) if metric == "euclidean" else np.maximum(np.abs(du), np.abs(dv))
    d[window, window] = 1.0  # the centre is never a donor (it is unknown); avoid 0 ** -p
    weights = d**-power
    weights[window, window] = 0.0
    values = np.where(known, grid.heights.astype(np.float64), 0.0)
    num = ndimage.correlate(values, weights, mode="constant", cval=0.0)
    den = ndimage.correlate(known.astype(np.float64), weights, mode="constant", cval=0.0)
    fill = ~known & (den > 0)
    heights = grid.heights.copy()
    if fill.any():
        # A weighted mean cannot leave its donors' range, but rounding (donors of mixed signs and
        # magnitudes) could by an ulp; clipping to the known range keeps that bound exact.
        donors = grid.heights[known]
        filled = np.clip(num[fill] / den[fill], donors.min(), donors.max())
        heights[fill] = filled.astype(np.float32)
    return HeightGrid(heights, known | fill, grid.resolution, grid.origin)
