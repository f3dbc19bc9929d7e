"""A sparse voxel octree with OctoMap's probabilistic model.

Voxels are keyed like OctoMap's depth-16 leaves (16 bits per axis, ``key = floor(x / res) +
32768``) and stored in dense 8 x 8 x 8 blocks behind a hash of block coordinates: a leaf is a
float32 log-odds (queries give NaN when unknown). The blocks' values are stored layer by layer (8 x
8 voxels at one z), unknown as zeroed memory, so a layer no voxel was written to takes no memory: a
planar laser's voxels fill one layer of a block's eight. End points only (``insert_endpoints``)
keep blocks with few voxels in a sparse store instead, a voxel-level hash (see _sparse.py); every
query reads both. Inner nodes are not stored; a coarser depth is computed on demand as the maximum
of its known voxels, which is what OctoMap's inner nodes hold. OctoMap's pruning is lossless (it
merges 8 equal children), so the voxel values here equal OctoMap's leaf values.
"""

from __future__ import annotations

import contextlib
import math
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from scan2terrain._numba import numba
from scan2terrain.errors import InputError
from scan2terrain.octree import (
    _batch,
    _group,
    _points,
    _raybox,
    _raycast,
    _sparse,
    _table,
    _waves,
)
from scan2terrain.octree import _kernels as K
from scan2terrain.octree.keys import KEY_OFFSET, key_to_coord

TREE_DEPTH = 16
#: Scans of fewer rays (end points: 16 points count as one ray) run on one core.
PARALLEL_MIN_RAYS = 4096
#: Largest per-scan dense block index (int32 entries): 64 MB.
MAX_DENSE = 1 << 24
#: A scan of PARALLEL_MIN_RAYS rays or more is cast into its own box of bits (_raybox.py) when
#: the box has at most this many blocks and at most BOX_BLOCKS_PER_RAY blocks a ray (above, most
#: of the box would be empty: long beams in open space); else into the dense store's bits.
MAX_BOX_BLOCKS = 1 << 19
BOX_BLOCKS_PER_RAY = 8
#: End points only: a block with this many known voxels or more is stored densely; below, its
#: voxels stay in the sparse store. A dense block costs ~2.3 KB (values, bits, index), a sparse
#: voxel 11-23 bytes (8 bytes at a load of 0.35-0.7), so 64 voxels keep the sparse store well
#: below the block's cost while most of a surface's blocks (and their fast path) stay dense.
DENSE_MIN = 64


def logodds(p: float) -> np.float32:
    """OctoMap's ``logodds``: computed in double, stored as float."""
    return np.float32(math.log(p / (1.0 - p)))  # type: ignore[no-any-return]


@dataclass(frozen=True)
class SensorModel:
    """OctoMap's sensor model, as probabilities; defaults are OctoMap's own."""

    hit: float = 0.7
    miss: float = 0.4
    clamp_min: float = 0.1192
    clamp_max: float = 0.971
    occupancy: float = 0.5

    def __post_init__(self) -> None:
        for name in ("hit", "miss", "clamp_min", "clamp_max", "occupancy"):
            p = getattr(self, name)
            if not 0.0 < p < 1.0:
                raise ValueError(f"{name} must be a probability in (0, 1), got {p}")
        if not self.miss < 0.5 < self.hit:
            raise ValueError(f"need miss ({self.miss}) < 0.5 < hit ({self.hit})")
        if not self.clamp_min < self.clamp_max:
            raise ValueError("clamp_min must be below clamp_max")


@dataclass(frozen=True)
class InsertStats:
    """What one insertion did."""

    points: int  #: points given
    dropped_nonfinite: int  #: NaN / inf points dropped before insertion
    out_of_range: int  #: end points outside the key range (ray skipped)
    beams_cut: int  #: beams longer than max_range, cut there (they only clear)
    hits: int  #: voxels updated as occupied
    misses: int  #: voxels updated as free


class VoxelOctree:
    """OctoMap-compatible occupancy octree.

    Parameters
    ----------
    resolution : float
        Voxel side in metres.
    model : SensorModel
        Hit/miss probabilities, clamping and occupancy threshold.
    """

    def __init__(
        self,
        resolution: float,
        model: SensorModel | None = None,
        *,
        max_bytes: int | None = None,
    ) -> None:
        if not (resolution > 0 and math.isfinite(resolution)):
            raise ValueError(f"resolution must be a positive number of metres, got {resolution}")
        self.resolution = float(resolution)
        #: Growing the dense store past this many bytes is refused (InputError); None: no limit.
        self.max_bytes = max_bytes
        self.model = model or SensorModel()
        m = self.model
        self._hit, self._miss = logodds(m.hit), logodds(m.miss)
        self._cmin, self._cmax = logodds(m.clamp_min), logodds(m.clamp_max)
        self._occ = logodds(m.occupancy)
        self._model = np.array([self._hit, self._miss, self._cmin, self._cmax], dtype=np.float32)
        # Storage starts small and doubles; see _grow.
        # Log-odds by layer: values[w, block, i] is voxel w * 64 + i of the block (z = w, i = y *
        # 8 + x), +0.0 = unknown (a log-odds of 0 is stored as -0.0, _table.stored). Zeroed
        # memory is mapped lazily: a layer no voxel is written to costs no memory, and a planar
        # laser's voxels (one z) fill one layer of 8.
        self._values = np.zeros((8, 1024, 64), dtype=np.float32)
        # Hit words, then one plane of miss words per thread numba may run.
        threads: int = numba.config.NUMBA_NUM_THREADS  # type: ignore[attr-defined]
        self._bits = np.zeros((1024, 8 * (1 + threads)), dtype=np.uint64)
        self._block_xyz = np.zeros((1024, 3), dtype=np.int32)
        self._stamp = np.full(1024, -1, dtype=np.int64)
        self._table_keys = np.full(4096, _table.EMPTY, dtype=np.int64)
        self._table_slots = np.zeros(4096, dtype=np.int32)
        self._counts = np.zeros(4, dtype=np.int64)  # _table.N_BLOCKS, N_TOUCHED, STAMP, WANTED
        self._touched = np.zeros(1024, dtype=np.int64)
        # The sparse store (end points only): voxel and block tables, (voxels, blocks) per region.
        self._vt = np.zeros(16 * _sparse.NREG, dtype=np.int64)
        self._st = np.zeros(16 * _sparse.NREG, dtype=np.int64)
        self._sparse_counts = np.zeros((_sparse.NREG, 2), dtype=np.int64)
        self._lut, self._max_hits = self._hit_values()
        # Many small scans on every core (_waves.py): the scans' scratch, and the waves cast.
        self._waves: tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.uint64]] | None = None
        self._wave = 0
        # Without a saturating hit count that fits the voxel table (a model needing more than
        # 255 hits to reach clamp_max), every block is dense.
        self._dense_min = DENSE_MIN if self._max_hits > 0 else 0

    def _hit_values(self) -> tuple[NDArray[np.float32], int]:
        """Log-odds of a voxel hit by 0..255 end-point calls from unknown (as apply_blocks
        computes them, float32 and clamped), and the count from which it no longer changes
        (0 if above 255)."""
        lut = np.full(256, np.nan, dtype=np.float32)
        v = np.float32(0.0)  # a new OcTreeNode starts at log-odds 0
        for hits in range(1, 256):  # a table of 255 entries, not a loop over points
            v = np.float32(v + self._hit)
            v = self._cmin if v < self._cmin else (self._cmax if v > self._cmax else v)
            if hits > 1 and v == lut[hits - 1]:
                lut[hits:] = v
                return lut, hits - 1
            lut[hits] = v
        return lut, 0

    # --- insertion ------------------------------------------------------------------------

    def insert_scan(
        self,
        points: NDArray[np.floating],
        origin: NDArray[np.floating] | tuple[float, float, float],
        *,
        max_range: float = -1.0,
    ) -> InsertStats:
        """Insert one scan with ray casting, as OctoMap's ``insertPointCloud``.

        Free: voxels an exact 3D DDA visits from ``origin`` up to (excluding) each end point's
        voxel; occupied: end point voxels; each voxel updated once per scan, occupied wins. Beams
        longer than ``max_range`` (metres; < 0 = unlimited) are cut there and only clear.
        Points are handled as float32, as OctoMap does. NaN/inf points are dropped.
        """
        pts, dropped = self._points(points)
        o32 = self.checked_origin(origin)
        res = self.resolution
        ends, kind, stats = _raycast.scan_rays(pts, o32, float(max_range), res)
        self._next_scan()
        k = self._kernels(len(pts))
        if k is K.PARALLEL and (done := self._cast_box(o32, ends, kind)) is not None:
            hits, misses = done
        else:
            hits, misses = self._cast_blocks(k, o32, ends, kind)
        return InsertStats(len(pts) + dropped, dropped, int(stats[2]), int(stats[1]), hits, misses)

    def checked_origin(
        self, origin: NDArray[np.floating] | tuple[float, float, float]
    ) -> NDArray[np.float32]:
        """A sensor origin as float32, refused (InputError) unless 3 finite numbers in the
        octree's key range."""
        o = np.asarray(origin, dtype=np.float64).reshape(-1)
        if o.shape != (3,) or not np.isfinite(o).all():
            raise InputError(None, f"sensor origin must be 3 finite numbers, got {origin!r}")
        o32 = o.astype(np.float32)
        inv = 1.0 / self.resolution  # coordToKeyChecked, in Python: no kernel call for 3 numbers
        if not all(-KEY_OFFSET <= math.floor(inv * float(c)) < KEY_OFFSET for c in o32):
            half = KEY_OFFSET * self.resolution
            raise InputError(
                None,
                f"sensor origin {tuple(float(c) for c in o)} is outside the octree's key range "
                f"(+-{half:g} m at {self.resolution} m)",
            )
        return o32

    def insert_scans(
        self,
        points: NDArray[np.floating],
        offsets: NDArray[np.integer],
        origins: NDArray[np.floating],
        max_ranges: NDArray[np.floating] | float = -1.0,
    ) -> InsertStats:
        """Insert many scans in order, as many ``insert_scan`` calls would, voxel for voxel.

        Scan s is ``points[offsets[s]:offsets[s + 1]]`` seen from ``origins[s]``, its beams cut
        at ``max_ranges[s]`` (one number: every scan's). Scans of fewer than PARALLEL_MIN_RAYS
        points go in runs: with several threads in waves of two scans a thread, cast side by
        side and applied in order (_waves.py), with one in one serial call (_batch.py); either
        way each scan updates each voxel once, occupied winning, before the next, and the values
        are the same. Larger scans go through insert_scan. Returns the stats summed over the
        scans.
        """
        pts = self._points_any(points)
        off = np.asarray(offsets, dtype=np.int64).reshape(-1)
        n = len(off) - 1
        if n < 0 or off[0] != 0 or off[-1] != len(pts) or (np.diff(off) < 0).any():
            raise ValueError("offsets must rise from 0 to len(points)")
        org = np.asarray(origins, dtype=np.float64)
        if org.shape != (n, 3):
            raise ValueError(f"origins must be ({n}, 3), got {org.shape}")
        mr = np.broadcast_to(np.asarray(max_ranges, dtype=np.float64), (n,))
        for s in np.flatnonzero(~self._in_key_range(org)):  # each refused as insert_scan would
            try:
                self.checked_origin(org[s])
            except InputError as exc:
                raise InputError(None, f"scan {s}: {exc.problem}") from exc
        finite = np.isfinite(pts).all(axis=1)
        dropped = len(pts) - int(finite.sum())
        if dropped:  # NaN / inf points dropped, as insert_scan drops them
            off = np.concatenate([[0], np.cumsum(finite)])[off]
            pts = np.ascontiguousarray(pts[finite])
        org32 = org.astype(np.float32)
        sizes = np.diff(off)
        total = np.zeros(_batch.N_STATS, dtype=np.int64)
        big = np.flatnonzero(sizes >= PARALLEL_MIN_RAYS)
        first = 0
        for b in [*big.tolist(), n]:  # runs of small scans, each large scan on its own
            if b > first:
                self._insert_batch(pts, off[first : b + 1], org32[first:b], mr[first:b], total)
            if b < n:
                self._insert_one(pts[off[b] : off[b + 1]], org[b], float(mr[b]), total)
            first = b + 1
        return InsertStats(
            int(total[0]) + dropped, dropped, int(total[2]), int(total[1]), int(total[3]),
            int(total[4]),
        )  # fmt: skip

    def _insert_one(
        self,
        pts: NDArray[np.float32],
        origin: NDArray[np.floating],
        max_range: float,
        total: NDArray[np.int64],
    ) -> None:
        """One scan through insert_scan, its stats added to insert_scans' ``total``."""
        st = self.insert_scan(pts, origin, max_range=max_range)
        total += (st.points, st.beams_cut, st.out_of_range, st.hits, st.misses)

    def _in_key_range(self, xyz: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Rows of finite coordinates in the key range, computed as checked_origin does."""
        with np.errstate(invalid="ignore", over="ignore"):
            k = np.floor((1.0 / self.resolution) * xyz.astype(np.float32).astype(np.float64))
            return np.asarray(((k >= -KEY_OFFSET) & (k < KEY_OFFSET)).all(axis=1))

    def _insert_batch(
        self,
        pts: NDArray[np.float32],
        off: NDArray[np.int64],
        org32: NDArray[np.float32],
        mr: NDArray[np.float64],
        total: NDArray[np.int64],
    ) -> None:
        """A run of small scans through _batch.insert_batch (the sparse store, which new
        blocks must adopt from, keeps them on insert_scan's path)."""
        if self._sparse_counts[:, 0].any():
            for s in range(len(org32)):
                self._insert_one(pts[off[s] : off[s + 1]], org32[s], float(mr[s]), total)
            return
        local = np.ascontiguousarray(pts[off[0] : off[-1]])
        rel = np.ascontiguousarray(off - off[0])
        if numba.get_num_threads() > 1 and len(org32) > 1:
            self._insert_waves(local, rel, org32, np.ascontiguousarray(mr), total)
            return
        self._insert_serial(local, rel, org32, np.ascontiguousarray(mr), total)

    def _insert_serial(
        self,
        local: NDArray[np.float32],
        rel: NDArray[np.int64],
        org32: NDArray[np.float32],
        mr: NDArray[np.float64],
        total: NDArray[np.int64],
    ) -> None:
        state = np.zeros(4, dtype=np.int64)
        cache = np.full((_batch.CACHE, 4), -1, dtype=np.int64)  # block id, slot, scan
        while True:
            status = _batch.insert_batch(
                local, rel, org32, mr, self.resolution, self._model, self._values, state, total,
                cache, self._storage(),
            )  # fmt: skip
            if status == _table.DONE:
                return
            self._grow(int(status))

    def _insert_waves(
        self,
        local: NDArray[np.float32],
        rel: NDArray[np.int64],
        org32: NDArray[np.float32],
        mr: NDArray[np.float64],
        total: NDArray[np.int64],
    ) -> None:
        """The scans in waves of two per thread (see _waves.py): cast side by side, applied in
        order; a scan that overflows its scratch goes the serial way, in its place."""
        slots = 2 * numba.get_num_threads()
        if self._waves is None or self._waves[0].shape[0] < slots:
            # Zeroed memory: pages are taken only as rows are used. Kept by the tree (a table
            # entry stamped by an earlier wave is stale).
            self._waves = (
                np.zeros((slots, _waves.TABLE, 3), dtype=np.int64),
                np.zeros((slots, _waves.ROWS), dtype=np.int64),
                np.zeros((slots, _waves.ROWS, 16), dtype=np.uint64),
            )
            self._wave = 0
        out = np.zeros((slots, 4), dtype=np.int64)
        state = np.array([0, 0, 0, 0, self._wave], dtype=np.int64)
        while True:
            with numba.parallel_chunksize(1):  # scans handed to the threads as they ask
                storage = self._storage()
                status = _waves.insert_waves(
                    local, rel, org32, mr, self.resolution, self._waves, out, state,
                    self._values, self._model, storage[1], storage[2], storage[3], storage[4],
                    storage[5], total,
                )  # fmt: skip
            if status == _table.DONE:
                break
            if status < 0:  # overflowed: this scan the serial way, then the rest of its wave
                s = int(state[0] + state[2])
                self._insert_serial(
                    np.ascontiguousarray(local[rel[s] : rel[s + 1]]),
                    np.array([0, rel[s + 1] - rel[s]]), org32[s : s + 1], mr[s : s + 1], total,
                )  # fmt: skip
                state[2] += 1
                state[3] = 0
            else:
                self._grow(int(status))
        self._wave = int(state[4])

    def _cast_box(
        self, o32: NDArray[np.float32], ends: NDArray[np.float32], kind: NDArray[np.int8]
    ) -> tuple[int, int] | None:
        """A scan's rays cast into its own box of bits (see _raybox.py), then applied; None
        (nothing changed) when the box is too large or a ray would leave it."""
        b = _raycast.block_bounds(o32, ends, self.resolution)
        lo = np.maximum(b[0] - 1, 0)
        nbk = np.minimum(b[1] + 1, (1 << (TREE_DEPTH - 3)) - 1) - lo + 1
        blocks = int(np.prod(nbk))
        # Rows are 8 words a plane: the limit is on blocks, the same for any thread count.
        if blocks > MAX_BOX_BLOCKS or blocks > BOX_BLOCKS_PER_RAY * len(ends):
            return None
        planes = 1 + numba.get_num_threads()
        with _zeroed_words(planes * blocks * 8) as words:
            # Plane 0 the hits, plane 1 + t thread t's misses: a thread writes its own memory.
            bits = words.reshape(planes, blocks, 8)
            lo_key = lo * 8
            with numba.parallel_chunksize(1):
                left = _raybox.cast_box(o32, ends, kind, self.resolution, lo_key, nbk, bits)
            if left:
                words[:] = 0
                return None
            rows = np.empty(blocks, dtype=np.int64)
            first_new = self.n_blocks
            self._until_done(
                lambda i: _raybox.alloc_box(bits, lo_key, nbk, i, rows, *self._storage()[1:])
            )
            self._counts[_table.N_TOUCHED] = 0  # apply_box goes by rows, not the touched list
            self._fresh_blocks(first_new)
            self._adopt(np.arange(first_new, self.n_blocks))
            with numba.parallel_chunksize(1024):  # rows handed out as threads ask, as the rays
                hits, misses = _raybox.apply_box(self._values, bits, rows, self._model)
        return int(hits), int(misses)

    def _cast_blocks(
        self,
        k: K.Kernels,
        o32: NDArray[np.float32],
        ends: NDArray[np.float32],
        kind: NDArray[np.int8],
    ) -> tuple[int, int]:
        """A scan's rays cast into the dense store's bits (see _raycast.py), then applied."""
        res = self.resolution
        first_new = self.n_blocks
        dense, box = self._scan_box(o32, ends)
        k.flag_blocks(o32, ends, kind, res, dense, box)
        self._until_done(lambda i: _raycast.alloc_flagged(dense, box, i, *self._storage()))
        self._until_done(
            lambda i: _raycast.mark_hits(ends, kind, res, dense, box, i, *self._storage())
        )
        deferred = k.cast_parallel(
            o32, ends, kind, res, self._planes(k), dense, box, *self._storage()
        )
        self._until_done(
            lambda i: _raycast.cast_serial(
                o32, ends, deferred, i, res, dense, box, *self._storage()
            )
        )
        self._fresh_blocks(first_new)
        self._adopt(np.arange(first_new, self.n_blocks))
        return self._apply(k)

    def _scan_box(
        self, origin: NDArray[np.float32], ends: NDArray[np.float32]
    ) -> tuple[NDArray[np.int32], NDArray[np.int64]]:
        """The dense per-scan block index: the bounding box of the blocks of the origin and the
        ray ends, one block of margin. Above MAX_DENSE entries (very long beams at a fine
        resolution) it covers the blocks nearest the origin only; rays leaving it take the
        serial path."""
        bounds = _raycast.block_bounds(origin, ends, self.resolution)
        lo, hi = bounds[0] - 1, bounds[1] + 1
        ob = _raycast.block_bounds(origin, ends[:0], self.resolution)[0]
        ext = hi - lo + 1
        while int(np.prod(ext)) > MAX_DENSE:  # shrink around the origin's block
            lo = np.maximum(lo, ob - ext // 4)
            hi = np.minimum(hi, ob + ext // 4)
            ext = hi - lo + 1
        box = np.concatenate([lo, ext]).astype(np.int64)
        return np.full(int(np.prod(ext)), -1, dtype=np.int32), box

    def insert_endpoints(self, points: NDArray[np.floating]) -> InsertStats:
        """Insert registered points as hits only (no ray casting); each voxel once per call.

        Points in dense blocks set hit bits there; the rest are grouped by block (region by
        region, every core): a block with DENSE_MIN voxels or more becomes dense, the others'
        voxels take one hit each in the sparse store.
        """
        pts = self._points_any(points)
        self._next_scan()
        k = self._kernels(len(pts) // 16)  # a point is far less work than a ray
        # Chunks of points and partitions go to the threads as they ask: a core held by
        # another process then delays one piece, not a thread's whole share.
        with numba.parallel_chunksize(1):
            return self._insert_endpoints(k, pts)

    def _insert_endpoints(self, k: K.Kernels, pts: NDArray[np.float32]) -> InsertStats:
        # a tree without dense blocks: no classes to keep (place_points recomputes partitions)
        cls = np.empty(len(pts) if self.n_blocks else 0, dtype=np.int32)
        hist = k.count_points(pts, self.resolution, self._table_keys, self._table_slots, cls)
        # Each chunk's points go after the earlier chunks' of the same partition (or of the
        # dense store); partitions one after the other.
        totals = hist.sum(axis=0)
        starts = np.zeros(_sparse.NPART + 1, dtype=np.int64)
        np.cumsum(totals[: _sparse.NPART], out=starts[1:])
        offsets = np.cumsum(hist[:, : _sparse.NPART + 1], axis=0) - hist[:, : _sparse.NPART + 1]
        offsets[:, : _sparse.NPART] += starts[:-1]
        new = np.empty(int(starts[-1]), dtype=np.int64)
        dense = np.empty(int(totals[_sparse.NPART]), dtype=np.int64)
        k.place_points(pts, self.resolution, cls, offsets, new, dense)
        del cls
        if len(dense):
            self._until_done(
                lambda i: _points.touch_points(dense, i, self._stamp, self._counts, self._touched)
            )
        sparse_hits = self._insert_new(k, new, starts) if len(new) else 0
        if len(dense):
            k.mark_point_bits(dense, self._planes(k), self._bits)
        hits, misses = self._apply(k, all_hits=True)
        outside, dropped = int(totals[_sparse.NPART + 1]), int(totals[_sparse.NPART + 2])
        return InsertStats(len(pts), dropped, outside, 0, hits + sparse_hits, misses)

    def _insert_new(self, k: K.Kernels, new: NDArray[np.int64], seg: NDArray[np.int64]) -> int:
        """End points in blocks the dense store lacks: voxel keys ``new``, partition p's in
        ``new[seg[p]:seg[p + 1]]``. Each distinct voxel once: dense blocks allocated and marked,
        the others' voxels hit in the sparse store. Returns the sparse store's voxels hit."""
        vt, st, counts = self._vt, self._st, self._sparse_counts
        written, runs = k.group_new_points(
            new, seg, vt, st, counts, self._dense_min, self._max_hits, self._planes(k)
        )
        sparse_hits = int(runs[:, 3].sum())
        ends = np.ascontiguousarray(written[:, 0])  # where the runs going dense end
        if runs[:, 0].any():  # blocks left for want of room: grow the tables, then hit them
            self._vt = self._fit(k, vt, counts[:, 0] + runs[:, 0], _sparse.KEY_MASK)
            self._st = self._fit(k, st, counts[:, 1] + runs[:, 1], _sparse.BLOCK_MASK)
            hits = k.upsert_sparse(
                new, seg, written, self._vt, self._st, counts, self._dense_min, self._max_hits
            )
            sparse_hits += int(hits[:, 0].sum())
            ends = np.where(hits[:, 1] > 0, written[:, 1], ends)  # promoted there too
        first_new = self.n_blocks
        adopt = np.empty(int(runs[:, 1:3].sum()), dtype=np.int64)  # dense + promoted runs
        n_adopt = np.zeros(1, dtype=np.int64)
        self._until_done(
            lambda i: _group.alloc_dense_runs(new, seg, ends, i, adopt, n_adopt, *self._storage())
        )
        self._fresh_blocks(first_new)
        self._adopt(adopt[: int(n_adopt[0])])
        return sparse_hits

    @staticmethod
    def _fit(
        k: K.Kernels, table: NDArray[np.int64], need: NDArray[np.int64], kmask: np.int64
    ) -> NDArray[np.int64]:
        """``table``, or a rehashed larger copy, with room for ``need`` entries per region."""
        size = size0 = len(table) >> _sparse.NREG_BITS
        while int(need.max()) > _sparse.SPARSE_LOAD * size:
            size *= 2
        if size == size0:
            return table
        # np.zeros maps its pages lazily: the table is not written twice
        out = np.zeros(size << _sparse.NREG_BITS, dtype=np.int64)
        k.sparse_rehash(table, kmask, out)
        return out

    def _adopt(self, slots: NDArray[np.int64]) -> None:
        """New dense blocks ``slots`` (every voxel unknown) take over their voxels from the sparse
        store."""
        if len(slots) and self._sparse_counts[:, 0].any():
            _sparse.adopt_sparse(
                slots,
                self._values,
                self._block_xyz,
                self._vt,
                self._st,
                self._sparse_counts,
                self._lut,
            )

    def _storage(self) -> tuple[NDArray[Any], ...]:
        """The arrays the marking kernels share, as they are now (they grow)."""
        return (
            self._bits,
            self._block_xyz,
            self._stamp,
            self._table_keys,
            self._table_slots,
            self._counts,
            self._touched,
        )

    def _next_scan(self) -> int:
        self._counts[_table.STAMP] += 1
        return int(self._counts[_table.STAMP])

    def _until_done(self, call: Callable[[int], tuple[int, int]]) -> None:
        """Run a resumable kernel to completion, growing the storage when it stops for room."""
        start = 0
        while True:
            start, status = call(start)
            if status == _table.DONE:
                return
            self._grow(status)

    def _fresh_blocks(self, first: int) -> None:
        """Blocks allocated since ``first`` start with every voxel unknown: zeroed memory
        (blocks are never freed, so their rows were never written)."""

    @staticmethod
    def _kernels(rays: int) -> K.Kernels:
        """Threads pay from a few thousand rays on; below, the serial build of the kernels."""
        return K.PARALLEL if rays >= PARALLEL_MIN_RAYS else K.SERIAL

    def _planes(self, k: K.Kernels) -> int:
        """Bit planes the kernels may use: one per numba thread (one when serial)."""
        if k is K.SERIAL:
            return 1
        return min(numba.get_num_threads(), self._bits.shape[1] // 8 - 1)

    def _apply(self, k: K.Kernels, *, all_hits: bool = False) -> tuple[int, int]:
        with numba.parallel_chunksize(256):  # blocks handed out as threads ask
            hits, misses = k.apply_blocks(
                self._values,
                self._bits,
                self._touched,
                int(self._counts[_table.N_TOUCHED]),
                self._model,
                all_hits,
            )
        self._counts[_table.N_TOUCHED] = 0
        return int(hits), int(misses)

    def _points(self, points: NDArray[np.floating]) -> tuple[NDArray[np.float32], int]:
        """Points as C-contiguous float32 (copied only if needed), non-finite rows dropped."""
        pts = self._points_any(points)
        if np.isfinite(pts).all():  # one cheap pass for the usual case
            return pts, 0
        finite = np.isfinite(pts).all(axis=1)
        return np.ascontiguousarray(pts[finite]), int(len(pts) - finite.sum())

    @staticmethod
    def _points_any(points: NDArray[np.floating]) -> NDArray[np.float32]:
        """Points as C-contiguous float32 (copied only if needed), non-finite rows kept."""
        arr = np.asarray(points)
        if arr.ndim != 2 or arr.shape[1] != 3:
            raise InputError(None, f"points must be an (N, 3) array, got shape {arr.shape}")
        return np.ascontiguousarray(arr, dtype=np.float32)

    def _grow(self, status: int) -> None:
        """Make room for the insertion kernels: more blocks, a longer list of blocks touched
        by the scan, or a larger hash table (kept at most half full)."""
        n_blocks = int(self._counts[_table.N_BLOCKS])
        n_touched = int(self._counts[_table.N_TOUCHED])
        # What the kernel still needs, when it knows (alloc_box): all three grown to fit at
        # once, not doubled time after time (a growth copies the store into fresh pages, slow to
        # touch on first use: 30-70 ms of FR-079's first scan at 0.05 m).
        wanted = int(self._counts[_table.WANTED])
        self._counts[_table.WANTED] = 0
        if status == _table.NEED_BLOCKS or n_blocks + wanted > len(self._bits):
            new = max(2 * len(self._bits), n_blocks + 4096, n_blocks + wanted)
            self._check_budget(new)
            # Fresh zeroed arrays (np.zeros maps pages lazily), only the used rows copied: the
            # tail stays untouched virtual memory, and so do the layers no voxel was written to.
            self._values = _copy_written(self._values, n_blocks, new)
            for name in ("_bits", "_block_xyz"):
                a = getattr(self, name)
                b = np.zeros((new, *a.shape[1:]), dtype=a.dtype)
                b[:n_blocks] = a[:n_blocks]
                setattr(self, name, b)
            # -1: touched by no scan yet, whichever path allocates the block (8 bytes a block).
            stamp = np.full(new, -1, dtype=np.int64)
            stamp[:n_blocks] = self._stamp[:n_blocks]
            self._stamp = stamp
        if status == _table.NEED_TOUCHED or n_touched + wanted > len(self._touched):
            touched = np.empty(max(2 * len(self._touched), n_touched + wanted), dtype=np.int64)
            touched[:n_touched] = self._touched[:n_touched]
            self._touched = touched
        if status == _table.NEED_TABLE or 2 * (n_blocks + wanted) > len(self._table_keys):
            cap = 1 << max(12, (4 * len(self._bits) - 1).bit_length())
            self._table_keys, self._table_slots = _table.rehash(self._block_xyz, n_blocks, cap)

    def _check_budget(self, blocks: int) -> None:
        """Refuse to grow the dense store to ``blocks`` blocks when that could take more than
        ``max_bytes``: the new arrays' capacity (filled as blocks come, it is what the tree
        reaches before its next growth) and the other arrays as they are. Free space along
        long beams at a fine resolution is what fills it: about 2.6 KB a block of 512 voxels,
        the ray touching a dozen of them."""
        if self.max_bytes is None:
            return
        per_block = (self._values, self._bits, self._block_xyz, self._stamp)
        row = sum(a.nbytes // len(self._bits) for a in per_block)
        need = self.memory_bytes() - sum(a.nbytes for a in per_block) + blocks * row
        if need > self.max_bytes:
            raise InputError(
                None,
                f"the octree would take {need / 2**30:.1f} GiB at {self.resolution:g} m, over "
                f"max_memory {self.max_bytes // 2**20} MiB (free space along long beams takes "
                "the most): choose a coarser --resolution or a shorter --max-range, or raise "
                "--max-memory",
            )

    # --- queries --------------------------------------------------------------------------

    @property
    def thresholds(self) -> dict[str, float]:
        """The model in log-odds (float32 values, as OctoMap stores them)."""
        return {
            "hit": float(self._hit),
            "miss": float(self._miss),
            "clamp_min": float(self._cmin),
            "clamp_max": float(self._cmax),
            "occupancy": float(self._occ),
        }

    def coord_to_key(self, xyz: NDArray[np.floating]) -> NDArray[np.int64]:
        """OctoMap keys of metric points (as float32, like OctoMap's point3d); -1 out of range."""
        p = np.asarray(xyz, dtype=np.float32).astype(np.float64)
        k = np.floor(p * (1.0 / self.resolution)) + KEY_OFFSET
        return np.where((k >= 0) & (k < 65536), k, -1).astype(np.int64)

    def key_to_coord(self, keys: NDArray[np.integer]) -> NDArray[np.float64]:
        """Voxel centres of keys, metres."""
        return key_to_coord(keys, self.resolution)

    def __len__(self) -> int:
        """Number of known voxels."""
        dense = np.count_nonzero(self._values[:, : self.n_blocks].view(np.uint32))  # not +0.0
        return int(dense) + self.n_sparse

    @property
    def n_sparse(self) -> int:
        """Voxels held by the sparse store."""
        return int(self._sparse_counts[:, 0].sum())

    @property
    def n_blocks(self) -> int:
        return int(self._counts[_table.N_BLOCKS])

    def logodds_at(self, points: NDArray[np.floating]) -> NDArray[np.float32]:
        """Log-odds of the voxels holding ``points`` (metres, (N, 3)); NaN where unknown."""
        return self.logodds_at_keys(self.coord_to_key(np.atleast_2d(points)))

    def logodds_at_keys(self, keys: NDArray[np.integer]) -> NDArray[np.float32]:
        k = np.ascontiguousarray(np.atleast_2d(keys), dtype=np.int64)
        return np.asarray(
            _sparse.lookup(
                k, self._values, self._table_keys, self._table_slots, self._vt, self._lut
            )
        )

    def is_occupied(self, logodds: NDArray[np.float32]) -> NDArray[np.bool_]:
        """OctoMap's isNodeOccupied: log-odds >= the threshold (NaN, unknown, is not)."""
        return np.asarray(logodds >= self._occ)

    def voxels(self) -> tuple[NDArray[np.uint16], NDArray[np.float32]]:
        """Every known voxel: keys uint16 (M, 3) and log-odds float32 (M,), the dense store's
        block by block, then the sparse store's."""
        keys, lo = _table.dense_voxels(self._values, self._block_xyz, self.n_blocks)
        if self.n_sparse == 0:
            return keys, lo
        skeys, slo = _sparse.sparse_voxels(self._vt, self._lut, self.n_sparse)
        return np.concatenate([keys, skeys]), np.concatenate([lo, slo])

    def occupied_and_free(self) -> tuple[NDArray[np.uint16], NDArray[np.bool_]]:
        """Keys of every known voxel and whether it is occupied (the maximum-likelihood map)."""
        keys, lo = self.voxels()
        return keys, self.is_occupied(lo)

    def at_depth(self, depth: int) -> tuple[NDArray[np.uint16], NDArray[np.float32]]:
        """Nodes at ``depth`` (0..16) that hold a known voxel: their min-corner voxel keys and
        value, the maximum log-odds below them (OctoMap's inner-node value)."""
        if not 0 <= depth <= TREE_DEPTH:
            raise ValueError(f"depth must be in 0..16, got {depth}")
        keys, lo = self.voxels()
        shift = TREE_DEPTH - depth
        node = keys.astype(np.int64) >> shift
        packed = (node[:, 0] << 32) | (node[:, 1] << 16) | node[:, 2]
        order = np.argsort(packed, kind="stable")
        packed, lo = packed[order], lo[order]
        starts = np.flatnonzero(np.r_[True, packed[1:] != packed[:-1]])
        value = np.maximum.reduceat(lo, starts) if len(lo) else lo
        u = packed[starts]
        corner = np.stack([(u >> 32) & 0xFFFF, (u >> 16) & 0xFFFF, u & 0xFFFF], axis=1) << shift
        return corner.astype(np.uint16), value.astype(np.float32)

    def bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        """Metric bounding box (min corner, max corner) of the known voxels, or None if empty."""
        keys, _ = self.voxels()
        if len(keys) == 0:
            return None
        lo = (keys.min(axis=0).astype(np.float64) - KEY_OFFSET) * self.resolution
        hi = (keys.max(axis=0).astype(np.float64) - KEY_OFFSET + 1) * self.resolution
        return lo, hi

    def memory_bytes(self) -> int:
        """Bytes held by the storage arrays (allocated capacity)."""
        arrays = (
            self._values,
            self._bits,
            self._block_xyz,
            self._stamp,
            self._table_keys,
            self._table_slots,
            self._touched,
            self._vt,
            self._st,
        )
        return sum(a.nbytes for a in arrays)

    # --- bulk construction ----------------------------------------------------------------

    def set_voxels(self, keys: NDArray[np.integer], logodds: NDArray[np.floating]) -> None:
        """Write log-odds at voxel keys (e.g. leaves read from a .bt file), replacing values."""
        k = np.ascontiguousarray(np.atleast_2d(keys), dtype=np.int64)
        v = np.ascontiguousarray(logodds, dtype=np.float32).reshape(-1)
        if k.shape != (len(v), 3):
            raise ValueError("keys must be (N, 3) and logodds (N,)")
        while len(self._bits) < self.n_blocks + len(k):
            self._grow(_table.NEED_BLOCKS)
        if len(self._table_keys) < 2 * len(self._bits):
            self._grow(_table.NEED_TABLE)
        _sparse.set_values(
            k,
            v,
            self._values,
            self._block_xyz,
            self._table_keys,
            self._table_slots,
            self._counts,
            self._vt,
            self._st,
            self._sparse_counts,
            self._lut,
        )


def _copy_written(values: NDArray[np.float32], n: int, size: int) -> NDArray[np.float32]:
    """``values`` (layers, blocks, 64) in a zeroed array of ``size`` blocks: of its first ``n``
    blocks, only the layer rows holding a nonzero bit are copied, so a layer never written
    stays untouched memory (reading it maps no page of its own)."""
    out = np.zeros((values.shape[0], size, values.shape[2]), dtype=values.dtype)
    for w in range(values.shape[0]):
        written = values[w, :n].view(np.uint32).any(axis=1)
        if written.all():
            out[w, :n] = values[w, :n]
        elif written.any():
            rows = np.flatnonzero(written)
            out[w, rows] = values[w, rows]
    return out


#: Zeroed memory for the box bits, kept for the next scan of any tree of the process: touching
#: fresh pages cost as much as the rays on this project's machine (FR-079 at 0.05 m: ~15 ms of
#: a 48 ms scan). It is zero whenever it is not in use (apply_box clears what it reads).
_SCRATCH: list[NDArray[np.uint64]] = [np.zeros(0, dtype=np.uint64)]
_SCRATCH_LOCK = threading.Lock()


@contextlib.contextmanager
def _zeroed_words(n: int) -> Iterator[NDArray[np.uint64]]:
    """``n`` zeroed uint64 words, to be left zeroed: the process's scratch, or fresh memory
    while another thread holds it."""
    if not _SCRATCH_LOCK.acquire(blocking=False):
        yield np.zeros(n, dtype=np.uint64)
        return
    try:
        if len(_SCRATCH[0]) < n:
            _SCRATCH[0] = np.zeros(0, dtype=np.uint64)  # the old one freed before the new
            _SCRATCH[0] = np.zeros(n, dtype=np.uint64)
        words = _SCRATCH[0][:n]
        try:
            yield words
        except BaseException:
            words[:] = 0  # whatever a failed scan left
            raise
    finally:
        _SCRATCH_LOCK.release()
