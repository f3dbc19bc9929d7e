"""The commands that start from sensor data: bag2world, cloud2world, convert, inspect.

bag2world:   open bag -> plan (topics, fixed frame, pose source) -> correction -> posed
             scans, streamed -> octree (ray cast, or end points only) -> octree_folder
             (a map topic instead goes straight to occupancy_folder, as map2world)
cloud2world: read cloud files -> local origin -> octree -> octree_folder
convert:     cloud file or bag -> one merged cloud file (hits only, fixed frame)
inspect:     a bag's topics, types, counts, duration, tf frames, and the plan with its reasons

Each command computes its world folder, then writes it once; this module composes the stages
and owns no algorithm.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from numpy.typing import NDArray

from scan2terrain.checks import grid_options, refuse_existing, refuse_unused, skipped_notes
from scan2terrain.commands import stream
from scan2terrain.commands.correct import correct_plan, decide
from scan2terrain.commands.maps import height_folder, occupancy_folder
from scan2terrain.commands.replay import scan_replay
from scan2terrain.commands.stream import cloud_bounds
from scan2terrain.commands.voxels import (
    RayBatch,
    Voxels,
    cast_hits,
    new_tree,
    octree_folder,
    point_columns,
)
from scan2terrain.config import DEFAULT_RESOLUTION, Config, cloud_resolution
from scan2terrain.errors import ConfigError, InputError, OutputError, about
from scan2terrain.exporters.pointcloud import FORMATS, cloud_bytes
from scan2terrain.exporters.trajectory import tum_bytes
from scan2terrain.fileio import atomic_write, check_file_target, is_url, url_path
from scan2terrain.filters.outliers import statistical_outliers
from scan2terrain.grids import to_trinary
from scan2terrain.octree.colour import VoxelColours
from scan2terrain.readers.cloudfile import SUFFIXES, merge_clouds, read_cloud
from scan2terrain.readers.crs import georeferenced, parse_crs
from scan2terrain.readers.messages import TF_TYPES
from scan2terrain.readers.points import hits_of, local_origin, start_of
from scan2terrain.readers.poses import pose6
from scan2terrain.readers.scans import (
    height_grid_from_message,
    is_height_grid,
    map_message,
    occupancy_from_message,
    plan_bag,
    posed_scans,
    read_tf,
    robot_trajectory,
)
from scan2terrain.replay.beams import BeamRecorder
from scan2terrain.steps import PointColumns, ScanProgress, StreamProgress
from scan2terrain.types import Cloud, OccupancyGrid, Pose2D, Scan, ScanCounts, StartPose, Transform
from scan2terrain.world.folder import Result, WorldFolder, write_world_folder

if TYPE_CHECKING:
    from scan2terrain.octree.tree import VoxelOctree
    from scan2terrain.readers.bag import Bag
    from scan2terrain.readers.scans import BagPlan

#: The octree's keys reach this many voxels either side of the origin (OctoMap's depth 16).
KEY_RANGE = 32768
#: map_saver's thresholds (percent) for an OccupancyGrid message: >= 65 occupied, <= 25 free.
MAP_OCCUPIED_ABOVE, MAP_FREE_BELOW = 64.0, 26.0


@dataclass(frozen=True)
class Ingest:
    """What went into the octree, for the report."""

    notes: tuple[str, ...]
    start: StartPose | None = None  #: the first scan's sensor pose: where the robot started


def streaming(cfg: Config) -> bool:
    """End points streamed into tiles (``stream.enabled``, implied by Dask workers or a
    scheduler) instead of the octree; refuses an explicit ray-casting request."""
    if not cfg.stream.active:
        return False
    if cfg.scans.insert == "raycast":
        raise ConfigError(
            "scans.insert raycast cannot be streamed or distributed (partial octrees do not "
            "merge exactly): drop --stream/--workers/--scheduler, or insert end points"
        )
    return True


# --- bags --------------------------------------------------------------------------------------


def bag2world(
    bags: Sequence[Path],
    out: Path,
    cfg: Config,
    *,
    overwrite: bool = False,
    progress: ScanProgress | None = None,
    stream_progress: StreamProgress | None = None,
) -> Result:
    """A bag (ROS1, ROS 2 sqlite3/MCAP; several files = one split bag) to a world folder."""
    from scan2terrain.readers.bag import open_bag

    refuse_existing(out, overwrite, tuple(bags))
    grid_options(cfg)
    if streaming(cfg):
        with open_bag(list(bags)) as bag:
            planned = plan_bag(bag, cfg.scans, max_range=cfg.octree.max_range)
        if planned.scan_topics:  # a map, or a trajectory only, is read as without --stream
            cfg = cfg.for_insert("endpoints")  # the written config says how scans went in
            streamed = stream.stream_bag(bags, cfg, stream_progress)
            cfg = cfg.for_poses(streamed.poses, corrected=streamed.corrected)
            folder = stream.streamed_folder(streamed, Path(bags[0]), cfg)
            return write_world_folder(folder, out, overwrite=overwrite)
    with open_bag(list(bags)) as bag:
        plan = plan_bag(bag, cfg.scans, max_range=cfg.octree.max_range)
        corrected = correct_plan(bag, cfg, plan)
        cfg = cfg.for_poses(plan.poses, corrected=plan.correction is not None)
        if plan.trajectory_only or plan.map_topic is not None:
            folder = (
                _trajectory_folder(bag, plan, cfg)
                if plan.trajectory_only
                else _map_topic_folder(bag, plan, cfg)
            )
            return write_world_folder(folder, out, overwrite=overwrite)
        cfg = cfg.for_insert("raycast")
        columns = point_columns(cfg, cast=cfg.scans.insert != "endpoints")
        recorder = BeamRecorder(beams=cfg.output.fidelity)  # the trajectory, at least
        tree, ingest = bag_octree(bag, cfg, plan, progress, columns, recorder=recorder)
    voxels = Voxels.taken(tree)
    del tree  # its store is not needed for the world: free it first
    replay = scan_replay(recorder, plan.pose_source, cfg, plan.correction)
    with octree_folder(
        voxels, source=bag.path, cfg=cfg, start=ingest.start, columns=columns, replay=replay,
        notes=[*ingest.notes, *corrected],
    ) as folder:  # fmt: skip
        return write_world_folder(folder, out, overwrite=overwrite)


def _map_topic_folder(bag: Bag, plan: BagPlan, cfg: Config) -> WorldFolder:
    """A bag's map topic (its last message, or ``scans.map_message``) as map2world or
    dem2world would make it: an OccupancyGrid, or an elevation grid (grid_map)."""

    msg, _ = map_message(bag, plan, cfg.scans.map_message)
    if is_height_grid(msg):  # an elevation grid: terrain, as dem2world makes it
        try:
            heights = height_grid_from_message(msg)
        except ValueError as exc:
            raise InputError(bag.path, f"{plan.map_topic}: {exc}") from exc
        rows, cols = heights.shape
        read = [*plan.reasons, f"height grid: {cols} x {rows} cells"]
        return height_folder(heights, bag.path, cfg).noted(first=read)
    try:
        data, res, (x, y, yaw) = occupancy_from_message(msg)
        grid = OccupancyGrid(data, res, Pose2D(x, y, yaw))
    except ValueError as exc:
        raise InputError(bag.path, f"{plan.map_topic}: {exc}") from exc
    trinary = to_trinary(grid.data, occupied_above=MAP_OCCUPIED_ABOVE, free_below=MAP_FREE_BELOW)
    folder = occupancy_folder(grid.with_data(trinary), bag.path, cfg)
    # What was read first, then what the world's builders said (tiles, Classic left out...).
    return folder.noted(first=[*plan.reasons, f"map: {grid.shape[1]} x {grid.shape[0]} cells"])


def _trajectory_folder(bag: Bag, plan: BagPlan, cfg: Config) -> WorldFolder:
    """A bag with poses and nothing to map: OUT/trajectory.tum (and the effective config), no
    world; the report's first line says so."""

    track, what = robot_trajectory(bag, cfg.scans, plan)
    span = (track.end_ns - track.start_ns) / 1e9
    data = tum_bytes(
        track.times_ns,
        track.translations,
        track.quaternions_xyzw,
        comment=f"{what} from {bag.path.name}, by scan2terrain\nt x y z qx qy qz qw",
    )
    notes = [*plan.reasons, f"trajectory: {len(track)} poses of {what}, {span:.3f} s"]
    result = Result(notes=notes)
    result.no_world = "nothing to map, the bag has no scans; the robot's trajectory only"
    return WorldFolder(bag.path, result, [], None, None, {"trajectory.tum": data}, cfg)


def bag_octree(
    bag: Bag,
    cfg: Config,
    plan: BagPlan,
    progress: ScanProgress | None = None,
    columns: PointColumns | None = None,
    *,
    recorder: BeamRecorder | None = None,
) -> tuple[VoxelOctree, Ingest]:
    """Every posed scan of the plan inserted into a new octree (and its hits into
    ``columns``, the points' column statistics, and its pose and beams into ``recorder``,
    when given)."""

    tree = new_tree(cfg)
    counts = ScanCounts()
    # With a time range, counting reads every scan message once more: only for a progress bar.
    total = 0
    if progress is not None:
        total = sum(bag.count(plan.scan_topics, plan.start_ns, plan.end_ns).values())
    batch = EndpointBatch(tree) if cfg.scans.insert == "endpoints" else None
    start = None
    with RayBatch(tree, bag.path) as rays:
        for scan in posed_scans(bag, cfg.scans, plan, counts, max_range=cfg.octree.max_range):
            if start is None:
                start = start_of(scan)
            if batch is None:
                at = f"{scan.topic} at {scan.stamp_ns / 1e9:.3f}: "
                rays.add(scan.points, scan.origin, scan.max_range, at)
            wanted = batch is not None or columns is not None
            hits = hits_of(scan) if wanted or (recorder and recorder.keeps_beams) else None
            if recorder is not None:
                recorder.add(scan, hits)
            if hits is not None and batch is not None:
                with about(bag.path):
                    batch.add(hits)
            if hits is not None and columns is not None:
                columns.add(hits)
            counts.inserted += 1
            counts.points += len(scan.points)
            if progress is not None:
                progress(counts, total)
    if batch is not None:
        with about(bag.path):
            batch.flush()
    refuse_unused(bag.path, counts, "used")
    notes = [*plan.reasons, f"scans: {counts.inserted} inserted ({counts.points:,} points)"]
    notes += skipped_notes(counts)
    if plan.tf is not None:
        notes += plan.tf.problems()
    return tree, Ingest(tuple(notes), start)


class EndpointBatch:
    """End points of many scans inserted together, ``CAPACITY`` points at a time.

    End points only ever add hits, so which voxels are occupied does not depend on how scans are
    grouped: a batch gives the same maximum-likelihood map (and ``.bt``, grids, worlds) as one
    insertion per scan, with fewer, larger calls (the octree's threads pay from ~65k points).
    Log-odds differ: a voxel gets one hit per batch, not one per scan.
    """

    CAPACITY = 1 << 20

    def __init__(self, tree: VoxelOctree) -> None:
        self.tree = tree
        self._buf = np.empty((self.CAPACITY, 3), dtype=np.float32)
        self._n = 0

    def add(self, points: NDArray[np.floating]) -> None:
        n = len(points)
        if self._n + n > self.CAPACITY:
            self.flush()
        if n > self.CAPACITY:
            self.tree.insert_endpoints(points)
            return
        self._buf[self._n : self._n + n] = points
        self._n += n

    def flush(self) -> None:
        if self._n:
            self.tree.insert_endpoints(self._buf[: self._n])
            self._n = 0


def inspect_bag(bags: Sequence[Path], cfg: Config) -> str:
    """A human report of a bag: topics, types, counts, duration, tf frames, and what bag2world
    would use and why (or why it cannot)."""
    from scan2terrain.readers.bag import open_bag

    with open_bag(list(bags)) as bag:
        lines = [
            f"{bag.path}",
            f"  {bag.container.describe()}",
            f"  duration {bag.duration_s:.3f} s, {bag.message_count} messages, "
            f"start {bag.start_ns / 1e9:.3f} (UNIX s)",
            "  topics:",
        ]
        width = max((len(n) for n in bag.topics), default=5)
        for name in sorted(bag.topics):
            t = bag.topics[name]
            lines.append(f"    {name:<{width}}  {t.count:>7}  {t.msgtype}")
            if how := bag.container.encodings.get(name):
                lines.append(f"    {'':<{width}}  {'':>7}  ({how})")
        for topic, reason in bag.skipped.items():
            lines.append(f"  skipped: {topic}: {reason}")
        if bag.topics_of_type(TF_TYPES):
            tf = read_tf(bag, cfg.scans)
            lines.append("  tf tree:")
            for e in sorted(tf.edges(), key=lambda e: (e.parent, e.child)):
                kind = "static" if e.static else f"{e.samples} samples"
                lines.append(f"    {e.parent} -> {e.child} ({kind})")
            lines += [f"  {p}" for p in tf.problems()]
        else:
            lines.append("  tf tree: none (no /tf or /tf_static)")
        try:
            plan = plan_bag(bag, cfg.scans, max_range=cfg.octree.max_range)
        except InputError as exc:
            lines.append(f"  bag2world would stop: {exc.problem}")
        else:
            lines.append("  bag2world would use:")
            lines += [f"    {r}" for r in plan.reasons]
            if plan.scan_topics:
                correct, why = decide(cfg, plan)
                kept = ", kept if the beams agree better" if cfg.scans.correct == "auto" else ""
                done = f"correction: scan matching and loop closure ({why}){kept}"
                lines.append(f"    {done if correct else why}")
    return "\n".join(lines)


# --- cloud files -------------------------------------------------------------------------------


class Clouds(NamedTuple):
    """Cloud files as read for a command."""

    points: list[NDArray[np.float64]]  #: per file, the local origin subtracted
    origin: NDArray[np.float64]  #: the local origin (zeros when none)
    notes: list[str]
    colours: list[NDArray[np.uint8] | None]  #: per file, aligned with ``points`` (if asked)


def read_clouds(
    files: Sequence[Path], cfg: Config, *, local: bool = True, colours: bool = False
) -> Clouds:
    """Points of every file (float64), the local origin subtracted from them (``local`` and
    ``scans.local_origin: auto``), and notes; with ``colours`` their RGB where a file has it."""
    clouds, notes = _cloud_files(files, cfg, colours=colours)
    points = [c.points for c in clouds]
    origin = np.zeros(3)
    if local:
        # The bounds the streamed path knows before reading a point (a LAS/LAZ header's, of
        # every class): the same origin, so the same coordinates, on both paths.
        lo, hi, _ = cloud_bounds(files, points)
        origin = local_origin(lo, hi, cfg.scans.local_origin, notes)
    return Clouds([p - origin for p in points], origin, notes, [c.colours for c in clouds])


def _cloud_files(
    files: Sequence[Path], cfg: Config, *, colours: bool = False, attributes: bool = False
) -> tuple[list[Cloud], list[str]]:
    """Every file's cloud (of ``scans.las_classes``, without statistical outliers when
    ``scans.outliers`` asks), and notes."""

    sc = cfg.scans
    clouds = [
        read_cloud(f, las_classes=sc.las_classes, colours=colours, attributes=attributes)
        for f in files
    ]
    notes = [f"{c.path.name}: {len(c.points):,} points ({c.format})" for c in clouds]
    if sc.outliers is not None:
        for i, c in enumerate(clouds):
            keep = statistical_outliers(
                c.points, neighbours=sc.outlier_neighbours, std_ratio=sc.outliers
            )
            clouds[i] = c.take(keep)
            notes.append(
                f"{c.path.name}: {int((~keep).sum()):,} statistical outliers removed (mean"
                f" distance to {sc.outlier_neighbours} neighbours over mean + {sc.outliers:g} sd)"
            )
            if not keep.any():  # pragma: no cover - the filter keeps points at the mean
                raise InputError(c.path, "every point is a statistical outlier")
    return clouds, notes


def cloud2world(
    files: Sequence[Path | str],
    out: Path,
    cfg: Config,
    *,
    overwrite: bool = False,
    stream_progress: StreamProgress | None = None,
) -> Result:
    """Point-cloud files to a world folder: each file one insertion (end points only, or ray
    cast from ``scans.pose`` when ``scans.insert`` is raycast: the cloud is then in the sensor
    frame)."""

    refuse_existing(out, overwrite, tuple(files))
    grid_options(cfg)
    cfg = cfg.for_insert("endpoints")

    if cfg.scans.crs is not None:  # refused before any point is read
        parse_crs(cfg.scans.crs)

    if streaming(cfg):
        chosen: list[str] = []
        if cfg.octree.resolution is None:
            cfg = _cloud_resolution(cfg, *stream.cloud_bounds(files), chosen)
        streamed = stream.stream_clouds(files, cfg, stream_progress)
        source = url_path(files[0])
        cfg = georeferenced(cfg, np.asarray(streamed.origin), files, chosen)
        folder = stream.streamed_folder(streamed, source, cfg).noted(first=chosen)
        return write_world_folder(folder, out, overwrite=overwrite)
    for f in files:
        if is_url(f):
            raise InputError(str(f), "URLs are read with --stream (LAS/LAZ)")
    voxels = cfg.world.geometry == "voxels"
    clouds, origin, notes, rgb = read_clouds([Path(f) for f in files], cfg, colours=voxels)
    asked = cfg.scans.local_origin  # before the origin used is recorded
    cfg = georeferenced(cfg, origin, files, notes)
    if cfg.octree.resolution is None:
        lo, hi, n = cloud_bounds(files, clouds, offset=origin)
        cfg = _cloud_resolution(cfg, lo, hi, n, notes)
    tree = new_tree(cfg)
    sensor = _fixed_pose(cfg)
    raycast = cfg.scans.insert == "raycast"
    columns = point_columns(cfg, cast=raycast)
    outside: dict[Path, int] = {}
    colours = None
    if any(c is not None for c in rgb):
        colours = VoxelColours(tree.resolution)
    for path, local, pts_rgb in zip(files, clouds, rgb, strict=True):
        pts = sensor.apply(local) if raycast else local
        if columns is not None:  # added on another thread while the octree takes them
            columns.add(cast_hits(pts, sensor.translation, cfg) if raycast else pts)
        with about(path):
            if raycast:
                stats = tree.insert_scan(pts, sensor.translation, max_range=cfg.octree.max_range)
            else:
                stats = tree.insert_endpoints(pts)
            if colours is not None and pts_rgb is not None:
                colours.add(pts, pts_rgb)
        if stats.out_of_range:
            outside[Path(path)] = stats.out_of_range
    keys, occupied = tree.occupied_and_free()
    if outside:  # the octree drops them silently; without this the error would be "no voxel"
        path, n = next(iter(outside.items()))
        res = tree.resolution
        span = f"outside the octree's key range (+-{KEY_RANGE * res:g} m at {res:g} m)"
        if len(keys) == 0:
            hint = (
                "the files may be in different coordinate systems (one local origin serves"
                " all); convert them to one, or use a coarser --resolution"
                if asked == "auto"
                else "use --local-origin auto, or a coarser --resolution"
            )
            raise InputError(path, f"all points lie {span}: {hint}")
        notes.append(
            f"{sum(outside.values()):,} point(s) {span} dropped, e.g. {n:,} of {path.name}"
        )
    taken = Voxels(keys, occupied, tree.resolution)
    del tree  # its store is not needed for the world: free it first
    with octree_folder(
        taken, source=Path(files[0]), cfg=cfg, colours=colours, columns=columns, notes=notes
    ) as folder:
        return write_world_folder(folder, out, overwrite=overwrite)


def _cloud_resolution(
    cfg: Config, lo: NDArray[np.float64], hi: NDArray[np.float64], points: int, notes: list[str]
) -> Config:
    """``cfg`` with cloud2world's resolution for ``points`` points within ``lo``..``hi`` (none
    was given);
    the reason in ``notes`` when it is coarser than the default."""

    res, why = cloud_resolution(lo.tolist(), hi.tolist(), points, cfg)
    if res != DEFAULT_RESOLUTION:
        notes.append(why)
    return dataclasses.replace(cfg, octree=dataclasses.replace(cfg.octree, resolution=res))


def _fixed_pose(cfg: Config) -> Transform:

    return pose6(cfg.scans.pose or [0.0] * 6)


# --- convert -----------------------------------------------------------------------------------


def convert(source: Sequence[Path], target: Path, cfg: Config, *, overwrite: bool = False) -> str:
    """A cloud file, or a bag's scans (hits only, in the fixed frame), to one cloud file.

    Cloud files keep what the target can hold of their attributes (intensity, classification,
    return numbers, GPS time, colour, ...), LAS layout (point format, scales, offsets) and CRS;
    one line of the report says what it cannot hold."""
    from scan2terrain.readers.bag import open_bag

    target = Path(target)
    # Before any work: a target this cannot write, or must not replace, is refused.
    check_file_target(target, overwrite, tuple(source))
    if target.suffix.lower() not in FORMATS:
        problem = (
            f"unsupported point cloud extension {target.suffix!r}"
            if target.suffix
            else "no point cloud extension"
        )
        raise OutputError(f"{target}: {problem} (use one of {', '.join(FORMATS)})")
    if all(Path(s).suffix.lower() in SUFFIXES for s in source):
        clouds, notes = _cloud_files(source, cfg, attributes=True)
        cloud, more = merge_clouds(clouds)
        del clouds  # one file's cloud is the merged one; several were copied into it
        notes += more
        if cloud.unread:
            notes.append(f"not read: {', '.join(cloud.unread)}")
    else:
        if cfg.scans.outliers is not None:
            raise ConfigError(
                "scans.outliers (--outliers) cleans cloud files; a bag's scans are not filtered:"
                " convert the bag to a cloud file first, then filter that"
            )
        with open_bag(list(source)) as bag:
            points, notes = _bag_hits(bag, cfg)
            cloud = Cloud(points, bag.path, "bag", len(points))
    try:
        out = cloud_bytes(cloud, target.suffix)
    except ValueError as exc:  # coordinates LAS cannot hold
        raise InputError(cloud.path, str(exc)) from exc
    atomic_write(target, out.data)
    lines = [f"Wrote {target} ({len(cloud.points):,} points)", *(f"  {n}" for n in notes)]
    if out.lost:
        lines.append(f"  {target.suffix[1:].upper()} cannot hold: {'; '.join(out.lost)}")
    return "\n".join(lines)


def _bag_hits(bag: Bag, cfg: Config) -> tuple[NDArray[np.float64], list[str]]:

    plan = plan_bag(bag, cfg.scans, max_range=cfg.octree.max_range)
    if plan.trajectory_only:
        raise InputError(
            bag.path,
            "no scans: nothing to convert (bag2world writes the trajectory of its poses)",
        )
    if plan.map_topic is not None:
        raise InputError(bag.path, f"{plan.map_topic} is a map, not scans: nothing to convert")
    counts = ScanCounts()
    parts = list(_hits(posed_scans(bag, cfg.scans, plan, counts, max_range=cfg.octree.max_range)))
    if not parts:
        raise InputError(bag.path, f"no scan could be posed ({counts.first_unposed})")
    tf = plan.tf.problems() if plan.tf is not None else []
    return np.concatenate(parts), [*plan.reasons, f"scans: {len(parts)}", *tf]


def _hits(scans: Iterator[Scan]) -> Iterator[NDArray[np.float64]]:
    for s in scans:
        pts = hits_of(s)
        if len(pts):
            yield pts
