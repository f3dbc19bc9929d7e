"""octree2world: an OctoMap ``.bt`` file (pruned leaves as vertical runs) or an OctoMap text scan
file (ray-cast into a new octree) -> octomap_server's 2D projection or a 2.5D height grid ->
the same world folder as map2world (commands.maps)."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from scan2terrain.checks import grid_options, refuse_existing, refuse_large_grid
from scan2terrain.commands.maps import height_folder, occupancy_folder
from scan2terrain.commands.replay import Replay, scan_replay
from scan2terrain.commands.stream import lattice_for
from scan2terrain.config import Config, octree_resolution
from scan2terrain.errors import InputError, about
from scan2terrain.exporters.pointcloud import points_bytes
from scan2terrain.grids import projection
from scan2terrain.grids.occupied import occupied_voxels
from scan2terrain.grids.projection import leaf_columns
from scan2terrain.octree.bt import bt_bytes, read_bt
from scan2terrain.octree.keys import key_to_coord
from scan2terrain.readers.octomap_scan import is_scan_file, read_scans
from scan2terrain.readers.points import within_reach
from scan2terrain.replay.beams import BeamRecorder
from scan2terrain.steps import PointColumns, ScanProgress, fill_holes, point_heights, solid_hint
from scan2terrain.types import Scan, ScanCounts, StartPose
from scan2terrain.world.folder import Result, WorldFolder, write_world_folder
from scan2terrain.world.voxels import voxel_mesh_folder

if TYPE_CHECKING:
    from scan2terrain.octree.colour import VoxelColours
    from scan2terrain.octree.tree import VoxelOctree


def octree2world(
    source: Path,
    out: Path,
    cfg: Config,
    *,
    overwrite: bool = False,
    progress: ScanProgress | None = None,
) -> Result:
    """An OctoMap ``.bt`` file, or an OctoMap text scan file (ray-cast into a new octree), to a
    world folder through octomap_server's 2D projection or a 2.5D height grid. ``progress``
    (scan files only) is called after each scan with the counts so far and a total of 0
    (unknown: the file is read once)."""

    refuse_existing(out, overwrite, (source,))
    grid_options(cfg)
    source = Path(source)
    if is_scan_file(source):
        columns = point_columns(cfg, cast=True)  # heights from the points, as for clouds
        recorder = BeamRecorder()
        tree = build_octree(source, cfg, progress, columns, recorder)
        voxels = Voxels.taken(tree)
        del tree  # its store is not needed for the world: free it first
        replay = scan_replay(recorder, "the scan file's NODE poses", cfg)
        with octree_folder(
            voxels, source=source, cfg=cfg, columns=columns, replay=replay
        ) as folder:
            return write_world_folder(folder, out, overwrite=overwrite)

    bt = read_bt(source)
    # Pruned leaves (a free 256^3 block is common in octomap_server maps) stay vertical runs.
    try:
        keys, occupied, runs = leaf_columns(bt.keys, bt.depth, bt.occupied)
    except ValueError as exc:
        raise InputError(source, f"{exc}: too large to project") from exc
    folder = voxels_folder(keys, occupied, bt.resolution, source=source, cfg=cfg, runs=runs)
    return write_world_folder(folder, out, overwrite=overwrite)


@dataclass(frozen=True)
class Voxels:
    """An octree's known voxels (OctoMap keys; occupied or free), taken out of it."""

    keys: NDArray[np.uint16]
    occupied: NDArray[np.bool_]
    resolution: float

    @classmethod
    def taken(cls, tree: VoxelOctree) -> Voxels:
        """The tree's voxels (the caller then drops the tree, whose store is large)."""
        keys, occupied = tree.occupied_and_free()
        return cls(keys, occupied, tree.resolution)


@contextmanager
def octree_folder(
    voxels: Voxels,
    *,
    source: Path,
    cfg: Config,
    start: StartPose | None = None,
    colours: VoxelColours | None = None,
    columns: PointColumns | None = None,
    replay: Replay | None = None,
    notes: Sequence[str] = (),
) -> Iterator[WorldFolder]:
    """The tail bag2world, cloud2world and octree2world share: the world folder of an octree's
    voxels (:func:`voxels_folder`), after ``notes`` (what was read), with ``octree.bt``, whose
    bytes are made on a second thread meanwhile, and the ``replay`` of the recording; write it
    inside the ``with`` (the writer waits for the bytes)."""
    with octree_file(voxels.resolution, voxels.keys, voxels.occupied) as bt:
        folder = voxels_folder(
            voxels.keys, voxels.occupied, voxels.resolution, source=source, cfg=cfg,
            start=start, colours=colours, columns=columns,
        )  # fmt: skip
        yield folder.noted(first=notes).with_extra(
            {**bt, "replay": replay} if replay is not None else bt, before=True
        )


def voxels_folder(  # noqa: PLR0913 (the octree's arrays and what the world needs of the run)
    keys: NDArray[np.uint16],
    occupied: NDArray[np.bool_],
    resolution: float,
    *,
    source: Path,
    cfg: Config,
    start: StartPose | None = None,
    runs: NDArray[np.uint16] | None = None,
    colours: VoxelColours | None = None,
    columns: PointColumns | None = None,
) -> WorldFolder:
    """Known voxels (OctoMap keys, occupied or free) to a world folder: octomap_server's 2D
    projection (``octree.grid: occupancy``) or a 2.5D height grid, plus the occupied voxel
    centres when ``octree.points`` asks for them; ``start`` as for :func:`occupancy_folder`;
    ``runs``: each key starts a vertical run of that many voxels (pruned leaves).
    ``columns``: the column statistics of the points the voxels were made from; a height
    grid's heights are then theirs (the points' z, as the streamed path takes them), not the
    voxel centres (only an OctoMap file, which has no points, needs those)."""

    extra: dict[str, bytes] = {}
    if len(keys) == 0:
        raise InputError(source, "the octree holds no known voxel")
    o = cfg.octree
    if o.points != "none":
        solid = occupied_voxels(keys, occupied, runs, source, why="--points")
        extra[f"occupied_voxels.{o.points}"] = points_bytes(
            key_to_coord(solid, resolution), f".{o.points}"
        )
    # Size the grid before allocating it (its columns span the keys' x and y range): a voxel
    # world's map is that grid too (it allocated 4e9 cells for a survey at 0.05 m, then failed).
    span = keys[:, :2].max(axis=0).astype(np.int64) - keys[:, :2].min(axis=0) + 1
    refuse_large_grid(source, "voxels", int(span[1]), int(span[0]), resolution=resolution, cfg=cfg)
    if cfg.world.geometry == "voxels":
        return voxel_mesh_folder(
            keys, occupied, resolution, source=source, cfg=cfg, start=start, runs=runs,
            colours=colours,
        ).with_extra(extra)  # fmt: skip
    z_min, z_max = o.z_band
    if o.grid == "occupancy":
        grid = projection.project_occupancy(
            keys, occupied, resolution, z_min=z_min, z_max=z_max, runs=runs
        )
        hint = solid_hint(grid)
        folder = occupancy_folder(grid, source, cfg, start=start, scans=True)
        return folder.noted(then=[hint] if hint else []).with_extra(extra)
    if columns is not None:
        tiles = columns.finish()
        # End points occupy every voxel they hit: their columns are the tiles' own (the same
        # cell rule), and the heights those the streamed path gets. Ray-cast points may have
        # had voxels cleared since: then the octree bounds them.
        bounds = None
        if columns.cast:
            bounds = projection.column_stats(
                keys, occupied, resolution, z_min=z_min, z_max=z_max, runs=runs
            )
        heights, notes = point_heights(tiles, cfg, source, occupied=bounds)
        folder = height_folder(heights, source, cfg, start=start)
        return folder.noted(then=notes).with_extra(extra)
    stats = projection.column_stats(keys, occupied, resolution, z_min=z_min, z_max=z_max, runs=runs)
    if not stats.known.any():
        raise InputError(source, "no occupied voxel in the z band: nothing to make terrain of")
    heights = fill_holes(stats.to_height_grid(o.height_stat), cfg)
    return height_folder(heights, source, cfg, start=start).with_extra(extra)


def point_columns(cfg: Config, *, cast: bool) -> PointColumns | None:
    """For a height grid: the points' column statistics, gathered beside the octree
    (``cast``: the points are ray-cast; see :class:`~scan2terrain.steps.PointColumns`)."""
    if cfg.octree.grid != "height" or cfg.world.geometry == "voxels":
        return None

    return PointColumns(lattice_for(cfg), cast=cast)


def cast_hits(
    points: NDArray[np.float64], sensor: NDArray[np.float64], cfg: Config
) -> NDArray[np.float64]:
    """A ray-cast scan's hits: its points within ``octree.max_range`` of the sensor."""

    return within_reach(points, sensor, cfg.octree.max_range)


def build_octree(
    source: Path,
    cfg: Config,
    progress: ScanProgress | None = None,
    columns: PointColumns | None = None,
    recorder: BeamRecorder | None = None,
) -> VoxelOctree:
    """Ray-cast every scan of an OctoMap text scan file into a new octree (and its hits into
    ``columns``, the points' column statistics, and its pose and beams into ``recorder``,
    when given)."""

    o = cfg.octree
    tree = new_tree(cfg)
    counts = ScanCounts()
    with RayBatch(tree, source) as rays:
        for scan in read_scans(source):
            rays.add(scan.points, scan.origin, o.max_range)
            _scan_extras(scan, cfg, columns, recorder)
            counts.messages += 1
            counts.inserted += 1
            counts.points += len(scan.points)
            if progress is not None:
                progress(counts, 0)
    return tree


def _scan_extras(
    scan: Scan, cfg: Config, columns: PointColumns | None, recorder: BeamRecorder | None
) -> None:
    """A ray-cast scan's hits into ``columns`` and its pose and beams into ``recorder``."""
    if columns is not None or recorder is not None:
        hits = cast_hits(scan.points, scan.origin, cfg)
        if columns is not None:
            columns.add(hits)
        if recorder is not None:
            recorder.add(scan, hits)


def new_tree(cfg: Config) -> VoxelOctree:
    """An empty voxel octree with the config's resolution and OctoMap sensor model, refusing
    to grow past ``max_memory``."""
    from scan2terrain.octree.tree import SensorModel, VoxelOctree

    o = cfg.octree
    return VoxelOctree(
        octree_resolution(cfg),
        SensorModel(o.hit, o.miss, o.clamp_min, o.clamp_max, o.occupancy),
        max_bytes=cfg.max_memory << 20,
    )


class RayBatch:
    """Scans ray-cast into ``tree`` many at a time, in order, on a second thread.

    ``add`` checks a scan's sensor origin at once (so a refusal names the scan) and queues it;
    every ``POINTS`` points (or ``SCANS`` scans) the queue goes to ``tree.insert_scans`` on the
    worker thread while the caller reads and poses the next scans: the kernels release the GIL,
    so on two cores reading costs no time. One batch at a time, in the order given, so the
    voxels are those of one ``insert_scan`` per scan, bit for bit. Use it as a context manager:
    leaving it inserts what is queued and waits; leaving it by an exception waits for the
    worker, then lets the exception go on.
    """

    POINTS = 1 << 17
    SCANS = 512

    def __init__(self, tree: VoxelOctree, source: Path) -> None:
        self.tree, self.source = tree, source
        self._points: list[NDArray[np.floating]] = []
        self._origins: list[NDArray[np.float32]] = []
        self._ranges: list[float] = []
        self._n = 0
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="octree.insert")
        self._running: Future[None] | None = None

    def __enter__(self) -> RayBatch:
        return self

    def __exit__(self, kind: type[BaseException] | None, *_: object) -> None:
        try:
            if kind is None:
                self.flush()
            self._wait()
        finally:
            self._pool.shutdown(wait=True)

    def add(self, points: NDArray[np.floating], origin: NDArray[np.floating], max_range: float,
            context: str = "") -> None:  # fmt: skip
        """Queue one scan (``context``, e.g. its topic and stamp, leads a refusal of it)."""
        with about(self.source, context):
            o32 = self.tree.checked_origin(origin)
        self._points.append(points)
        self._origins.append(o32)
        self._ranges.append(max_range)
        self._n += len(points)
        if self._n >= self.POINTS or len(self._points) >= self.SCANS:
            self.flush()

    def flush(self) -> None:
        """Hand the queued scans to the worker (after the batch before them)."""
        if not self._points:
            return
        sizes = [len(p) for p in self._points]
        pts = np.concatenate(self._points).astype(np.float32, copy=False)
        offsets = np.zeros(len(sizes) + 1, dtype=np.int64)
        np.cumsum(sizes, out=offsets[1:])
        origins, ranges = np.stack(self._origins), np.asarray(self._ranges)
        self._points, self._origins, self._ranges, self._n = [], [], [], 0
        self._wait()
        self._running = self._pool.submit(self._insert, pts, offsets, origins, ranges)

    def _insert(self, pts: NDArray[np.float32], offsets: NDArray[np.int64],
                origins: NDArray[np.float32], ranges: NDArray[np.float64]) -> None:  # fmt: skip
        with about(self.source):
            self.tree.insert_scans(pts, offsets, origins, ranges)

    def _wait(self) -> None:
        if self._running is not None:
            running, self._running = self._running, None
            running.result()


@contextmanager
def octree_file(
    resolution: float, keys: NDArray[np.uint16], occupied: NDArray[np.bool_]
) -> Iterator[dict[str, Future[bytes]]]:
    """``{"octree.bt": the .bt bytes}``, made on a second thread while the caller builds the
    world from the same (unchanged) voxels: the .bt kernels release the GIL, so on two cores
    the file costs no time; the bytes are the same. The writer waits for them."""

    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="octree.bt") as pool:
        yield {
            "octree.bt": pool.submit(bt_bytes, resolution=resolution, keys=keys, occupied=occupied)
        }
