"""Column statistics of points, kept in tiles that merge exactly: the streaming 2.5D grid.

Points go straight into grid columns, no octree: each cell of the global lattice (resolution
``r``; cell ``(row, col) = (coord_cell(y), coord_cell(x))``, OctoMap's key rule on the float32
point, ``floor(double(float32(v)) * (1.0 / r))``, so the octree's voxel columns, also for points
at cell edges) keeps the number of points whose z voxel lies in the band, their integer z sum
(``round(z * SUM_SCALE)``, for the mean) and their float32 minimum and maximum. Every one of
these merges exactly and in any order (integer addition, min, max), so a grid built from any
split of the points, merged in any order, on one process or many, is the same grid, bit for bit.

Cells live in tiles of ``tile x tile`` cells, allocated when a point first lands in them, so
memory follows the area covered, not the number of points: a :class:`TileSet` is the output grid
(24 bytes a cell) plus the chunk being added.

Heights are the points' own z (as PDAL's ``writers.gdal`` and CloudCompare's rasteriser give
them), not voxel centres; but which points count is the octree's choice: the z band tests the
centre of the point's z voxel, as the octree's projection does. The mean is exact to 1/SUM_SCALE m.
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from scan2terrain.grids.projection import STATS, ColumnStats
from scan2terrain.octree.keys import coord_cell
from scan2terrain.types import OCCUPIED, UNKNOWN, HeightGrid, OccupancyGrid, Pose2D

#: Points per thread at least before :meth:`TileSet.add_points` uses another thread.
_PER_THREAD = 1 << 17
#: Points binned on threads at a time (their sorted record indices and z: 32 MB at most).
_PIECE = 1 << 21
#: Buckets of the threaded binning are bands of a tile: 2^_BAND_BITS a tile (32 rows of 256).
_BAND_BITS = 3

#: Heights are summed as integers in units of 1/SUM_SCALE m (2^-14 m, 0.06 mm): integer sums
#: are associative, float sums are not. int64 holds 5.6e14 m of summed height per cell.
SUM_SCALE = 16384.0


@dataclass(frozen=True)
class Lattice:
    """The grid every partial result shares: cell size (metres), tile side (cells) and the z band
    (metres, inclusive) of the points that count."""

    resolution: float
    tile: int = 256
    z_min: float = -math.inf
    z_max: float = math.inf

    def __post_init__(self) -> None:
        if not (self.resolution > 0 and math.isfinite(self.resolution)):
            raise ValueError(f"resolution must be a positive number of metres: {self.resolution}")
        if self.tile < 1 or self.tile & (self.tile - 1):
            raise ValueError(f"tile must be a power of two (cells): {self.tile}")
        if math.isnan(self.z_min) or math.isnan(self.z_max) or self.z_min > self.z_max:
            raise ValueError(f"need z_min <= z_max: {self.z_min}, {self.z_max}")

    def z_limits(self) -> tuple[float, float]:
        """The z band as limits on the points' float64 z: ``lo <= z <= hi`` exactly when the
        point's z voxel (:func:`~scan2terrain.octree.keys.coord_cell`) has its centre in
        [z_min, z_max], as the octree's projection selects voxels (a test as cheap as one on
        the point's z). ±inf: unbounded."""
        return _z_limits(self.resolution, self.z_min, self.z_max)


#: The largest float32, as float64: z beyond it is not finite as float32 (not counted).
_F32_MAX = float(np.finfo(np.float32).max)


def _ordered(v: float) -> int:
    """float64 -> int, order-preserving (adjacent floats: adjacent ints)."""
    b = int(np.float64(v).view(np.int64))
    return b if b >= 0 else -(b & 0x7FFF_FFFF_FFFF_FFFF)


def _unordered(o: int) -> float:
    b = o if o >= 0 else (-o) | -0x8000_0000_0000_0000
    return float(np.int64(b).view(np.float64))


def _first(pred: Callable[[float], bool]) -> float:
    """The least finite float64 in [-_F32_MAX, _F32_MAX] where ``pred`` (False, then True along
    the floats) holds; inf if none."""
    lo, hi = _ordered(-_F32_MAX), _ordered(_F32_MAX)
    if not pred(_unordered(hi)):
        return math.inf
    while lo < hi:
        mid = (lo + hi) // 2
        if pred(_unordered(mid)):
            hi = mid
        else:
            lo = mid + 1
    return _unordered(lo)


@functools.cache
def _z_limits(resolution: float, z_min: float, z_max: float) -> tuple[float, float]:
    inv = 1.0 / resolution

    def centre(z: float) -> float:
        # key_to_coord of the point's z key: (key - KEY_OFFSET + 0.5) * resolution, exactly.
        return (float(coord_cell(z, inv)) + 0.5) * resolution

    # The voxel centre is monotonic in z: the band's points are an interval of z.
    lo = -math.inf if z_min == -math.inf else _first(lambda z: centre(z) >= z_min)
    hi = math.inf
    if z_max != math.inf:
        above = _first(lambda z: centre(z) > z_max)
        hi = _F32_MAX if above == math.inf else float(np.nextafter(above, -math.inf))
    return lo, hi


@dataclass(frozen=True)
class TileRecords:
    """The cells with a point of a :class:`TileSet`: ``tiles`` (n, 2) tile row and column;
    tile k's cells are ``cell[ends[k - 1]:ends[k]]`` (index in the tile, row-major) with their
    24-byte ``records`` (m, 3) int64 as in the tile set."""

    lattice: Lattice
    tiles: NDArray[np.int64]
    ends: NDArray[np.int64]
    cell: NDArray[np.uint32]
    records: NDArray[np.int64]

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in (self.tiles, self.ends, self.cell, self.records))


class TileSet:
    """Per-cell count, z sum, min and max of points, in tiles of the lattice.

    Storage: ``cells`` int64 ``(n_tiles, tile * tile, 3)``, one 24-byte record per cell: count,
    z sum (units of 1/SUM_SCALE m), then float32 min and max in the last word (the kernels
    read them; :attr:`count` is the counts; min/max meaningful where count > 0). ``index``
    maps a tile ``(tile_row, tile_col)`` to its row. Rows beyond ``len(index)`` are spare
    capacity: zeroed virtual memory that costs nothing until written.

    ``threads``: a chunk of ``2^18`` points or more is binned on that many threads (the
    streamed path's single process); the records, and the order of the tiles, are those one
    thread gives.
    """

    def __init__(self, lattice: Lattice, threads: int = 1) -> None:
        self.lattice = lattice
        #: Threads :meth:`add_points` bins a large chunk on (the records do not depend on it).
        self.threads = max(1, int(threads))
        self.index: dict[tuple[int, int], int] = {}
        self.cells: NDArray[np.int64] = np.zeros((0, lattice.tile**2, 3), dtype=np.int64)

    @property
    def count(self) -> NDArray[np.int64]:
        return self.cells[..., 0]

    @property
    def points(self) -> int:
        """Points counted so far (in the band)."""
        return int(self.count[: len(self.index)].sum())

    @property
    def nbytes(self) -> int:
        """Bytes of the tiles in use."""
        return int(self.cells[: len(self.index)].nbytes)

    def __getstate__(self) -> dict[str, object]:
        # What travels (to and from Dask workers, or a pickle) is the cells with a point.
        return {"lattice": self.lattice, "records": self.records()}

    def __setstate__(self, state: dict[str, Any]) -> None:
        TileSet.__init__(self, state["lattice"])
        self.merge(state["records"])

    def clear(self) -> None:
        """Drop every tile (their memory is freed), as when just made."""
        self.index = {}
        self.cells = np.zeros((0, self.lattice.tile**2, 3), dtype=np.int64)

    # --- adding -------------------------------------------------------------------------------

    def add_points(self, points: NDArray[np.floating]) -> int:
        """Count every point (x, y, z, metres, shape (N, 3)) whose z is in the band; non-finite
        points are skipped. Returns how many counted."""
        from scan2terrain.grids import _tile_kernels as K

        pts = np.ascontiguousarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"points must be an (N, 3) array, got shape {pts.shape}")
        lat = self.lattice
        inv = 1.0 / lat.resolution
        band = lat.z_limits()
        threads = min(self.threads, len(pts) // _PER_THREAD)
        if threads > 1:
            with ThreadPoolExecutor(threads) as pool:
                return self._add_threaded(pts, inv, band, pool, threads)
        x0, y0, x1, y1, n = K.extent(pts, band)
        if n == 0:
            return 0
        shift = lat.tile.bit_length() - 1
        tr0, tc0, flags = self._flags((x0, y0, x1, y1), [pts], None)
        slots = np.full(flags.shape, -1, dtype=np.int64)
        for r, c in zip(*np.nonzero(flags), strict=True):
            slots[r, c] = self._slot((int(r) + tr0, int(c) + tc0))
        cells = self.cells
        K.accumulate(
            pts, inv, band, shift, SUM_SCALE, tr0, tc0, slots,
            cells, cells.view(np.float32),
        )  # fmt: skip
        return int(n)

    def _flags(
        self,
        box: tuple[float, float, float, float],
        parts: list[NDArray[np.float64]],
        pool: ThreadPoolExecutor | None,
    ) -> tuple[int, int, NDArray[np.uint8]]:
        """(first tile row, first tile column, flags) over the tile extent of ``box`` (x0, y0,
        x1, y1 of the usable points): 1 where a tile holds a usable point of ``parts`` (the
        chunk's points, flagged side by side on ``pool`` when given)."""
        from scan2terrain.grids import _tile_kernels as K

        lat = self.lattice
        inv = 1.0 / lat.resolution
        band = lat.z_limits()
        shift = lat.tile.bit_length() - 1
        x0, y0, x1, y1 = box
        # A point's cell is monotonic in its coordinate: the extreme points hold the extreme tiles.
        tr0, tr1 = (coord_cell(v, inv) >> shift for v in (y0, y1))
        tc0, tc1 = (coord_cell(v, inv) >> shift for v in (x0, x1))
        # A table over the chunk's tile extent: 8 bytes per tile, while the grid those tiles
        # would become is >= 17 bytes per *cell*, so the table never dominates.
        shape = (tr1 - tr0 + 1, tc1 - tc0 + 1)
        if shape == (1, 1):
            return tr0, tc0, np.ones(shape, dtype=np.uint8)
        tables = [np.zeros(shape, dtype=np.uint8) for _ in parts]

        def flag(k: int) -> None:
            K.flag_tiles(parts[k], inv, band, shift, tr0, tc0, tables[k])

        list(map(flag, range(len(parts))) if pool is None else pool.map(flag, range(len(parts))))
        return tr0, tc0, np.bitwise_or.reduce(tables)

    def _add_threaded(
        self,
        pts: NDArray[np.float64],
        inv: float,
        band: tuple[float, float],
        pool: ThreadPoolExecutor,
        threads: int,
    ) -> int:
        """:meth:`add_points` on ``threads`` threads, with the same records and tiles in the
        same order: the chunk's tiles get their rows as one thread gives them, then
        ``_PIECE`` points at a time each thread counts and places its range of the piece by
        bucket (``_tile_kernels``), and adds whole buckets."""
        from scan2terrain.grids import _tile_kernels as K

        def ranges(a: NDArray[np.float64]) -> list[NDArray[np.float64]]:
            edges = [len(a) * k // threads for k in range(threads + 1)]
            return [a[i:j] for i, j in itertools.pairwise(edges)]

        parts = ranges(pts)
        ext = list(pool.map(lambda p: K.extent(p, band), parts))
        n = sum(int(e[4]) for e in ext)
        if n == 0:
            return 0
        box = (
            min(e[0] for e in ext), min(e[1] for e in ext),
            max(e[2] for e in ext), max(e[3] for e in ext),
        )  # fmt: skip
        tr0, tc0, flags = self._flags(box, parts, pool)
        rows, cols = np.nonzero(flags)
        local = np.full(flags.shape, -1, dtype=np.int64)
        local[rows, cols] = np.arange(len(rows))
        slot_of = np.array(
            [self._slot((int(r) + tr0, int(c) + tc0)) for r, c in zip(rows, cols, strict=True)],
            dtype=np.int64,
        )
        cells = self.cells  # after _slot: it may have grown
        shift = self.lattice.tile.bit_length() - 1
        band_shift = max(shift - _BAND_BITS, 0)
        n_bands = 1 << (shift - band_shift)
        n_buckets = len(rows) * n_bands
        geometry = (inv, band, shift, band_shift, n_bands, tr0, tc0, local)
        for s in range(0, len(pts), _PIECE):  # 16 bytes a point of a piece
            _bin_piece(ranges(pts[s : s + _PIECE]), geometry, slot_of, n_buckets, cells, pool)
        return n

    def _slot(self, key: tuple[int, int]) -> int:
        slot = self.index.get(key)
        if slot is None:
            slot = len(self.index)
            if slot == len(self.cells):
                self._grow()
            self.index[key] = slot
        return slot

    def _grow(self) -> None:
        n = len(self.index)
        # np.zeros maps pages lazily: the spare rows cost address space, not memory.
        new = np.zeros((max(4, 2 * n), *self.cells.shape[1:]), dtype=np.int64)
        new[:n] = self.cells[:n]
        self.cells = new

    # --- merging ------------------------------------------------------------------------------

    def records(self) -> TileRecords:
        """The cells with a point, tile by tile: bytes by the cells that hold points, not by
        the area of their tiles (what a Dask task sends back)."""
        n = len(self.index)
        # Tiles get rows 0, 1, ... as they are first met: the index lists them in row order.
        keys = np.array(list(self.index), dtype=np.int64).reshape(n, 2)
        slot, cell = np.nonzero(self.count[:n] > 0)
        return TileRecords(
            self.lattice,
            keys,
            np.cumsum(np.bincount(slot, minlength=n)),
            cell.astype(np.uint32),
            self.cells[slot, cell],
        )

    def merge(self, other: TileSet | TileRecords) -> None:
        """Add another partial result of the same lattice (exact, in any order)."""
        if other.lattice != self.lattice:
            raise ValueError(f"cannot merge tiles of {other.lattice} into {self.lattice}")
        rec = other.records() if isinstance(other, TileSet) else other
        slots = np.array([self._slot((r, c)) for r, c in rec.tiles.tolist()], dtype=np.int64)
        t2 = self.lattice.tile**2
        rows = np.repeat(slots, np.diff(rec.ends, prepend=0)) * t2 + rec.cell
        flat = self.cells.reshape(-1, 3)  # after _slot: it may have grown
        mine, theirs = flat[rows], rec.records
        fresh = mine[:, 0] == 0
        lo, hi = mine.view(np.float32)[:, 4], mine.view(np.float32)[:, 5]
        olo, ohi = theirs.view(np.float32)[:, 4], theirs.view(np.float32)[:, 5]
        np.minimum(lo, olo, out=lo)
        np.maximum(hi, ohi, out=hi)
        lo[fresh] = olo[fresh]  # a cell's first points set min and max (the storage's 0s don't)
        hi[fresh] = ohi[fresh]
        mine[:, :2] += theirs[:, :2]
        flat[rows] = mine

    # --- results ------------------------------------------------------------------------------

    def _known_box(self) -> tuple[int, int, int, int]:
        """(row0, col0, row1, col1), inclusive global cells, of the cells with a point."""
        t = self.lattice.tile
        box = [math.inf, math.inf, -math.inf, -math.inf]
        for (tr, tc), s in self.index.items():
            occupied = self.count[s].reshape(t, t) > 0
            rows = np.flatnonzero(occupied.any(axis=1))
            if len(rows) == 0:
                continue
            cols = np.flatnonzero(occupied.any(axis=0))
            box[0] = min(box[0], tr * t + rows[0])
            box[1] = min(box[1], tc * t + cols[0])
            box[2] = max(box[2], tr * t + rows[-1])
            box[3] = max(box[3], tc * t + cols[-1])
        if box[0] == math.inf:
            raise ValueError("no point in the z band: the grid is empty")
        return int(box[0]), int(box[1]), int(box[2]), int(box[3])

    def _paste(
        self,
        box: tuple[int, int, int, int],
        values: Callable[[NDArray[np.int64]], NDArray[Any]],
        dtype: type[Any],
        fill: Any = 0,
    ) -> NDArray[Any]:
        """A dense grid over ``box`` of ``values(records)`` computed tile by tile (``records``:
        one tile's (t, t, 3) int64 cell records), ``fill`` where no tile is. Only one tile's
        temporaries exist at a time: the peak is the tiles plus the grid returned."""
        r0, c0, r1, c1 = box
        t = self.lattice.tile
        out = np.full((r1 - r0 + 1, c1 - c0 + 1), fill, dtype=dtype)
        for (tr, tc), s in self.index.items():
            # The tile's rows/cols clipped to the box, in global cells.
            gr0, gc0 = max(tr * t, r0), max(tc * t, c0)
            gr1, gc1 = min(tr * t + t, r1 + 1), min(tc * t + t, c1 + 1)
            if gr0 >= gr1 or gc0 >= gc1:
                continue
            records = self.cells[s].reshape(t, t, 3)[
                gr0 - tr * t : gr1 - tr * t, gc0 - tc * t : gc1 - tc * t
            ]
            out[gr0 - r0 : gr1 - r0, gc0 - c0 : gc1 - c0] = values(records)
        return out

    def grid_shape(self) -> tuple[int, int]:
        """Rows and columns of the dense grid :meth:`heights` / :meth:`occupancy` would return
        (the bounding box of the cells with a point), without allocating it."""
        r0, c0, r1, c1 = self._known_box()
        return r1 - r0 + 1, c1 - c0 + 1

    def origin_of(self, box: tuple[int, int, int, int]) -> Pose2D:
        r = self.lattice.resolution
        return Pose2D(box[1] * r, box[0] * r, 0.0)

    def heights(self, stat: str, occupied: ColumnStats | None = None) -> HeightGrid:
        """One statistic of the points' z per cell (``"max"``, ``"min"`` or ``"mean"``, metres,
        float32, NaN where no point) over the bounding box of the cells with a point; the same
        values as :meth:`column_stats`, without its other grids (5 bytes a cell, not 17).

        ``occupied``: the occupied voxels' column statistics of an octree on the same lattice
        (:func:`~scan2terrain.grids.projection.column_stats`, any frame), for points that were
        ray-cast, where later rays may have cleared some of their voxels: only columns with an
        occupied voxel are known, and in a column with points beyond its occupied voxels the
        height is kept between the outer faces of those voxels (the octree says what is
        there, the points say where exactly). Points inserted as end points occupy every voxel
        they hit (the same cell rule), so it changes nothing for them."""
        if stat not in STATS:
            raise ValueError(f"stat must be one of {STATS}, got {stat!r}")
        box = self._known_box()
        heights = self._paste(box, _STAT[stat], np.float32, np.nan)
        known = self._paste(box, _known, np.bool_, False)
        if occupied is not None:
            self._within(heights, known, box, occupied)
        return HeightGrid(heights, known, self.lattice.resolution, self.origin_of(box))

    def _within(
        self,
        heights: NDArray[np.float32],
        known: NDArray[np.bool_],
        box: tuple[int, int, int, int],
        occupied: ColumnStats,
    ) -> None:
        """:meth:`heights` bounded by the octree's occupied voxels, in place."""
        r = self.lattice.resolution
        if not math.isclose(occupied.resolution, r, rel_tol=1e-12):
            raise ValueError(f"occupied has {occupied.resolution} m cells, the tiles {r} m")
        inv = 1.0 / r
        # The octree's frame in the tiles' one: its origin is on a voxel edge.
        r0 = round(occupied.origin.y * inv) - box[0]
        c0 = round(occupied.origin.x * inv) - box[1]
        h, w = heights.shape
        rows, cols = occupied.shape
        a0, a1 = max(r0, 0), min(r0 + rows, h)
        b0, b1 = max(c0, 0), min(c0 + cols, w)
        inside = np.zeros_like(known)
        lo = np.zeros((h, w), dtype=np.float64)  # z cells of the lowest and highest voxel
        hi = np.zeros((h, w), dtype=np.float64)
        if a0 < a1 and b0 < b1:
            src = np.s_[a0 - r0 : a1 - r0, b0 - c0 : b1 - c0]
            inside[a0:a1, b0:b1] = occupied.known[src]
            # Voxel centres back to cells (exact: a centre is half a cell from either edge).
            lo[a0:a1, b0:b1] = np.floor(occupied.min_z[src].astype(np.float64) * inv)
            hi[a0:a1, b0:b1] = np.floor(occupied.max_z[src].astype(np.float64) * inv)
        known &= inside
        # Columns whose highest or lowest point lies in a voxel the octree does not hold
        # occupied: the keys of real float32 points, as the octree keyed them (a mean is no
        # point: its integer sum may sit a hair past a face its points are within).
        top = self._paste(box, _STAT["max"], np.float32, np.nan).astype(np.float64)
        bottom = self._paste(box, _STAT["min"], np.float32, np.nan).astype(np.float64)
        with np.errstate(invalid="ignore"):
            past = known & ((np.floor(top * inv) > hi) | (np.floor(bottom * inv) < lo))
        heights[past] = np.clip(heights[past], lo[past] * r, (hi[past] + 1) * r)
        heights[~known] = np.nan

    def cell_spreads(self) -> NDArray[np.float32]:
        """The z spread (max - min, metres) of every cell holding two points or more, in no
        particular order: what one height per cell leaves out."""
        t2 = self.lattice.tile**2
        parts = [np.zeros(0, dtype=np.float32)]
        for s in range(len(self.index)):  # a tile at a time: its temporaries only
            records = self.cells[s].reshape(t2, 3)
            two = records[:, 0] >= 2
            if two.any():
                z = np.ascontiguousarray(records[two, 2]).view(np.float32).reshape(-1, 2)
                parts.append(z[:, 1] - z[:, 0])
        return np.concatenate(parts)

    def column_stats(self) -> ColumnStats:
        """The merged grid as :class:`ColumnStats` over the bounding box of the cells with a
        point (the box does not depend on the tile size): max/min/mean z in metres, NaN where no
        point; count (int32, saturated)."""
        box = self._known_box()
        z = {k: self._paste(box, f, np.float32, np.nan) for k, f in _STAT.items()}
        return ColumnStats(
            max_z=z["max"],
            min_z=z["min"],
            mean_z=z["mean"],
            count=self._paste(box, _count32, np.int32),
            known=self._paste(box, _known, np.bool_, False),
            resolution=self.lattice.resolution,
            origin=self.origin_of(box),
        )

    def occupancy(self) -> OccupancyGrid:
        """Cells with a point occupied, the rest unknown: end points see no free space. The same
        grid as the octree's end points projected (``project_occupancy``) without a z band."""
        box = self._known_box()
        data = self._paste(box, _occupancy, np.int8, UNKNOWN)
        return OccupancyGrid(data, self.lattice.resolution, self.origin_of(box))


def _bin_piece(
    parts: list[NDArray[np.float64]],
    geometry: tuple[Any, ...],
    slot_of: NDArray[np.int64],
    n_buckets: int,
    cells: NDArray[np.int64],
    pool: ThreadPoolExecutor,
) -> None:
    """``parts`` of a piece of points (one a thread) counted, placed by bucket and added
    (``_tile_kernels``; ``geometry``: the kernels' lattice arguments)."""
    from scan2terrain.grids import _tile_kernels as K

    threads = len(parts)
    counts = np.zeros((threads, n_buckets), dtype=np.int64)

    def count(k: int) -> None:
        K.bucket_counts(parts[k], *geometry, counts[k])

    list(pool.map(count, range(threads)))
    # Bucket by bucket, thread by thread: where each thread places its points of a bucket.
    ends = np.cumsum(counts.T.ravel()).reshape(n_buckets, threads)
    at = np.ascontiguousarray((ends - counts.T).T)
    m = int(ends[-1, -1])
    keys = np.empty(m, dtype=np.int64)
    zs = np.empty(m, dtype=np.float64)

    def put(k: int) -> None:
        K.place(parts[k], *geometry, slot_of, at[k], keys, zs)

    list(pool.map(put, range(threads)))
    # Whole buckets to each thread, about m / threads points each.
    bucket_end = ends[:, -1]
    cuts = np.searchsorted(bucket_end, [m * k // threads for k in range(1, threads)])
    bounds = [0, *(int(bucket_end[c]) for c in cuts), m]

    def add(k: int) -> None:
        a, b = bounds[k], bounds[k + 1]
        K.add_sorted(keys[a:b], zs[a:b], SUM_SCALE, cells, cells.view(np.float32))

    list(pool.map(add, range(threads)))


# Per-tile views of the cell records (count, z sum, float32 min|max): each returns the values of
# one statistic for a (rows, cols, 3) block, NaN / False / UNKNOWN where a cell has no point.


def _known(r: NDArray[np.int64]) -> NDArray[np.bool_]:
    known: NDArray[np.bool_] = r[..., 0] > 0
    return known


def _count32(r: NDArray[np.int64]) -> NDArray[np.int32]:
    return np.minimum(r[..., 0], np.iinfo(np.int32).max).astype(np.int32)


def _word(r: NDArray[np.int64], k: int) -> NDArray[np.float32]:
    # The third int64 holds the two float32 words 4 and 5 of the record: min (k = 0), max (1).
    z = np.ascontiguousarray(r[..., 2]).view(np.float32).reshape(*r.shape[:-1], 2)[..., k]
    out: NDArray[np.float32] = np.where(r[..., 0] > 0, z, np.float32(np.nan))
    return out


def _mean(r: NDArray[np.int64]) -> NDArray[np.float32]:
    n = r[..., 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = r[..., 1] / n / SUM_SCALE
    return np.where(n > 0, mean, np.nan).astype(np.float32)


def _occupancy(r: NDArray[np.int64]) -> NDArray[np.int8]:
    data: NDArray[np.int8] = np.where(r[..., 0] > 0, np.int8(OCCUPIED), np.int8(UNKNOWN))
    return data


_STAT: dict[str, Callable[[NDArray[np.int64]], NDArray[np.float32]]] = {
    "max": lambda r: _word(r, 1),
    "min": lambda r: _word(r, 0),
    "mean": _mean,
}
