"""bag2world on a PointCloud2 bag beside rosbags, and on laser logs beside OctoMap (by hand).

    python benchmarks/bench_bag2world.py [--quick] [--cache DIR]
        [--formats mcap,ros1,mcap-ros1,foxglove-protobuf]

The data: a synthetic place, a 40 x 20 x 4 m hall (walls and floor, no roof) with pillars and
crates (axis-aligned boxes), and a lidar on a robot driving an ellipse through it. Each cloud is
20,000 points (float32 x, y, z, intensity; point_step 16) in the lidar frame: the rays of a fixed
48 x 512 pattern cast against the boxes (a small numba kernel, ~5 ms a cloud), the hits within
30 m thinned evenly to 20,000. Clouds at 10 Hz on /points; /tf odom -> base_link at 20 Hz and
map -> odom at 1 Hz; /tf_static base_link -> lidar. Bags are written with rosbags' writers (and
the test helpers of tests/bagmaker.py): rosbag2 with MCAP storage, no compression, and a ROS1
.bag (uncompressed chunks). A lap is 1,000 clouds (--quick: 100); a longer bag drives the same
lap again (same place, later stamps). Bags are written once per run into a temporary folder, or
kept in --cache DIR, named by a digest of the scene's parameters, and reused.

Measured, and printed as tables:

1. Throughput on 1,000 clouds (20 M points), per format: rosbags alone (``AnyReader``,
   ``messages()`` of every connection, ``deserialize`` of each message, nothing else) beside
   ``scans.bag2world`` with ``scans.insert = endpoints`` and ``octree.resolution = 0.1``, the
   library call of ``scan2terrain bag2world BAG -o OUT --insert endpoints --resolution 0.1``
   (read, pose, transform, insert, project, export; the output folder overwritten each run),
   in this process after a warm-up; again with one numba thread; and the CLI itself once in a
   fresh process (start-up, imports and the numba cache included), and on a 3-cloud bag for
   that fixed start-up cost. Target (issue 17; issue 16 asked 10): bag2world >= 20 M points/s.
2. Where bag2world's time goes: one run with every stage timed by wrapping the functions
   bag2world calls (open_bag, plan_bag with its tf pass, rosbags' raw read and deserialise,
   pointcloud2_xyz, the rest of posed_scans = pose lookup + transform, insert_endpoints,
   occupied_and_free + .bt, voxels_folder + write_world_folder = projection + export).
3. Peak memory against recording length: bag2world on one lap and on ten laps of the same place
   (1,000 and 10,000 clouds; --quick: 100 and 1,000), each in a fresh process (through a small
   launcher, so ru_maxrss is the child's own), ru_maxrss after the run. Target: the long bag
   peaks within 1.1x of the short one.
4. Laser logs (issue 31), also with --quick: the bundled MIT CSAIL CARMEN log
   (fixtures/logs/raw_carmen_mit_csail/mit-csail.clf.bz2, 1,988 scans) and a synthetic rosbag2
   (MCAP) log of 5,000 LaserScans of 360 beams: a 40 x 20 m floor (a corridor, ten rooms with
   doorways, a table and a cabinet in each), a robot at 0.45 m/s through every room, range_max
   30 m (inf beyond), 1 cm noise, 0.5% NaN beams, /tf map -> odom (1 Hz) -> base_link (20 Hz),
   /tf_static base_link -> laser, scan stamps between tf samples; ranges cast with
   tests/bagmaker.py's cast_rays and written with its laserscan_msg, tf_msg and write_bag, once
   into --cache. Ours: ``scan2terrain bag2world LOG -o OUT --no-filter --max-range 30
   --resolution 0.05 --correct off --no-fidelity`` (OctoMap's settings; no correction nor
   replay, so both sides read, pose, insert by ray casting and write) in a fresh process: wall
   time and ru_maxrss (through a launcher); and the same command in this process with
   VoxelOctree.insert_scan (and insert_scans, where it exists) wrapped: the insertion's seconds
   and beams/s. OctoMap: octomap-python ``OcTree(0.05).insertPointCloud(points, origin,
   maxrange)`` per scan over the same scans (scan2terrain's reader, posed_scans: float64
   world-frame points with clear-only beams beyond the cut-off, the same cut-off, 30 m plus the
   reader's slack), saved to an .npz and loaded by a fresh process that times the loop alone:
   seconds, beams/s, ru_maxrss, and ru_maxrss minus that after loading the scans ('tree').
   Targets: OctoMap's insertion time / our whole process >= 10, our peak <= OctoMap's, >= 2 M
   beams/s through our insertion. --quick keeps the full 5,000-scan log (OctoMap's loop takes
   ~35-45 s on it here). One run each: on a shared machine the ratios move by ~20%.

Times are wall clock (time.perf_counter); "best" is the minimum over the repetitions and
"median" their median; "cpu" is the process's CPU time (every thread) in the best run. The
machine may be shared: the load average is printed at the start and the end, and rates on a
loaded machine are lower bounds. --quick: 100-cloud laps, fewer repetitions, MCAP only
(the laser logs as in full mode).
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import gc
import hashlib
import importlib.metadata
import json
import math
import os
import platform
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

ROOT = Path(__file__).resolve().parent.parent

# --- the place: a hall, pillars and crates (axis-aligned boxes, metres, map frame) --------------

HALL_LO = np.array([-20.0, -10.0, 0.0])
HALL_HI = np.array([20.0, 10.0, 4.0])
#: x0, y0, z0, x1, y1, z1 of each box.
BOXES = np.array(
    [
        # pillars, floor to top
        [-10.2, -0.2, 0.0, -9.8, 0.2, 4.0],
        [-0.2, -0.2, 0.0, 0.2, 0.2, 4.0],
        [9.8, -0.2, 0.0, 10.2, 0.2, 4.0],
        [-5.2, 2.8, 0.0, -4.8, 3.2, 4.0],
        [4.8, -3.2, 0.0, 5.2, -2.8, 4.0],
        # crates and shelves along the walls (outside the robot's loop)
        [-19.0, -9.5, 0.0, -16.0, -8.0, 1.5],
        [15.0, 7.5, 0.0, 18.5, 9.5, 2.0],
        [-2.0, 8.5, 0.0, 2.0, 9.8, 1.0],
        [3.0, -9.8, 0.0, 6.0, -8.8, 2.5],
        [17.5, -6.0, 0.0, 19.5, -2.0, 1.2],
        [-19.5, 3.0, 0.0, -18.0, 7.0, 3.0],
        # low boxes inside the loop
        [-7.0, -2.0, 0.0, -5.0, -1.0, 0.8],
        [6.0, 1.0, 0.0, 8.0, 2.5, 1.6],
        [-1.0, -4.0, 0.0, 1.0, -3.0, 0.5],
    ]
)
#: The robot's loop: an ellipse around the hall's centre (semi-axes, metres).
LOOP = (14.0, 6.0)
#: The lidar: rings x azimuth steps, elevations (degrees), range limit (metres).
RINGS, AZIMUTHS = 48, 512
ELEVATION = (-25.0, 12.0)
RANGE_MAX = 30.0
POINTS = 20_000
RATE_HZ = 10.0
#: bag2world's end-to-end rate to reach, million points a second (issue 17).
TARGET_MPTS = 20.0
TF_RATE_HZ = 20.0  #: odom -> base_link; map -> odom at 1 Hz
START_NS = 1_700_000_000_000_000_000
LAG_NS = 5_000_000  #: record time - header stamp of a cloud
#: base_link -> lidar (x, y, z, roll, pitch, yaw), on /tf_static.
MOUNT = (0.25, 0.0, 1.1, 0.0, 0.04, 0.0)
#: map -> odom (x, y, yaw), constant, on /tf at 1 Hz.
MAP_TO_ODOM = (0.5, -0.3, 0.02)
FRAME = "lidar"
TOPIC = "/points"
RESOLUTION = 0.1
#: Bumped when the scene or the writer changes (part of the cached bags' names).
BAG_VERSION = 1
FORMAT_NAMES = {
    "mcap": "rosbag2 MCAP (no compression)",
    "ros1": "ROS1 .bag (uncompressed)",
    "mcap-ros1": "ROS1 MCAP (profile ros1, no compression)",
    "foxglove-protobuf": "Foxglove protobuf MCAP (PointCloud + FrameTransforms, no compression)",
}


def _cast_kernel() -> Any:
    """The numba ray caster (compiled on first use, ~1 s; not cached to disk)."""
    import numba

    @numba.njit(error_model="numpy", cache=False)
    def cast(
        origin: NDArray[np.float64],
        dirs: NDArray[np.float64],
        lo: NDArray[np.float64],
        hi: NDArray[np.float64],
        boxes: NDArray[np.float64],
        max_range: float,
    ) -> NDArray[np.float64]:  # pragma: no cover - compiled
        n = dirs.shape[0]
        out = np.empty(n)
        for i in range(n):
            inv0, inv1, inv2 = 1.0 / dirs[i, 0], 1.0 / dirs[i, 1], 1.0 / dirs[i, 2]
            tx = ((hi[0] if inv0 > 0 else lo[0]) - origin[0]) * inv0
            ty = ((hi[1] if inv1 > 0 else lo[1]) - origin[1]) * inv1
            t = min(tx, ty)
            if inv2 < 0:
                t = min(t, (lo[2] - origin[2]) * inv2)
            elif (hi[2] - origin[2]) * inv2 < t:
                t = np.inf  # leaves over the walls (the hall has no roof)
            for b in range(boxes.shape[0]):
                a1 = (boxes[b, 0] - origin[0]) * inv0
                a2 = (boxes[b, 3] - origin[0]) * inv0
                near, far = min(a1, a2), max(a1, a2)
                a1 = (boxes[b, 1] - origin[1]) * inv1
                a2 = (boxes[b, 4] - origin[1]) * inv1
                near, far = max(near, min(a1, a2)), min(far, max(a1, a2))
                a1 = (boxes[b, 2] - origin[2]) * inv2
                a2 = (boxes[b, 5] - origin[2]) * inv2
                near, far = max(near, min(a1, a2)), min(far, max(a1, a2))
                if near <= far and 0 < near < t:
                    t = near
            out[i] = t if t <= max_range else np.inf
        return out

    return cast


def rpy(roll: float, pitch: float, yaw: float) -> NDArray[np.float64]:
    from scan2terrain.readers.poses import rpy_matrix

    return rpy_matrix(roll, pitch, yaw)


def quaternion(r: NDArray[np.float64]) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation matrix (one with w well away from 0, as here)."""
    w = math.sqrt(max(1.0 + r[0, 0] + r[1, 1] + r[2, 2], 0.0)) / 2
    return (
        (r[2, 1] - r[1, 2]) / (4 * w),
        (r[0, 2] - r[2, 0]) / (4 * w),
        (r[1, 0] - r[0, 1]) / (4 * w),
        w,
    )


def base_pose(phase: NDArray[np.float64]) -> NDArray[np.float64]:
    """x, y, yaw (map frame) of base_link at loop phases (radians)."""
    a, b = LOOP
    return np.stack(
        [a * np.cos(phase), b * np.sin(phase), np.arctan2(b * np.cos(phase), -a * np.sin(phase))],
        axis=-1,
    )


@dataclass(frozen=True)
class Lap:
    """One lap of clouds: each (POINTS, 4) float32 x, y, z, intensity in the lidar frame."""

    clouds: list[NDArray[np.float32]]
    seconds: float
    ranges: tuple[float, float, float]  #: min, median, max over the lap


def lidar_lap(n: int) -> Lap:
    """``n`` clouds evenly spaced along one loop: rays of a fixed pattern (rings x azimuths)
    cast against the hall, the hits within RANGE_MAX thinned evenly to POINTS."""
    t0 = time.perf_counter()
    cast = _cast_kernel()
    el = np.repeat(np.deg2rad(np.linspace(*ELEVATION, RINGS)), AZIMUTHS)
    az = np.tile(np.linspace(-np.pi, np.pi, AZIMUTHS, endpoint=False), RINGS)
    dirs = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    mount_r = rpy(*MOUNT[3:])
    mount_t = np.array(MOUNT[:3])
    poses = base_pose(2 * np.pi * np.arange(n) / n)
    clouds = []
    lo, med, hi = np.inf, [], 0.0
    for x, y, yaw in poses:
        r = rpy(0.0, 0.0, yaw) @ mount_r
        origin = np.array([x, y, 0.0]) + rpy(0.0, 0.0, yaw) @ mount_t
        t = cast(origin, dirs @ r.T, HALL_LO, HALL_HI, BOXES, RANGE_MAX)
        hit = np.flatnonzero(np.isfinite(t))
        if len(hit) < POINTS:
            raise RuntimeError(f"only {len(hit)} hits at {x:.2f}, {y:.2f}: widen the pattern")
        hit = hit[np.linspace(0, len(hit) - 1, POINTS).astype(np.int64)]
        d = t[hit]
        cloud = np.empty((POINTS, 4), dtype=np.float32)
        cloud[:, :3] = dirs[hit] * d[:, None]
        cloud[:, 3] = 100.0 / (1.0 + d)  # something intensity-like
        clouds.append(cloud)
        lo, hi = min(lo, float(d.min())), max(hi, float(d.max()))
        med.append(float(np.median(d)))
    return Lap(clouds, time.perf_counter() - t0, (lo, float(np.median(med)), hi))


# --- the bag --------------------------------------------------------------------------------------


def _bagmaker() -> Any:
    """tests/bagmaker.py (the test suite's bag writer helpers)."""
    if str(ROOT / "tests") not in sys.path:
        sys.path.insert(0, str(ROOT / "tests"))
    import bagmaker  # type: ignore[import-not-found]

    return bagmaker


def bag_messages(lap: Lap, laps: int) -> Iterator[tuple[str, str, int, dict[str, Any]]]:
    """(topic, msgtype, record time ns, message dict) in record-time order: ``laps`` times the
    lap's clouds at RATE_HZ, /tf at TF_RATE_HZ (odom -> base_link; map -> odom every second),
    /tf_static once."""
    bm = _bagmaker()
    n = len(lap.clouds)
    total = n * laps
    mount_q = quaternion(rpy(*MOUNT[3:]))
    yield (
        "/tf_static",
        bm.TF_MESSAGE,
        START_NS,
        bm.tf_msg([("base_link", FRAME, START_NS, MOUNT[:3], mount_q)]),
    )
    per = round(TF_RATE_HZ / RATE_HZ)
    tf_period = round(1e9 / TF_RATE_HZ)
    mx, my, myaw = MAP_TO_ODOM
    c, s = math.cos(myaw), math.sin(myaw)
    m2o_q = bm.yaw_quaternion(myaw)
    fields = [
        {"name": name, "offset": 4 * i, "datatype": 7, "count": 1}
        for i, name in enumerate(("x", "y", "z", "intensity"))
    ]
    for j in range(total * per + 1):
        t = START_NS + j * tf_period
        x, y, yaw = base_pose(np.array(2 * np.pi * j / (n * per)))
        # odom -> base_link = inverse(map -> odom) * (map -> base_link)
        dx, dy = float(x) - mx, float(y) - my
        edges = [
            (
                "odom",
                "base_link",
                t,
                (c * dx + s * dy, -s * dx + c * dy, 0.0),
                bm.yaw_quaternion(float(yaw) - myaw),
            ),
        ]
        if j % round(TF_RATE_HZ) == 0:
            edges.append(("map", "odom", t, (mx, my, 0.0), m2o_q))
        yield "/tf", bm.TF_MESSAGE, t + 1_000_000, bm.tf_msg(edges)
        if j % per == 0 and j // per < total:
            cloud = lap.clouds[(j // per) % n]
            yield (
                TOPIC,
                bm.POINT_CLOUD2,
                t + LAG_NS,
                {
                    "header": bm.header(t, FRAME),
                    "height": 1,
                    "width": len(cloud),
                    "fields": fields,
                    "is_bigendian": False,
                    "point_step": 16,
                    "row_step": 16 * len(cloud),
                    "data": cloud.view(np.uint8).reshape(-1),
                    "is_dense": True,
                },
            )


def write_bag(path: Path, fmt: str, lap: Lap, laps: int) -> float:
    """Write the bag (``fmt`` mcap: a rosbag2 folder, MCAP storage, no compression; ros1: a
    ``.bag`` file, uncompressed chunks); the seconds it took."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2

    bm = _bagmaker()
    if fmt in ("mcap-ros1", "foxglove-protobuf"):  # the ROS1 bag rewritten (tests/bagmaker.py)
        t0 = time.perf_counter()
        ros1 = path.with_name(path.stem + ".tmp.bag")
        write_bag(ros1, "ros1", lap, laps)
        if fmt == "mcap-ros1":  # as `mcap convert` does
            bm.ros1_bag_to_mcap(ros1, path, compression="none", chunk_size=1 << 20)
        else:  # as the Foxglove SDKs write: foxglove.PointCloud, foxglove.FrameTransforms
            bm.ros_bag_to_foxglove_mcap(ros1, path, "protobuf", compression="none")
        ros1.unlink()
        return time.perf_counter() - t0
    t0 = time.perf_counter()
    ts = bm.typestore("ros1" if fmt == "ros1" else "mcap")
    serialize = ts.serialize_ros1 if fmt == "ros1" else ts.serialize_cdr
    writer: Any = (
        Writer1(path)
        if fmt == "ros1"
        else Writer2(path, version=9, storage_plugin=StoragePlugin.MCAP)
    )
    conns: dict[str, Any] = {}
    with writer:
        for topic, msgtype, t_ns, msg in bag_messages(lap, laps):
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=ts)
            writer.write(conns[topic], t_ns, serialize(bm.build(ts, msgtype, msg), msgtype))
    return time.perf_counter() - t0


# --- timing helpers -------------------------------------------------------------------------------


@dataclass
class Timing:
    times: list[float]
    cpus: list[float]  #: CPU seconds of each run (every thread of the process)

    @property
    def cpu(self) -> float:
        """CPU seconds of the best run."""
        return self.cpus[self.times.index(self.best)]

    @property
    def best(self) -> float:
        return min(self.times)

    @property
    def median(self) -> float:
        return statistics.median(self.times)


def timed(fn: Callable[[], Any], repeats: int) -> Timing:
    """Wall-clock and CPU times of ``repeats`` calls (garbage collected before each, not timed)."""
    times, cpus = [], []
    for _ in range(repeats):
        gc.collect()
        c0, t0 = time.process_time(), time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    return Timing(times, cpus)


@contextlib.contextmanager
def numba_threads(n: int) -> Iterator[None]:
    import numba

    old = numba.get_num_threads()
    numba.set_num_threads(n)
    try:
        yield
    finally:
        numba.set_num_threads(old)


# --- what is measured -----------------------------------------------------------------------------


def rosbags_alone(bag: Path, *, deserialise: bool) -> int:
    """rosbags by itself: open the bag with AnyReader, read every message (and deserialise it);
    the number of messages."""
    from rosbags.highlevel import AnyReader

    n = 0
    with AnyReader([bag]) as reader:
        for conn, _, raw in reader.messages(reader.connections):
            if deserialise:
                reader.deserialize(raw, conn.msgtype)
            n += 1
    return n


def mcap_alone(bag: Path, *, deserialise: bool) -> int:
    """What bag2world reads a ROS1 MCAP with (scan2terrain's McapFile on the ``mcap`` package's
    records, rosbags' ROS1 deserialiser), by itself: every message (and decoded)."""
    from scan2terrain.readers._mcap import McapFile

    n = 0
    reader = McapFile(bag)
    try:
        for conn, _, raw in reader.messages(reader.connections):
            if deserialise:
                reader.decode(conn, raw)
            n += 1
    finally:
        reader.close()
    return n


def mcap_library_alone(bag: Path, protobuf: bool = False) -> int:
    """The ``mcap`` package's own reader and decoders (``mcap-ros1-support``, or
    ``mcap-protobuf-support`` with ``protobuf``, if installed) in a plain loop:
    ``iter_decoded_messages()`` over every message."""
    from mcap.reader import make_reader

    if protobuf:
        from mcap_protobuf.decoder import DecoderFactory
    else:
        from mcap_ros1.decoder import DecoderFactory  # type: ignore[import-not-found,no-redef]

    n = 0
    with bag.open("rb") as f:
        for _ in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            n += 1
    return n


def config() -> Any:
    """bag2world BAG -o OUT --insert endpoints --resolution 0.1, as a Config."""
    from scan2terrain.config import Config

    cfg = Config()
    cfg.scans.insert = "endpoints"
    cfg.octree.resolution = RESOLUTION
    return cfg.validate()


def bag2world(bag: Path, out: Path) -> Any:
    from scan2terrain.commands import scans

    return scans.bag2world([bag], out, config(), overwrite=True)


def warm_up(tmp: Path) -> float:
    """Load (or compile) the numba kernels and import the pipeline: a 3-cloud bag through
    bag2world; the seconds it took."""
    t0 = time.perf_counter()
    path = tmp / "warm_up"
    if not path.exists():
        write_bag(path, "mcap", Lap(lidar_lap_cached(3).clouds, 0.0, (0, 0, 0)), 1)
    bag2world(path, tmp / "warm_up_out")
    return time.perf_counter() - t0


_LAPS: dict[int, Lap] = {}


def lidar_lap_cached(n: int) -> Lap:
    if n not in _LAPS:
        _LAPS[n] = lidar_lap(n)
    return _LAPS[n]


#: (stage key, label) in the order printed.
STAGES = (
    ("open", "open the bag (open_bag: index, connections, types)"),
    ("plan", "plan + tf pass (plan_bag: topics, frames, /tf read once)"),
    ("plan.read", "   of which rosbags read (raw bytes)"),
    ("plan.deser", "   of which rosbags deserialise"),
    ("scans.read", "scans: rosbags read (raw bytes)"),
    ("scans.deser", "scans: rosbags deserialise"),
    ("decode", "scans: decode (pointcloud2_xyz)"),
    ("pose", "scans: pose + transform (rest of posed_scans)"),
    ("insert", "octree insert_endpoints"),
    ("loop", "bag_octree loop (counts, progress, _insert)"),
    ("voxels", "occupied_and_free + .bt bytes"),
    ("export", "project + export (voxels_folder, write_world_folder)"),
)


@contextlib.contextmanager
def stage_clock(acc: dict[str, float]) -> Iterator[None]:
    """Accumulate seconds per stage of scans.bag2world into ``acc`` by wrapping the functions
    it calls (looked up at call time on their modules or classes, so wrapping them times them).
    Generators are timed per next(); nested stages are subtracted when printing."""
    from rosbags.highlevel import AnyReader

    from scan2terrain.commands import scans as scan_commands
    from scan2terrain.commands import voxels as voxels_commands
    from scan2terrain.octree import bt
    from scan2terrain.octree.tree import VoxelOctree
    from scan2terrain.readers import bag as bagmod
    from scan2terrain.readers import scans

    phase = ["plan"]

    def add(key: str, seconds: float) -> None:
        acc[key] = acc.get(key, 0.0) + seconds

    def call(fn: Callable[..., Any], key: str | Callable[[], str]) -> Callable[..., Any]:
        @functools.wraps(fn)
        def inner(*args: Any, **kwargs: Any) -> Any:
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                add(key if isinstance(key, str) else key(), time.perf_counter() - t0)

        return inner

    def gen(fn: Callable[..., Iterator[Any]], key: Callable[[], str]) -> Callable[..., Any]:
        @functools.wraps(fn)
        def inner(*args: Any, **kwargs: Any) -> Iterator[Any]:
            it = fn(*args, **kwargs)
            while True:
                t0 = time.perf_counter()
                try:
                    item = next(it)
                except StopIteration:
                    add(key(), time.perf_counter() - t0)
                    return
                add(key(), time.perf_counter() - t0)
                yield item

        return inner

    def bag_octree(fn: Callable[..., Any]) -> Callable[..., Any]:
        @functools.wraps(fn)
        def inner(*args: Any, **kwargs: Any) -> Any:
            phase[0] = "scans"
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                add("bag_octree", time.perf_counter() - t0)
                phase[0] = "after"

        return inner

    patches: list[tuple[Any, str, Callable[[Any], Any]]] = [
        (bagmod, "open_bag", lambda f: call(f, "open")),
        (scans, "plan_bag", lambda f: call(f, "plan")),
        (bagmod.Bag, "_raw", lambda f: gen(f, lambda: f"{phase[0]}.read")),
        (AnyReader, "deserialize", lambda f: call(f, lambda: f"{phase[0]}.deser")),
        (scans, "pointcloud2_xyz", lambda f: call(f, "decode")),
        (scans, "posed_scans", lambda f: gen(f, lambda: "posed")),
        (VoxelOctree, "insert_endpoints", lambda f: call(f, "insert")),
        (scan_commands, "bag_octree", bag_octree),
        (VoxelOctree, "occupied_and_free", lambda f: call(f, "voxels")),
        (bt, "bt_bytes", lambda f: call(f, "voxels")),
        (voxels_commands, "voxels_folder", lambda f: call(f, "export")),
        (scan_commands, "write_world_folder", lambda f: call(f, "export")),
    ]
    saved = []
    for owner, name, wrap in patches:
        original = owner.__dict__[name]
        saved.append((owner, name, original))
        setattr(owner, name, wrap(original))
    try:
        yield
    finally:
        for owner, name, original in reversed(saved):
            setattr(owner, name, original)
    acc["pose"] = acc.get("posed", 0.0) - sum(
        acc.get(k, 0.0) for k in ("scans.read", "scans.deser", "decode")
    )
    acc["loop"] = acc.get("bag_octree", 0.0) - acc.get("posed", 0.0) - acc.get("insert", 0.0)


# --- memory: a fresh process per bag --------------------------------------------------------------


def _status_kb(field: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    return -1


def child_memory(bag: Path, out: Path, warm: Path) -> None:
    """Runs in the child process: bag2world on one bag, its memory as JSON on stdout."""
    warm_up(warm)  # imports, numba kernels, a tiny bag through the whole pipeline
    gc.collect()
    base = {
        "base_peak_kb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss,
        "base_hwm_kb": _status_kb("VmHWM"),
    }
    t0 = time.perf_counter()
    result = bag2world(bag, out)
    seconds = time.perf_counter() - t0
    print(
        json.dumps(
            base
            | {
                "peak_kb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss,
                "hwm_kb": _status_kb("VmHWM"),
                "seconds": seconds,
                "notes": list(result.notes),
            }
        )
    )


#: Linux carries a process's peak RSS into ru_maxrss across fork and exec, so a child of this
#: (by then large) process would report at least the parent's peak. A small launcher in between
#: gives the child a clean count: it inherits only the launcher's ~10 MB.
_LAUNCHER = "import subprocess, sys; sys.exit(subprocess.run(sys.argv[1:]).returncode)"


def measure_memory(bag: Path, out: Path, warm: Path) -> dict[str, Any]:
    """bag2world on ``bag`` in a fresh process (via the launcher): its memory and time."""
    script = str(Path(__file__).resolve())
    child = [sys.executable, script, "--child", str(bag), str(out), str(warm)]
    cmd = [sys.executable, "-S", "-c", _LAUNCHER, *child]
    done = subprocess.run(cmd, check=True, capture_output=True, text=True)
    result: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


def run_cli(bag: Path, out: Path) -> Timing:
    """``scan2terrain bag2world BAG -o OUT --insert endpoints --resolution 0.1`` in a fresh
    process, once; wall-clock and CPU seconds (Python start-up, imports, numba cache included)."""
    exe = Path(sys.executable).with_name("scan2terrain")
    cmd = [str(exe), "bag2world", str(bag), "-o", str(out), "--overwrite", "-q"]
    cmd += ["--insert", "endpoints", "--resolution", str(RESOLUTION)]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
    return Timing([seconds], [cpu])


# --- laser logs: bag2world beside OctoMap's insertion ---------------------------------------------

#: The MIT CSAIL CARMEN log bundled in fixtures (1,988 scans).
CARMEN_LOG = ROOT / "fixtures" / "logs" / "raw_carmen_mit_csail" / "mit-csail.clf.bz2"
#: The synthetic laser log: scans, beams per scan (360 degrees), range limit and voxel side
#: (OctoMap's settings for 2D logs), scan and tf rates, robot speed.
LOG_SCANS, LOG_BEAMS, LOG_RANGE_MAX, LOG_RESOLUTION = 5000, 360, 30.0, 0.05
LOG_RATE_HZ, LOG_TF_HZ, LOG_SPEED = 10.0, 20.0, 0.45
LOG_NOISE, LOG_DROPOUT = 0.01, 0.005  #: range noise sigma (m), share of beams with no return
#: base_link -> laser (x, y, z, yaw) and map -> odom (x, y, yaw).
LOG_MOUNT = (0.2, 0.0, 0.3, 0.0)
LOG_MAP_TO_ODOM = (0.3, -0.2, 0.05)
LOG_STAMP_OFFSET_NS = 17_000_000  #: scan stamps fall between tf samples (poses interpolated)
#: Bumped when the building, the path or the writer changes (part of the cached logs' names).
LOG_VERSION = 1
#: bag2world's targets on laser logs (issue 31): x OctoMap's insertion time end to end, peak
#: memory at most OctoMap's, M beams a second through insertion.
TARGET_X_OCTOMAP, TARGET_PEAK_RATIO, TARGET_MBEAMS = 10.0, 1.0, 2.0
#: The room centres along the corridor (x, metres); rooms are 8 m wide on both sides.
ROOM_XS = (-16.0, -8.0, 0.0, 8.0, 16.0)


def building_segments() -> NDArray[np.float64]:
    """Wall segments (x0, y0, x1, y1; metres, map frame) of a 40 x 20 m floor: a 3 m corridor
    along x with five 8 x 8.5 m rooms on each side, each with a 1 m doorway onto the corridor
    and a table and a cabinet inside. Walls lie 0.025 m off multiples of 0.05 m (as
    tests/bagmaker.py's room), so no wall falls on a voxel boundary."""
    off = 0.025
    x0, x1, y0, y1, cy = -20.0 + off, 20.0 + off, -10.0 + off, 10.0 + off, 1.5 + off
    segs: list[tuple[float, float, float, float]] = [
        (x0, y0, x1, y0),
        (x1, y0, x1, y1),
        (x1, y1, x0, y1),
        (x0, y1, x0, y0),
    ]
    for side in (1.0, -1.0):
        wall_y = side * cy
        doors = [(cx - 0.5, cx + 0.5) for cx in ROOM_XS]
        edges = [x0, *[e for d in doors for e in d], x1]
        segs += [(a, wall_y, b, wall_y) for a, b in zip(edges[::2], edges[1::2], strict=True)]
        for dx in (-12.0, -4.0, 4.0, 12.0):  # room dividers
            segs.append((dx + off, wall_y, dx + off, side * y1))
        for cx in ROOM_XS:
            for bx0, by0, bx1, by1 in (
                (cx + 2.0, 6.5, cx + 3.2, 7.3),  # a table
                (cx - 3.6, 3.0, cx - 3.0, 5.0),  # a cabinet against the divider
            ):
                ya, yb = sorted((side * by0 + off, side * by1 + off))
                xa, xb = bx0 + off, bx1 + off
                segs += [(xa, ya, xb, ya), (xb, ya, xb, yb), (xb, yb, xa, yb), (xa, yb, xa, ya)]
    return np.array(segs, dtype=np.float64)


def building_path() -> NDArray[np.float64]:
    """The robot's closed route (waypoints x, y): east along the corridor into every other room
    (through its door, a loop in the room, back out), then west into the rooms it skipped."""
    pts: list[tuple[float, float]] = [(-18.0, 0.3)]
    for lane, xs, first in ((0.3, ROOM_XS, 1.0), (-0.3, ROOM_XS[::-1], -1.0)):
        for i, cx in enumerate(xs):
            s = first if i % 2 == 0 else -first
            pts += [(cx, lane), (cx, 3 * s), (cx - 1.5, 6 * s), (cx + 1.5, 6 * s), (cx, 3 * s)]
            pts.append((cx, lane))
        pts.append((18.0 if lane > 0 else -18.0, lane))
        if lane > 0:
            pts.append((18.0, -0.3))
    return np.array(pts, dtype=np.float64)


def route_poses(t_s: NDArray[np.float64]) -> NDArray[np.float64]:
    """x, y, yaw (map frame) of base_link at times ``t_s`` (seconds): the route driven at
    LOG_SPEED, round and round, heading along the route (smoothed over 0.5 m)."""
    way = building_path()
    closed = np.vstack([way, way[:1]])
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(closed, axis=0).T))])

    def at(s: NDArray[np.float64]) -> NDArray[np.float64]:
        s = np.mod(s, cum[-1])
        return np.column_stack([np.interp(s, cum, closed[:, 0]), np.interp(s, cum, closed[:, 1])])

    s = LOG_SPEED * t_s
    ahead, behind = at(s + 0.25), at(s - 0.25)
    yaw = np.arctan2(ahead[:, 1] - behind[:, 1], ahead[:, 0] - behind[:, 0])
    return np.column_stack([at(s), yaw])


def laser_messages(n_scans: int) -> list[tuple[str, str, int, dict[str, Any]]]:
    """The log's messages (topic, msgtype, record time ns, message dict): /scan LaserScan in
    frame ``laser`` at LOG_RATE_HZ (ranges ray-cast against the building with
    tests/bagmaker.py's cast_rays, float32, Gaussian noise, a few beams with no return (NaN),
    nothing within LOG_RANGE_MAX: inf), /tf odom -> base_link at LOG_TF_HZ and map -> odom at
    1 Hz, /tf_static base_link -> laser."""
    bm = _bagmaker()
    rng = np.random.default_rng(31)
    segments = building_segments()
    period = round(1e9 / LOG_RATE_HZ)
    stamps = START_NS + LOG_STAMP_OFFSET_NS + np.arange(n_scans, dtype=np.int64) * period
    base = route_poses((stamps - START_NS) / 1e9)
    mx, my, mz, myaw = LOG_MOUNT
    mount = np.array([mx, my, myaw])
    sensor = bm._compose2d(base, mount)
    inc = 2 * np.pi / LOG_BEAMS
    local = -np.pi + inc * np.arange(LOG_BEAMS)
    msgs: list[tuple[str, str, int, dict[str, Any]]] = []
    for k0 in range(0, n_scans, 250):  # cast_rays is (scans x beams x segments): in slices
        k1 = min(k0 + 250, n_scans)
        dist = bm.cast_rays(sensor[k0:k1, :2], sensor[k0:k1, 2:3] + local[None, :], segments)
        dist = dist + rng.normal(0.0, LOG_NOISE, dist.shape)
        dist[rng.random(dist.shape) < LOG_DROPOUT] = np.nan
        dist[dist > LOG_RANGE_MAX] = np.inf
        for k in range(k0, k1):
            msg = bm.laserscan_msg(
                int(stamps[k]), "laser", -np.pi, inc, dist[k - k0], 0.05, LOG_RANGE_MAX
            )
            msgs.append(("/scan", bm.LASER_SCAN, int(stamps[k]) + LAG_NS, msg))
    n_tf = math.ceil((stamps[-1] - START_NS) / 1e9 * LOG_TF_HZ) + 2
    tf_stamps = START_NS + np.arange(n_tf, dtype=np.int64) * round(1e9 / LOG_TF_HZ)
    m2o = np.array(LOG_MAP_TO_ODOM)
    odom_base = bm._compose2d(bm._inverse2d(m2o), route_poses((tf_stamps - START_NS) / 1e9))
    per_second = round(LOG_TF_HZ)
    for j, stamp in enumerate(tf_stamps):
        t = int(stamp)
        x, y, yaw = odom_base[j]
        edges = [("odom", "base_link", t, (x, y, 0.0), bm.yaw_quaternion(yaw))]
        if j % per_second == 0:
            edges.append(("map", "odom", t, (m2o[0], m2o[1], 0.0), bm.yaw_quaternion(m2o[2])))
        msgs.append(("/tf", bm.TF_MESSAGE, t + 1_000_000, bm.tf_msg(edges)))
    static = bm.tf_msg([("base_link", "laser", START_NS, (mx, my, mz), bm.yaw_quaternion(myaw))])
    msgs.append(("/tf_static", bm.TF_MESSAGE, START_NS, static))
    return msgs


def ensure_laser_log(folder: Path, n_scans: int) -> tuple[Path, str]:
    """The synthetic laser log of ``n_scans`` scans (rosbag2, MCAP storage, written with
    tests/bagmaker.py's write_bag unless a complete one is cached) and what happened."""
    scene = repr(
        (
            LOG_VERSION,
            LOG_BEAMS,
            LOG_RANGE_MAX,
            LOG_RATE_HZ,
            LOG_TF_HZ,
            LOG_SPEED,
            LOG_NOISE,
            LOG_DROPOUT,
            LOG_MOUNT,
            LOG_MAP_TO_ODOM,
        )
    )
    path = folder / f"laser_{n_scans}_{hashlib.sha1(scene.encode()).hexdigest()[:8]}"
    done = path.with_name(path.name + ".done")
    if done.exists():
        return path, f"{path.name}: cached"
    if path.exists():
        shutil.rmtree(path)
    t0 = time.perf_counter()
    _bagmaker().write_bag(path, "mcap", laser_messages(n_scans))
    done.touch()
    return path, f"{path.name}: written in {time.perf_counter() - t0:.1f} s"


def log_argv(log: Path, out: Path) -> list[str]:
    """bag2world's arguments for a laser log: OctoMap's settings, correction and replay off."""
    return [
        "bag2world",
        str(log),
        "-o",
        str(out),
        "--overwrite",
        "-q",
        "--no-filter",
        "--max-range",
        format(LOG_RANGE_MAX, "g"),
        "--resolution",
        format(LOG_RESOLUTION, "g"),
        "--correct",
        "off",
        "--no-fidelity",
    ]


def log_config() -> Any:
    """The reader's part of log_argv as a Config (what posed_scans needs)."""
    from scan2terrain.config import Config

    cfg = Config()
    cfg.octree.resolution = LOG_RESOLUTION
    cfg.octree.max_range = LOG_RANGE_MAX
    cfg.scans.correct = "off"
    return cfg.validate()


def write_scans_npz(log: Path, npz: Path) -> tuple[int, int]:
    """The log's scans as scan2terrain's reader gives them to the octree (open_bag, plan_bag,
    posed_scans, as commands/scans.py's bag_octree): world-frame float64 points (hits, and
    clear-only beams beyond the cut-off), origins and cut-offs, in an .npz; (scans, beams)."""
    from scan2terrain.readers.bag import open_bag
    from scan2terrain.readers.scans import plan_bag, posed_scans
    from scan2terrain.types import ScanCounts

    cfg = log_config()
    points, origins, ranges = [], [], []
    with open_bag([log]) as bag:
        plan = plan_bag(bag, cfg.scans, max_range=cfg.octree.max_range)
        for scan in posed_scans(bag, cfg.scans, plan, ScanCounts(), max_range=LOG_RANGE_MAX):
            points.append(np.ascontiguousarray(scan.points, dtype=np.float64))
            origins.append(scan.origin)
            ranges.append(scan.max_range)
    offsets = np.concatenate([[0], np.cumsum([len(p) for p in points])]).astype(np.int64)
    np.savez(
        npz,
        points=np.concatenate(points),
        offsets=offsets,
        origins=np.array(origins, dtype=np.float64),
        max_ranges=np.array(ranges, dtype=np.float64),
    )
    return len(points), int(offsets[-1])


def child_octomap(npz: Path) -> None:
    """Runs in a fresh process: OctoMap's insertPointCloud over every scan of the .npz, timed
    alone; its time and memory as JSON on stdout."""
    import octomap

    data = np.load(npz)
    points, offsets = data["points"], data["offsets"]
    origins, max_ranges = data["origins"], data["max_ranges"]
    scans = np.split(points, offsets[1:-1])
    origin_list = list(origins)
    range_list = [float(r) for r in max_ranges]
    tree = octomap.OcTree(LOG_RESOLUTION)
    gc.collect()
    base_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t0 = time.perf_counter()
    for pts, origin, mr in zip(scans, origin_list, range_list, strict=True):
        tree.insertPointCloud(pts, origin, maxrange=mr)
    seconds = time.perf_counter() - t0
    peak_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    result = {
        "seconds": seconds,
        "base_kb": base_kb,
        "peak_kb": peak_kb,
        "leafs": int(tree.getNumLeafNodes()),
        "tree_bytes": int(tree.memoryUsage()),
    }
    print(json.dumps(result))


#: The launcher, reporting what the command in the child used (a fresh process has only its
#: own children in RUSAGE_CHILDREN): wall seconds and ru_maxrss of the child, as JSON.
_RUSAGE_LAUNCHER = (
    "import json, resource, subprocess, sys, time\n"
    "t0 = time.perf_counter()\n"
    "done = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL)\n"
    "seconds = time.perf_counter() - t0\n"
    "peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss\n"
    "print(json.dumps({'rc': done.returncode, 'seconds': seconds, 'peak_kb': peak}))\n"
)


def octomap_fresh(npz: Path) -> dict[str, Any]:
    """child_octomap in a fresh process (via the launcher, so ru_maxrss is its own)."""
    script = str(Path(__file__).resolve())
    child = [sys.executable, script, "--octomap-child", str(npz)]
    cmd = [sys.executable, "-S", "-c", _LAUNCHER, *child]
    done = subprocess.run(cmd, check=True, capture_output=True, text=True)
    result: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


def cli_fresh(log: Path, out: Path) -> dict[str, Any]:
    """``scan2terrain bag2world LOG -o OUT ...`` (log_argv) in a fresh process: its wall time
    (start-up, imports, numba cache, read, pose, insert, write) and ru_maxrss."""
    exe = str(Path(sys.executable).with_name("scan2terrain"))
    cmd = [sys.executable, "-S", "-c", _RUSAGE_LAUNCHER, exe, *log_argv(log, out)]
    done = subprocess.run(cmd, check=True, capture_output=True, text=True)
    result: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
    if result["rc"] != 0:
        raise RuntimeError(f"bag2world on {log} exited with {result['rc']}")
    return result


def insertion_seconds(log: Path, out: Path) -> float:
    """bag2world (the CLI's main, in this process, log_argv) with the octree's insertion
    methods wrapped (VoxelOctree.insert_scan, and insert_scans where it exists; a call inside
    another is not counted twice): the seconds spent inside them."""
    from scan2terrain import cli
    from scan2terrain.octree.tree import VoxelOctree

    acc = [0.0]
    depth = [0]

    def wrap(fn: Callable[..., Any]) -> Callable[..., Any]:
        @functools.wraps(fn)
        def inner(*args: Any, **kwargs: Any) -> Any:
            depth[0] += 1
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                depth[0] -= 1
                if depth[0] == 0:
                    acc[0] += time.perf_counter() - t0

        return inner

    names = [n for n in ("insert_scan", "insert_scans") if hasattr(VoxelOctree, n)]
    saved = [(n, VoxelOctree.__dict__[n]) for n in names]
    for name, original in saved:
        setattr(VoxelOctree, name, wrap(original))
    try:
        gc.collect()
        code = cli.main(log_argv(log, out))
    finally:
        for name, original in saved:
            setattr(VoxelOctree, name, original)
    if code != 0:
        raise RuntimeError(f"bag2world on {log} exited with {code}")
    return acc[0]


def insertion_methods() -> str:
    from scan2terrain.octree.tree import VoxelOctree

    return " + ".join(n for n in ("insert_scan", "insert_scans") if hasattr(VoxelOctree, n))


@dataclass(frozen=True)
class LogRun:
    name: str
    scans: int
    beams: int
    ours: dict[str, Any]  #: cli_fresh's result
    insert_s: float  #: our insertion, in this process
    octomap: dict[str, Any]  #: child_octomap's result


def laser_log_case(name: str, log: Path, folder: Path) -> LogRun:
    npz = folder / f"scans_{log.name}.npz"
    scans, beams = write_scans_npz(log, npz)
    octo = octomap_fresh(npz)
    npz.unlink()
    ours = cli_fresh(log, folder / "out_log")
    insert_s = insertion_seconds(log, folder / "out_log")
    return LogRun(name, scans, beams, ours, insert_s, octo)


# --- printing -------------------------------------------------------------------------------------


def mb(n_bytes: float) -> str:
    return f"{n_bytes / 2**20:8.1f}"


def verdict(ok: bool) -> str:
    return "PASS" if ok else "FAIL"


def load() -> str:
    return ", ".join(f"{x:.2f}" for x in os.getloadavg())


def machine_info() -> None:
    import numba

    try:
        cpu = next(
            line.split(":", 1)[1].strip()
            for line in Path("/proc/cpuinfo").read_text().splitlines()
            if line.startswith("model name")
        )
    except (OSError, StopIteration):
        cpu = platform.processor() or "?"
    print(f"machine: {platform.machine()}, {cpu}")
    print(
        f"cpus: os.cpu_count()={os.cpu_count()}, affinity={len(os.sched_getaffinity(0))}; "
        f"numba threads {numba.get_num_threads()}, threading layer "
        f"{numba.config.THREADING_LAYER!r}, OMP_WAIT_POLICY="  # type: ignore[attr-defined]
        f"{os.environ.get('OMP_WAIT_POLICY', '(unset)')}"
    )
    versions = {
        "python": platform.python_version(),
        "numpy": np.__version__,
        "numba": numba.__version__,
        "rosbags": importlib.metadata.version("rosbags"),
        "scan2terrain": importlib.metadata.version("scan2terrain"),
    }
    print("versions: " + ", ".join(f"{k} {v}" for k, v in versions.items()))
    print(f"load average (1, 5, 15 min) at start: {load()}")


# --- the benchmark --------------------------------------------------------------------------------


def bag_path(folder: Path, fmt: str, n: int, laps: int) -> Path:
    """Where the bag of these parameters lives (the name carries a digest of the scene)."""
    scene = repr((BAG_VERSION, RINGS, AZIMUTHS, ELEVATION, RANGE_MAX, POINTS, RATE_HZ, MOUNT))
    digest = hashlib.sha1(scene.encode()).hexdigest()[:8]
    name = f"points_{n}x{laps}_{digest}"
    suffix = {"ros1": ".bag", "mcap-ros1": ".mcap", "foxglove-protobuf": ".pb.mcap"}.get(fmt, "")
    return folder / (name + suffix)


def ensure_bag(folder: Path, fmt: str, n: int, laps: int) -> tuple[Path, str]:
    """The bag (written unless a complete one is cached) and a line saying what happened."""
    path = bag_path(folder, fmt, n, laps)
    done = path.with_name(path.name + ".done")
    if done.exists():
        return path, f"{path.name}: cached"
    if path.is_dir():
        shutil.rmtree(path)
    path.unlink(missing_ok=True)
    lap = lidar_lap_cached(n)
    seconds = write_bag(path, fmt, lap, laps)
    done.touch()
    return path, f"{path.name}: written in {seconds:.1f} s"


def size_of(path: Path) -> int:
    if path.is_dir():
        return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
    return path.stat().st_size


def run(*, quick: bool, folder: Path, formats: list[str]) -> None:
    wall0 = time.perf_counter()
    lap_n = 100 if quick else 1000
    reps_read, reps_b2w = (3, 2) if quick else (5, 3)
    print(f"bench_bag2world ({'--quick' if quick else 'full'} mode)")
    machine_info()
    summary: list[tuple[str, str, str, bool | None]] = []

    # --- the bags -------------------------------------------------------------------------------
    print()
    print(
        f"Bags: a {HALL_HI[0] - HALL_LO[0]:g} x {HALL_HI[1] - HALL_LO[1]:g} x {HALL_HI[2]:g} m "
        f"hall (walls, floor, no roof) with {len(BOXES)} boxes (pillars, crates); a lidar on a "
        f"robot driving an ellipse ({LOOP[0]:g} x {LOOP[1]:g} m), {lap_n} clouds per lap at "
        f"{RATE_HZ:g} Hz"
    )
    print(
        f"   each cloud: {POINTS:,} points, x y z intensity float32 (point_step 16), lidar frame; "
        f"rays of a {RINGS} x {AZIMUTHS} pattern ({ELEVATION[0]:g} to {ELEVATION[1]:g} deg) "
        f"cast against the hall (numba), hits within {RANGE_MAX:g} m thinned evenly to {POINTS:,}"
    )
    print(
        f"   tf: /tf odom->base_link at {TF_RATE_HZ:g} Hz, map->odom at 1 Hz, /tf_static "
        f"base_link->{FRAME}; a longer bag repeats the lap (same place, later stamps)"
    )
    n_big = 1000
    short, long_ = (lap_n, 10 * lap_n)
    bags: dict[tuple[str, int], Path] = {}
    for fmt, clouds in [(f, n_big) for f in formats] + [("mcap", short), ("mcap", long_)]:
        if (fmt, clouds) in bags:
            continue
        path, what = ensure_bag(folder, fmt, lap_n, clouds // lap_n)
        bags[fmt, clouds] = path
        print(
            f"   {FORMAT_NAMES[fmt]}, {clouds:,} clouds: {size_of(path) / 2**20:,.0f} MiB; {what}",
            flush=True,
        )
    if lap_n in _LAPS:  # some bag was written
        lap = _LAPS[lap_n]
        lo, med, hi = lap.ranges
        print(
            f"   one lap of {lap_n} clouds generated in {lap.seconds:.1f} s (ray casting; "
            f"ranges {lo:.2f}-{hi:.2f} m, median {med:.1f} m), then written as above"
        )
    warm = folder / "warm"
    warm.mkdir(exist_ok=True)
    print(
        f"   warm-up (imports, numba kernels, a 3-cloud bag through bag2world): "
        f"{warm_up(warm):.2f} s"
    )

    # --- 1. throughput --------------------------------------------------------------------------
    n_pts = n_big * POINTS
    print()
    print(
        f"1. Throughput, {n_big:,} clouds = {n_pts / 1e6:g} M points, {RESOLUTION:g} m voxels "
        f"(best and median of {reps_read} (rosbags) / {reps_b2w} (bag2world) runs, this process)"
    )
    print("   rosbags alone: AnyReader(bag), messages() of every connection (+ deserialize each)")
    print(
        "   bag2world: scans.bag2world with scans.insert=endpoints, octree.resolution 0.1 "
        "(= the CLI's --insert endpoints --resolution 0.1), output overwritten each run"
    )
    print(
        f"   {'format':<9} {'what':<42} {'best s':>7} {'median':>7} {'cpu s':>6} {'M pts/s':>8} "
        f"{'MiB/s':>6} {'x rosbags':>9} {'target':>7}"
    )
    out = folder / "out"
    stage_runs: dict[str, dict[str, float]] = {}
    for fmt in formats:
        bag = bags[fmt, n_big]
        size = size_of(bag)
        ours = fmt in ("mcap-ros1", "foxglove-protobuf")
        alone = mcap_alone if ours else rosbags_alone
        who = "McapFile" if ours else "rosbags"
        t_raw = timed(functools.partial(alone, bag, deserialise=False), reps_read)
        t_des = timed(functools.partial(alone, bag, deserialise=True), reps_read)
        t_b2w = timed(functools.partial(bag2world, bag, out), reps_b2w)
        with numba_threads(1):
            t_one = timed(functools.partial(bag2world, bag, out), reps_b2w)
        rows: list[tuple[str, Timing, float | None]] = [
            (f"{who}: read every message", t_raw, None),
            (f"{who}: read + deserialise every message", t_des, None),
        ]
        if ours:
            protobuf = fmt == "foxglove-protobuf"
            try:
                t_lib = timed(functools.partial(mcap_library_alone, bag, protobuf), reps_read)
            except ImportError:
                print("   (mcap's decoder package is not installed: no row for its decoders)")
            else:
                lib = "mcap_protobuf" if protobuf else "mcap_ros1"
                rows.append((f"mcap + {lib} decoders, plain loop", t_lib, None))
        rows += [
            ("bag2world --insert endpoints", t_b2w, TARGET_MPTS),
            ("bag2world, numba 1 thread", t_one, None),
        ]
        if fmt == "mcap":
            t_cli = run_cli(bag, out)
            rows.append(("CLI in a fresh process (1 run)", t_cli, None))
        for what, t, target in rows:
            rate = n_pts / t.best / 1e6
            line = (
                f"   {fmt:<9} {what:<42} {t.best:7.3f} {t.median:7.3f} {t.cpu:6.2f} {rate:8.2f} "
                f"{size / 2**20 / t.best:6.0f} {t.best / t_des.best:9.2f}"
            )
            if target is not None:
                line += f" {'>=' + format(target, 'g'):>7} {verdict(rate >= target)}"
                summary.append(
                    (
                        f"bag2world {fmt} {n_big} clouds",
                        f"{rate:.2f} M/s",
                        f">= {TARGET_MPTS:g} M/s",
                        rate >= target,
                    )
                )
            print(line, flush=True)
        if fmt == "mcap":  # the CLI's fixed start-up cost (imports, numba cache): a 3-cloud bag
            start = run_cli(warm / "warm_up", folder / "out_cli_small")
            label = "CLI on a 3-cloud bag (its start-up cost)"
            print(f"   {fmt:<9} {label:<42} {start.best:7.3f} {'':>7} {start.cpu:6.2f}")
        rate = n_pts / t_des.best / 1e6
        summary.append((f"  rosbags alone {fmt} (same run)", f"{rate:.2f} M/s", "reference", None))
        acc: dict[str, float] = {}
        gc.collect()
        with stage_clock(acc):
            t0 = time.perf_counter()
            bag2world(bag, out)
            acc["total"] = time.perf_counter() - t0
        stage_runs[fmt] = acc

    # --- 2. stages ------------------------------------------------------------------------------
    print()
    print("2. Where bag2world's time goes (one run per format, every stage timed by wrapping the")
    print("   functions bag2world calls; ms and share of the total)")
    print(f"   {'stage':<58}" + "".join(f" {f + ' ms':>9} {'share':>5}" for f in formats))
    for key, label in (*STAGES, ("other", "other (Python between stages)"), ("total", "total")):
        cells = ""
        for fmt in formats:
            acc = stage_runs[fmt]
            if key == "other":
                top = [k for k, _ in STAGES if "." not in k or k.startswith("scans.")]
                value = acc["total"] - sum(acc.get(k, 0.0) for k in top)
            else:
                value = acc.get(key, 0.0)
            cells += f" {value * 1e3:9.0f} {value / acc['total']:5.0%}"
        print(f"   {label:<58}{cells}")
    for fmt in formats:
        acc = stage_runs[fmt]
        print(
            f"   {fmt}: {n_pts / acc['total'] / 1e6:.2f} M pts/s with the wrappers; without "
            f"octree insertion {n_pts / (acc['total'] - acc.get('insert', 0.0)) / 1e6:.1f} M pts/s"
        )

    # --- 3. memory ------------------------------------------------------------------------------
    print()
    print(
        f"3. Peak memory vs recording length: bag2world on {short:,} and {long_:,} clouds of the "
        "same place (MCAP), each in a fresh process"
    )
    print(
        "   ru_maxrss after bag2world ('peak'); 'base' = ru_maxrss after imports and a warm-up run "
        "on a 3-cloud bag; VmHWM as a check"
    )
    print(
        f"   {'clouds':>7} {'points':>12} {'base MiB':>9} {'peak MiB':>9} {'peak-base':>9} "
        f"{'HWM MiB':>8} {'seconds':>8} {'M pts/s':>8}"
    )
    mem: dict[int, dict[str, Any]] = {}
    for clouds in (short, long_):
        m = measure_memory(bags["mcap", clouds], folder / f"out_mem_{clouds}", warm)
        mem[clouds] = m
        print(
            f"   {clouds:7,d} {clouds * POINTS:12,d} {mb(m['base_peak_kb'] * 1024)} "
            f"{mb(m['peak_kb'] * 1024)} {mb((m['peak_kb'] - m['base_peak_kb']) * 1024)} "
            f"{mb(m['hwm_kb'] * 1024)} {m['seconds']:8.2f} "
            f"{clouds * POINTS / m['seconds'] / 1e6:8.2f}",
            flush=True,
        )
    ratio = mem[long_]["peak_kb"] / mem[short]["peak_kb"]
    grow = (mem[long_]["peak_kb"] - mem[long_]["base_peak_kb"]) / max(
        mem[short]["peak_kb"] - mem[short]["base_peak_kb"], 1
    )
    print(
        f"   peak {long_:,} / {short:,} clouds: {ratio:.3f} (target <= 1.1) "
        f"{verdict(ratio <= 1.1)}; above base: {grow:.3f}"
    )
    summary.append(
        (f"peak memory {long_} / {short} clouds", f"{ratio:.3f}x", "<= 1.1x", ratio <= 1.1)
    )

    # --- 4. laser logs --------------------------------------------------------------------------
    print()
    print(
        "4. Laser logs: bag2world beside OctoMap's insertion (issue 31), one run each: "
        f"{LOG_RESOLUTION:g} m voxels, beams cut at {LOG_RANGE_MAX:g} m"
    )
    print(f"   ours: scan2terrain {' '.join(log_argv(Path('LOG'), Path('OUT')))}")
    print(
        "      'whole s' and 'peak' of that command in a fresh process (start-up, imports, numba "
        "cache, read, pose, insert by ray casting, write the world; ru_maxrss via a launcher);"
    )
    print(
        f"      'insert s': the same command in this process, time inside VoxelOctree."
        f"{insertion_methods()} (wrapped)"
    )
    print(
        "   OctoMap: octomap-python OcTree(0.05).insertPointCloud(points, origin, maxrange) per "
        "scan, the same scans (scan2terrain's reader:"
    )
    print(
        "      float64 world-frame points, clear-only beams beyond the cut-off, the same cut-off "
        "30 m + slack), loaded from an .npz in a fresh process; 'insert s' = the loop alone,"
    )
    print(
        "      'peak' its ru_maxrss, 'tree' = ru_maxrss minus that after loading the scans "
        "(Python, numpy, the data)"
    )
    synth, what = ensure_laser_log(folder, LOG_SCANS)
    print(
        f"   synthetic log: {what}; a 40 x 20 m floor (corridor, 10 rooms with doors, tables, "
        f"cabinets), {LOG_BEAMS} beams over 360 deg,"
    )
    print(
        f"      {LOG_RATE_HZ:g} Hz, range_max {LOG_RANGE_MAX:g} m (inf beyond), noise "
        f"{LOG_NOISE * 100:g} cm, {LOG_DROPOUT:.1%} NaN; robot at {LOG_SPEED:g} m/s through "
        f"every room; /tf map->odom->base_link ({LOG_TF_HZ:g} Hz), /tf_static ->laser"
    )
    # The numba kernels loaded once before timing anything in this process: a short log.
    warm_log, _ = ensure_laser_log(folder, 20)
    insertion_seconds(warm_log, folder / "out_log_warm")
    runs = [
        laser_log_case("MIT CSAIL (CARMEN)", CARMEN_LOG, folder),
        laser_log_case(f"synthetic {LOG_SCANS:,} scans", synth, folder),
    ]
    print(
        f"   {'log':<22} {'scans':>6} {'M beams':>8} {'side':<8} {'whole s':>8} {'insert s':>9} "
        f"{'M beams/s':>9} {'peak MiB':>9} {'tree MiB':>9}"
    )
    for r in runs:
        o, m = r.ours, r.octomap
        mbeams = r.beams / 1e6
        print(
            f"   {r.name:<22} {r.scans:6,d} {mbeams:8.3f} {'ours':<8} {o['seconds']:8.2f} "
            f"{r.insert_s:9.3f} {mbeams / r.insert_s:9.2f} {mb(o['peak_kb'] * 1024):>9}"
        )
        print(
            f"   {'':<22} {'':>6} {'':>8} {'OctoMap':<8} {'':>8} {m['seconds']:9.3f} "
            f"{mbeams / m['seconds']:9.2f} {mb(m['peak_kb'] * 1024):>9} "
            f"{mb((m['peak_kb'] - m['base_kb']) * 1024):>9}"
        )
    print(
        f"   {'log':<22} {'x OctoMap end to end':>21} {'insert x OctoMap':>17} "
        f"{'peak ours/OctoMap':>18} {'ours/OctoMap tree':>18} {'M beams/s':>10}"
    )
    for r in runs:
        o, m = r.ours, r.octomap
        x_e2e = m["seconds"] / o["seconds"]
        x_ins = m["seconds"] / r.insert_s
        peak = o["peak_kb"] / m["peak_kb"]
        tree = o["peak_kb"] / max(m["peak_kb"] - m["base_kb"], 1)
        rate = r.beams / r.insert_s / 1e6
        print(
            f"   {r.name:<22} {x_e2e:10.2f} {verdict(x_e2e >= TARGET_X_OCTOMAP):>10} "
            f"{x_ins:17.2f} {peak:13.2f} {verdict(peak <= TARGET_PEAK_RATIO):>4} {tree:18.2f} "
            f"{rate:5.2f} {verdict(rate >= TARGET_MBEAMS):>4}"
        )
        summary += [
            (
                f"{r.name}: x OctoMap end to end",
                f"{x_e2e:.2f}x",
                f">= {TARGET_X_OCTOMAP:g}x",
                x_e2e >= TARGET_X_OCTOMAP,
            ),
            (
                f"{r.name}: peak / OctoMap's",
                f"{peak:.2f}x",
                f"<= {TARGET_PEAK_RATIO:g}x",
                peak <= TARGET_PEAK_RATIO,
            ),
            (
                f"{r.name}: insertion",
                f"{rate:.2f} M/s",
                f">= {TARGET_MBEAMS:g} M/s",
                rate >= TARGET_MBEAMS,
            ),
        ]
    print(
        f"   targets (issue 31): OctoMap's insertion time / our whole process >= "
        f"{TARGET_X_OCTOMAP:g}; our peak <= OctoMap's (whole processes); >= "
        f"{TARGET_MBEAMS:g} M beams/s through insertion"
    )
    print()
    print("Summary (rates from the best run)")
    for name, shown, goal, ok in summary:
        mark = "" if ok is None else verdict(ok)
        print(f"   {name:<40} {shown:>12} {goal:>12}  {mark}")
    print(f"numba threading layer used: {threading_layer()}")
    print(f"load average at end: {load()}; total {time.perf_counter() - wall0:.0f} s")


def threading_layer() -> str:
    import numba

    try:
        return str(numba.threading_layer())  # type: ignore[attr-defined]
    except ValueError:  # no parallel kernel ran in this process
        return "none started (every kernel ran serially)"


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument(
        "--quick", action="store_true", help="100 vs 1,000 clouds for memory, fewer repetitions"
    )
    parser.add_argument(
        "--cache",
        type=Path,
        help="keep the generated bags in this folder and reuse them (default: a temporary "
        "folder, removed at the end)",
    )
    parser.add_argument(
        "--formats",
        default=None,
        help="comma-separated bag formats for the throughput part: mcap, ros1, mcap-ros1, "
        "foxglove-protobuf "
        "(the ROS1 bag rewritten as ROS1 MCAP) (default: mcap,ros1; --quick: mcap)",
    )
    parser.add_argument("--child", nargs=3, metavar=("BAG", "OUT", "WARM"), help=argparse.SUPPRESS)
    parser.add_argument("--octomap-child", type=Path, metavar="NPZ", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child_memory(*(Path(p) for p in args.child))
        return
    if args.octomap_child:
        child_octomap(args.octomap_child)
        return
    formats = (args.formats or ("mcap" if args.quick else "mcap,ros1")).split(",")
    if any(f not in FORMAT_NAMES for f in formats):
        parser.error(f"--formats: each of {', '.join(FORMAT_NAMES)}")
    if args.cache is not None:
        args.cache.mkdir(parents=True, exist_ok=True)
        run(quick=args.quick, folder=args.cache, formats=formats)
        return
    with tempfile.TemporaryDirectory(prefix="bench_bag2world_") as tmp:
        run(quick=args.quick, folder=Path(tmp), formats=formats)


if __name__ == "__main__":
    main()
