"""Streamed, tiled rasterisation: clouds and bags larger than memory to grids, on one process or
on a Dask cluster.

cloud2world/bag2world with ``stream.enabled`` (``--stream``):
    plan chunks (LAS/LAZ: ranges of points, from the headers; other cloud files: one per file;
    bags: time slices) -> each chunk read ``stream.chunk_points`` at a time -> end points into a
    :class:`~scan2terrain.grids.tiles.TileSet` -> partial results (their cells with a point,
    :class:`~scan2terrain.grids.tiles.TileRecords`) merged (exact, any order) -> column
    statistics or occupancy (the tiles freed) -> the world folder (:func:`streamed_folder`),
    which the command (commands/scans.py) writes once, atomically
With ``stream.workers`` or ``stream.scheduler`` every chunk is a Dask task: workers read their
chunk themselves (by path: they must see the same files) and send back its tiles; the client
merges them. Without either, nothing imports Dask.

What is distributed: reading, decoding, posing and rasterising the end points, per chunk. What is
not: ray casting (an octree's clamped log-odds depend on the order of updates, so partial octrees
do not merge exactly; ray-cast bags and clouds take the octree path on one process), bags' tf
pass (read once by the client, sent to every task), the merge and the writing of outputs.

Like the other commands, this module composes the stages and owns no algorithm.
"""

from __future__ import annotations

import contextlib
import itertools
import math
import queue
import threading
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

import numpy as np
from numpy.typing import NDArray

from scan2terrain.checks import refuse_large_grid, refuse_tiles_grid
from scan2terrain.commands.correct import correct_plan
from scan2terrain.commands.maps import height_folder, occupancy_folder
from scan2terrain.commands.replay import scan_replay
from scan2terrain.config import Config, octree_resolution
from scan2terrain.errors import ConfigError, InputError
from scan2terrain.fileio import is_url, url_path
from scan2terrain.grids.tiles import Lattice, TileRecords, TileSet
from scan2terrain.readers.cloudfile import read_cloud
from scan2terrain.readers.las import LAS_SUFFIXES, iter_las, las_info, url_suffix
from scan2terrain.readers.points import hits_of, local_origin, start_of
from scan2terrain.readers.scans import plan_bag, posed_scans
from scan2terrain.replay.beams import BeamRecorder
from scan2terrain.steps import StreamProgress, point_heights, solid_hint
from scan2terrain.types import ScanCounts

if TYPE_CHECKING:
    from scan2terrain.commands.replay import Replay
    from scan2terrain.readers.scans import BagPlan
    from scan2terrain.replay.beams import BeamRecorder
    from scan2terrain.types import StartPose
    from scan2terrain.world.folder import WorldFolder

#: A Dask task reads about this many chunks of ``stream.chunk_points``: a range of a big LAS/LAZ
#: file, or several small files (fewer, larger results to send back and merge).
CHUNKS_PER_TASK = 4
#: A bag task reads about this many scan messages.
SCANS_PER_TASK = 256

T = TypeVar("T")


@dataclass(frozen=True)
class CloudChunk:
    """Points ``[start, start + count)`` of a cloud file (``count`` None: the whole file, of
    ``size`` points)."""

    path: str
    start: int = 0
    count: int | None = None
    size: int = 0


@dataclass(frozen=True)
class BagChunk:
    """A bag's scans with a stamp in ``[start_ns, end_ns]`` (bag time, inclusive)."""

    paths: tuple[str, ...]
    start_ns: int
    end_ns: int


Chunk = CloudChunk | BagChunk


@dataclass(frozen=True)
class Job:
    """What every task needs besides its chunk (small, sent with each task)."""

    lattice: Lattice
    origin: tuple[float, float, float]  #: subtracted from every point (local origin), metres
    step: int  #: points read at a time
    las_classes: tuple[int, ...] | None = None
    bag: BagJob | None = None


@dataclass(frozen=True)
class BagJob:
    """A bag task's plan: topics, frames and the tf tree the client read (no re-reading)."""

    plan: BagPlan
    config: Config


@dataclass(frozen=True)
class Streamed:
    """The merged tiles and what went into them, for the report."""

    tiles: TileSet
    notes: tuple[str, ...]
    start: StartPose | None = None  #: a bag's first scan pose, as the octree path finds it
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)  #: the clouds' local origin
    replay: Replay | None = None  #: a bag's: its recorded beams, replayed in the world
    poses: str = ""  #: a bag's: where its poses came from (tf, odom, trajectory, fixed)
    corrected: bool = False  #: a bag's: its poses were corrected (scans.correct)


# --- planning ---------------------------------------------------------------------------------


def lattice_for(cfg: Config) -> Lattice:
    return Lattice(octree_resolution(cfg), cfg.stream.tile_cells, *cfg.octree.z_band)


def cloud_bounds(
    files: Sequence[Path | str],
    points: Sequence[NDArray[np.float64]] | None = None,
    offset: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], int]:
    """The bounds and the number of points of cloud files as both paths know them before any
    grid: a LAS/LAZ header's, else the points' (``points``, one array per file, when they are
    read already; plus ``offset`` when they are less it, a local origin: the bounds of
    ``points + offset`` exactly, rounding being monotonic, without adding it to every point)."""

    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    n = 0
    for i, f in enumerate(files):
        if url_suffix(f) in LAS_SUFFIXES:
            info = las_info(f)
            lo, hi = np.minimum(lo, info.mins), np.maximum(hi, info.maxs)
            n += info.points
            continue
        p = points[i] if points is not None else read_cloud(Path(f)).points
        if len(p):
            plo, phi = p.min(axis=0), p.max(axis=0)
            if offset is not None:
                plo, phi = plo + offset, phi + offset
            lo, hi = np.minimum(lo, plo), np.maximum(hi, phi)
            n += len(p)
    return lo, hi, n


def plan_clouds(
    files: Sequence[Path | str], cfg: Config
) -> tuple[list[CloudChunk], Job, list[str]]:
    """Chunks and the job for cloud files. LAS/LAZ headers give counts and bounds without
    reading points; other formats are read once here for their bounds (they are read whole by
    their task too: only LAS/LAZ stream within a file)."""

    st = cfg.stream
    per_task = st.chunk_points * CHUNKS_PER_TASK
    chunks: list[CloudChunk] = []
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    notes: list[str] = []
    total = 0
    classes = cfg.scans.las_classes
    for f in files:
        # Workers may run elsewhere: an absolute path, or the URL as given.
        path: Path | str = str(f) if is_url(f) else Path(f).resolve()
        name = url_path(path).name
        if url_suffix(path) in LAS_SUFFIXES:
            info = las_info(path)
            if info.points == 0:
                raise InputError(path, "no point in the cloud (the header says 0)")
            # A LAZ of variable-size chunks (COPC) is read from its start only: one piece.
            piece = info.points if info.variable_chunks else per_task
            chunks += [
                CloudChunk(str(path), s, min(piece, info.points - s), min(piece, info.points - s))
                for s in range(0, info.points, piece)
            ]
            lo = np.minimum(lo, info.mins)
            hi = np.maximum(hi, info.maxs)
            n, fmt = info.points, info.format
        else:
            if is_url(path):
                raise InputError(path, "URLs are read for LAS/LAZ files only")
            if classes is not None:
                raise InputError(path, "LAS classes can only be selected in .las/.laz files")
            cloud = read_cloud(path)
            chunks.append(CloudChunk(str(path), size=len(cloud.points)))
            lo = np.minimum(lo, cloud.points.min(axis=0))
            hi = np.maximum(hi, cloud.points.max(axis=0))
            n, fmt = len(cloud.points), cloud.format
        total += n
        notes.append(f"{name}: {n:,} points ({fmt})")
    # The tiles and the merge take memory by the cells the points span: refused now, from the
    # bounds, rather than after streaming (the grid is sized again, exactly, before it is built).
    res = octree_resolution(cfg)
    cols, rows = (np.floor(hi[:2] / res) - np.floor(lo[:2] / res) + 1).astype(np.int64)
    refuse_large_grid(url_path(files[0]), "points", int(rows), int(cols), resolution=res, cfg=cfg)
    origin = local_origin(lo, hi, cfg.scans.local_origin, notes)
    job = Job(
        lattice_for(cfg),
        (float(origin[0]), float(origin[1]), float(origin[2])),
        st.chunk_points,
        None if classes is None else tuple(classes),
    )
    notes.append(f"streamed: {len(chunks)} piece(s) over {total:,} points")
    return chunks, job, notes


def plan_bag_chunks(
    bags: Sequence[Path], start_ns: int, end_ns: int, messages: int
) -> list[BagChunk]:
    """Equal, disjoint time slices of ``[start_ns, end_ns]`` (bag time, inclusive), about
    ``SCANS_PER_TASK`` scan messages each if they are evenly spread. Planned from the bag's
    index (counts and span) alone: no pass over the messages."""
    paths = tuple(str(Path(b).resolve()) for b in bags)
    n = max(1, min(math.ceil(messages / SCANS_PER_TASK), end_ns - start_ns + 1))
    edges = start_ns + (np.arange(n + 1, dtype=np.int64) * (end_ns - start_ns + 1)) // n
    return [BagChunk(paths, int(a), int(b) - 1) for a, b in itertools.pairwise(edges)]


# --- one task ---------------------------------------------------------------------------------


def rasterize(task: Sequence[Chunk], job: Job) -> tuple[TileRecords, BeamRecorder | None]:
    """The cells of a task's end points (one or more chunks): a Dask task's work. Only the
    cells with a point travel back, not the tiles they were counted in; with them, for a bag,
    the recorded beams of its scans (for the replay)."""
    tiles = TileSet(job.lattice)
    recorder = _recorder(job)
    for _, points in _read_ahead(_numbered_points(task, job, recorder)):
        if points is not None:
            tiles.add_points(points)
    return tiles.records(), recorder


def _recorder(job: Job) -> BeamRecorder | None:
    """A bag's scans are recorded for the replay (the sensor poses and beams)."""
    if job.bag is None:
        return None

    return BeamRecorder()


def tasks_of(chunks: Sequence[Chunk], points_per_task: int) -> list[tuple[Chunk, ...]]:
    """Consecutive chunks grouped into tasks of about ``points_per_task`` points (files are
    listed side by side, usually neighbours, so a task's tiles overlap); a bag slice is a task
    of its own."""
    tasks: list[tuple[Chunk, ...]] = []
    group: list[Chunk] = []
    held = 0
    for chunk in chunks:
        size = chunk.size if isinstance(chunk, CloudChunk) else points_per_task
        if group and held + size > points_per_task:
            tasks.append(tuple(group))
            group, held = [], 0
        group.append(chunk)
        held += size
    if group:
        tasks.append(tuple(group))
    return tasks


def _read_ahead(items: Iterator[T]) -> Iterator[T]:
    """``items``, produced on another thread one item ahead; its exceptions re-raised here."""

    box: queue.Queue[tuple[bool, object]] = queue.Queue(maxsize=1)
    stop = threading.Event()

    def produce() -> None:
        try:
            for item in items:
                if stop.is_set():
                    return
                box.put((True, item))
        except BaseException as exc:  # handed to the consumer, raised there
            box.put((False, exc))
            return
        box.put((False, None))

    worker = threading.Thread(target=produce, name="scan2terrain-read-ahead", daemon=True)
    worker.start()
    try:
        while True:
            ok, item = box.get()
            if not ok:
                if item is not None:
                    raise item  # type: ignore[misc]
                return
            yield item  # type: ignore[misc]
    finally:
        stop.set()
        with contextlib.suppress(queue.Empty):
            box.get_nowait()  # unblock a producer waiting to put
        worker.join()


def _chunk_points(
    chunk: Chunk, job: Job, recorder: BeamRecorder | None = None
) -> Iterator[NDArray[np.float64]]:
    """The chunk's points less the job's local origin, ``job.step`` at a time (a bag's scans
    also into ``recorder``, when given)."""
    if isinstance(chunk, BagChunk):
        yield from _bag_points(chunk, job, recorder)
        return

    origin = np.array(job.origin)
    if url_suffix(chunk.path) in LAS_SUFFIXES:
        yield from iter_las(
            chunk.path,
            start=chunk.start,
            count=chunk.count,
            step=job.step,
            las_classes=job.las_classes,
            origin=origin,
        )
        return
    points = read_cloud(chunk.path).points
    for s in range(0, len(points), job.step):
        yield points[s : s + job.step] - origin


def _bag_points(
    chunk: BagChunk, job: Job, recorder: BeamRecorder | None
) -> Iterator[NDArray[np.float64]]:

    from scan2terrain.readers.bag import open_bag

    assert job.bag is not None, "a bag chunk needs the bag's plan"
    plan = replace(job.bag.plan, start_ns=chunk.start_ns, end_ns=chunk.end_ns)
    cfg = job.bag.config
    buf: list[NDArray[np.float64]] = []
    held = 0
    with open_bag([Path(p) for p in chunk.paths]) as bag:
        counts = ScanCounts()
        for scan in posed_scans(bag, cfg.scans, plan, counts, max_range=cfg.octree.max_range):
            hits = hits_of(scan)
            if recorder is not None:
                recorder.add(scan, hits)
            buf.append(hits)
            held += len(hits)
            if held >= job.step:
                yield np.concatenate(buf)
                buf, held = [], 0
    if buf:
        yield np.concatenate(buf)


# --- running ----------------------------------------------------------------------------------


def run(
    chunks: Sequence[Chunk], job: Job, cfg: Config, progress: StreamProgress | None = None
) -> tuple[TileSet, BeamRecorder | None]:
    """Every chunk rasterized and merged: here, or on Dask with ``stream.workers`` or
    ``stream.scheduler``; for a bag, its recorded beams too. The result does not depend on
    which."""
    if cfg.stream.distributed:
        return _run_dask(chunks, job, cfg, progress)
    # Straight into the result (the same sums, no merge), reading ahead across chunks: a file
    # of one chunk is read while the previous one is rasterized, on numba's threads (the same
    # records on any number).
    total = TileSet(job.lattice, threads=numba_threads())
    recorder = _recorder(job)
    for i, points in _read_ahead(_numbered_points(chunks, job, recorder)):
        if points is None:  # chunk i is done
            if progress is not None:
                progress(i + 1, len(chunks), total.points)
            continue
        total.add_points(points)
    return total, recorder


def numba_threads() -> int:
    """The threads numba may run (``NUMBA_NUM_THREADS``, every core by default), read without
    starting its threading layer."""
    from scan2terrain._numba import numba

    threads: int = numba.config.NUMBA_NUM_THREADS  # type: ignore[attr-defined]
    return threads


def _numbered_points(
    chunks: Sequence[Chunk], job: Job, recorder: BeamRecorder | None = None
) -> Iterator[tuple[int, NDArray[np.float64] | None]]:
    """(chunk number, points) for every piece of every chunk, then (chunk number, None)."""
    for i, chunk in enumerate(chunks):
        for points in _chunk_points(chunk, job, recorder):
            yield i, points
        yield i, None


def _run_dask(
    chunks: Sequence[Chunk], job: Job, cfg: Config, progress: StreamProgress | None
) -> tuple[TileSet, BeamRecorder | None]:
    """The chunks as Dask tasks (:func:`tasks_of`); results merged on the client as they
    complete. A task whose worker dies is run again by Dask on another worker, and its result
    counts once: only a completed task's result is merged, and every task completes once."""
    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise ConfigError(
            "stream.workers/stream.scheduler need Dask: pip install 'scan2terrain[dask]'"
        ) from None
    st = cfg.stream
    total = TileSet(job.lattice)
    recorder = _recorder(job)
    with contextlib.ExitStack() as stack:
        if st.scheduler:
            try:
                client = stack.enter_context(Client(st.scheduler, timeout="10s"))
            except OSError as exc:
                raise ConfigError(
                    f"stream.scheduler {st.scheduler}: cannot connect ({exc})"
                ) from exc
        else:
            cluster = stack.enter_context(
                LocalCluster(
                    n_workers=st.workers,
                    threads_per_worker=1,
                    processes=True,
                    dashboard_address=None,
                )
            )
            client = stack.enter_context(Client(cluster))
        tasks = tasks_of(chunks, st.chunk_points * CHUNKS_PER_TASK)
        futures = client.map(rasterize, tasks, job=job, pure=False)
        for done, future in enumerate(as_completed(futures), start=1):
            records, part = future.result()
            total.merge(records)
            if recorder is not None and part is not None:
                recorder.merge(part)  # the same beams in any order (replay/beams.py)
            future.release()
            if progress is not None:
                progress(done, len(futures), total.points)
    return total, recorder


# --- commands ---------------------------------------------------------------------------------


def stream_clouds(
    files: Sequence[Path | str], cfg: Config, progress: StreamProgress | None = None
) -> Streamed:
    chunks, job, notes = plan_clouds(files, cfg)
    tiles, _ = run(chunks, job, cfg, progress)
    return Streamed(tiles, tuple(notes), origin=job.origin)


def stream_bag(
    bags: Sequence[Path], cfg: Config, progress: StreamProgress | None = None
) -> Streamed:
    """A bag's end points (hits, in the fixed frame) streamed into tiles. The client plans and
    reads tf once; the scans' stamps come from the bag's index, without decoding scans."""
    from scan2terrain.readers.bag import open_bag

    with open_bag(list(bags)) as bag:
        plan = plan_bag(bag, cfg.scans, max_range=cfg.octree.max_range)
        if plan.map_topic is not None:
            raise InputError(bag.path, f"{plan.map_topic} is a map, not scans: nothing to stream")
        corrected = correct_plan(bag, cfg, plan)
        bag.require_messages(plan.scan_topics, plan.start_ns, plan.end_ns)
        # The first posed scan only (one batch of messages): the spawn pose's starting point.
        scans = posed_scans(bag, cfg.scans, plan, ScanCounts(), max_range=cfg.octree.max_range)
        first = next(scans, None)
        del scans
        messages = sum(bag.count(plan.scan_topics).values())
        lo = bag.start_ns if plan.start_ns is None else max(plan.start_ns, bag.start_ns)
        hi = bag.end_ns if plan.end_ns is None else min(plan.end_ns, bag.end_ns)
    chunks = plan_bag_chunks(bags, lo, hi, messages)
    job = Job(lattice_for(cfg), (0.0, 0.0, 0.0), cfg.stream.chunk_points, bag=BagJob(plan, cfg))
    tiles, recorder = run(chunks, job, cfg, progress)
    notes = [*plan.reasons, f"streamed: {len(chunks)} piece(s) over {messages:,} scan messages"]
    notes += corrected
    assert recorder is not None  # a bag job records
    replay = scan_replay(recorder, plan.pose_source, cfg, plan.correction)
    return Streamed(
        tiles,
        tuple(notes),
        None if first is None else start_of(first),
        replay=replay,
        poses=plan.poses,
        corrected=plan.correction is not None,
    )


def streamed_folder(streamed: Streamed, source: Path, cfg: Config) -> WorldFolder:
    """The merged tiles to a world folder: occupancy (cells with a point occupied, the rest
    unknown) or a 2.5D height grid (``octree.height_stat`` of the points' z, holes filled as
    ``octree.fill`` says), then as every other grid. The tiles are consumed: emptied once the
    grid is made, so their memory is not held while the world is built."""

    tiles = streamed.tiles
    read = [*streamed.notes, f"points counted: {tiles.points:,}"]
    extra = {} if streamed.replay is None else {"replay": streamed.replay}
    # The grid holds what the world needs: the tiles' records go before the world is made.
    if cfg.octree.grid == "occupancy":
        refuse_tiles_grid(tiles, cfg, source)  # sized before the dense grid is allocated
        grid = tiles.occupancy()
        tiles.clear()
        hint = solid_hint(grid)
        folder = occupancy_folder(grid, source, cfg, start=streamed.start, scans=True)
        folder = folder.noted(then=[hint] if hint else [])
    else:  # the octree path's heights come from the same step (commands/voxels.py)
        heights, notes = point_heights(tiles, cfg, source)
        folder = height_folder(heights, source, cfg, start=streamed.start).noted(then=notes)
    return folder.noted(first=read).with_extra(extra)
