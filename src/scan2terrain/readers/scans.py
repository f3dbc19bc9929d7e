"""What a robot saw, posed: scans from a bag, each with its points and sensor origin in one fixed
frame, ready for the octree.

Two steps, both here because both need the bag's topics and tf tree:

* :func:`plan_bag` decides what to read: the scan topics (``sensor_msgs/LaserScan`` and
  ``sensor_msgs/PointCloud2``), or a ``nav_msgs/OccupancyGrid`` topic when the bag has no scans,
  and where each scan's pose comes from. A choice is made automatically only when there is one
  sensible choice; otherwise the error lists the choices and the option that picks one. Every
  decision is recorded with its reason (``scan2terrain inspect`` prints them).
* :func:`posed_scans` streams the scans. tf and odometry are read first in their own pass (they
  are small), so a scan can be interpolated between the transforms around its stamp and memory
  does not grow with the recording: scans are decoded in batches of :data:`BATCH` messages and
  their poses looked up together (one vectorised lookup per batch).

Poses, in the order a user expects (``scans.poses: auto`` tries the first two):

1. tf: the sensor frame (the scan's ``header.frame_id``) in the fixed frame (``map`` if the tree
   has it, else ``odom``, or the one given), interpolated at the scan's stamp;
2. odometry: a ``nav_msgs/Odometry`` topic gives the robot base in ``odom``; the sensor mount comes
   from ``/tf_static`` (base -> sensor) when it is there, else from ``scans.mount`` (identity if
   not given, reported);
3. trajectory: a TUM file of the base pose (the usual output of SLAM systems), plus the mount;
4. fixed: one pose for a stationary sensor.

A scan whose pose cannot be found (before the first transform, after the last, inside a gap longer
than ``scans.max_gap``) is counted and reported with the reason of the first one, never inserted
at identity.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from scan2terrain.config import ScansConfig
from scan2terrain.errors import InputError
from scan2terrain.readers.foxglove import LASER_SCAN as FOXGLOVE_LASER_SCAN
from scan2terrain.readers.foxglove import Grid as FoxgloveGrid
from scan2terrain.readers.foxglove import LaserScan as FoxgloveLaserScan
from scan2terrain.readers.foxglove import PointCloud as FoxglovePointCloud
from scan2terrain.readers.laserscan import (
    BlockPoints,
    ScanBlock,
    block_points,
    laserscan_points,
    raw_laserscans,
    wire_layout_known,
)
from scan2terrain.readers.mapserver import extent_problem
from scan2terrain.readers.messages import (
    LASER_SCAN,
    MAP_TYPES,
    ODOMETRY_TYPES,
    TF_TYPES,
    resolve_time,
)
from scan2terrain.readers.messages import SCAN_TYPES as _SCAN_TYPES
from scan2terrain.readers.pointcloud2 import pointcloud2_xyz
from scan2terrain.readers.poses import matrices_to_quaternions, pose6
from scan2terrain.readers.tf import TfBuffer
from scan2terrain.readers.tracks import PoseTrack, odometry_track, read_tum
from scan2terrain.types import (
    HeightGrid,
    Pose2D,
    PoseCorrection,
    Scan,
    ScanCounts,
    Transform,
    normalise_frame,
)

if TYPE_CHECKING:
    from rosbags.interfaces import Connection

    from scan2terrain.readers.bag import Bag

#: Scans decoded and posed together (one vectorised pose lookup per batch).
BATCH = 64
SCAN_TYPES = tuple(sorted(_SCAN_TYPES))


@dataclass
class BagPlan:
    """What :func:`posed_scans` will read and why."""

    scan_topics: list[str] = field(default_factory=list)
    map_topic: str | None = None
    poses: str = ""  #: tf | odom | trajectory | fixed ('' for a map)
    fixed_frame: str = ""
    sensor_frames: dict[str, str] = field(default_factory=dict)  #: topic -> frame
    odom_topic: str | None = None
    start_ns: int | None = None
    end_ns: int | None = None
    reasons: list[str] = field(default_factory=list)
    tf: TfBuffer | None = None  #: the bag's tf tree, read once
    #: The robot base frame whose trajectory is written when there is nothing to map (tf poses).
    base_frame: str = ""
    #: Poses corrected by scan matching and loop closure (``scans.correct``), applied to every
    #: pose the plan gives; None: as recorded.
    correction: PoseCorrection | None = None

    @property
    def pose_source(self) -> str:
        """Where the scans' poses come from, as the plan's reason says ("odometry on /odom
        plus the sensor mount"), for the replay's report."""
        return next((r for r in self.reasons if r.startswith("poses: ")), "poses: given")[7:]

    @property
    def trajectory_only(self) -> bool:
        """No scans and no map: the bag gives the robot's trajectory and nothing to map."""
        return not self.scan_topics and self.map_topic is None


def scan_topics(bag: Bag) -> list[str]:
    return sorted(n for n, t in bag.topics.items() if t.msgtype in SCAN_TYPES and t.count)


def plan_bag(bag: Bag, cfg: ScansConfig, *, max_range: float = -1.0) -> BagPlan:
    """Decide topics, fixed frame and pose source for ``bag`` (see the module docstring).
    ``max_range`` (metres, ``octree.max_range``; < 0: none) only decides what the plan says
    of a ``foxglove.LaserScan`` topic's no-return readings.

    Raises
    ------
    InputError
        No usable topic (the message lists what the bag has), several candidates and none
        chosen (the message lists them), a chosen topic that is missing or of another type, or
        no pose source.
    """
    plan = BagPlan(start_ns=resolve_time(cfg.start, bag), end_ns=resolve_time(cfg.end, bag))
    path = bag.path
    if cfg.topics:
        # The bag's names: 'scan' and '/scan' are one topic (Bag.require), read once.
        chosen = list(
            dict.fromkeys(bag.require(t, (*SCAN_TYPES, *MAP_TYPES)).name for t in cfg.topics)
        )
        maps = [t for t in chosen if bag.topics[t].msgtype in MAP_TYPES]
        if maps and len(chosen) > 1:
            raise InputError(path, "give either scan topics or one OccupancyGrid topic, not both")
        if maps:
            plan.map_topic = maps[0]
        else:
            plan.scan_topics = chosen
        plan.reasons.append(f"topics {', '.join(chosen)}: chosen (--topic)")
    else:
        scans = scan_topics(bag)
        maps = sorted(n for n, t in bag.topics.items() if t.msgtype in MAP_TYPES and t.count)
        if len(scans) == 1:
            plan.scan_topics = scans
            plan.reasons.append(f"topic {scans[0]}: the bag's only LaserScan/PointCloud2 topic")
        elif len(scans) > 1:
            listing = "; ".join(f"{n} ({_short(bag.topics[n].msgtype)})" for n in scans)
            raise InputError(
                path, f"several scan topics, choose with --topic (repeatable): {listing}"
            )
        elif len(maps) == 1:
            plan.map_topic = maps[0]
            plan.reasons.append(f"topic {maps[0]}: no scan topic; the bag's only OccupancyGrid")
        elif len(maps) > 1:
            raise InputError(
                path,
                f"no scan topic and several OccupancyGrid topics, choose with --topic: "
                f"{', '.join(maps)}",
            )
        else:
            _plan_trajectory(bag, cfg, plan)
            return plan
    if plan.map_topic is not None:
        bag.require_messages([plan.map_topic], plan.start_ns, plan.end_ns)
        return plan
    bag.require_messages(plan.scan_topics, plan.start_ns, plan.end_ns)
    for t in plan.scan_topics:
        frames = bag.frame_ids(t)
        if len(frames) > 1:
            raise InputError(path, f"{t} changes frame ({', '.join(sorted(frames))})")
        plan.sensor_frames[t] = normalise_frame(next(iter(frames), ""))
        if bag.topics[t].msgtype == FOXGLOVE_LASER_SCAN and max_range <= 0:
            plan.reasons.append(
                f"{t}: foxglove.LaserScan has no range_max: its no-return (+inf) readings clear "
                "nothing; give --max-range (the scanner's range) to clear along them as a ROS "
                "LaserScan does up to its range_max"
            )
    _plan_poses(bag, cfg, plan)
    plan.reasons += bag.container.notes  # what the container says of its poses (CARMEN logs)
    return plan


#: Robot base frames a trajectory is written of, from tf, in this order (REP 105's names).
BASE_FRAMES = ("base_link", "base_footprint")


def _plan_trajectory(bag: Bag, cfg: ScansConfig, plan: BagPlan) -> None:
    """A bag without scans or a map: plan the robot's trajectory (tf: a base frame in the fixed
    frame, else odometry), or refuse: nothing to map and nothing to follow the robot by."""
    nothing = "nothing to map (no LaserScan, PointCloud2 or OccupancyGrid topic)"
    choice = cfg.poses
    if choice == "auto" and (cfg.pose is not None or cfg.trajectory is not None):
        choice = "fixed" if cfg.pose is not None else "trajectory"
    if choice in ("fixed", "trajectory"):
        given = "--pose" if choice == "fixed" else "--trajectory FILE"
        raise InputError(
            bag.path,
            f"{nothing}, and with {given} (--poses {choice}) there is no trajectory of the bag "
            f"to write; the bag has: {bag.describe_topics()}",
        )
    has_tf = bool(bag.topics_of_type(TF_TYPES))
    odoms = bag.topics_of_type(ODOMETRY_TYPES)
    if choice in ("auto", "tf") and has_tf:
        plan.tf = plan.tf or read_tf(bag, cfg)
        fixed = normalise_frame(cfg.fixed_frame) if cfg.fixed_frame else plan.tf.fixed_frame()
        if fixed is not None and fixed in plan.tf.frames():
            root = _root(plan.tf, fixed)
            plan.base_frame = next(
                (b for b in BASE_FRAMES if b in plan.tf.frames() and _root(plan.tf, b) == root),
                "",
            )
        if plan.base_frame:
            assert fixed is not None
            plan.poses, plan.fixed_frame = "tf", fixed
    if not plan.base_frame and (choice == "odom" or (choice == "auto" and odoms)):
        plan.odom_topic = bag.pick_topic(ODOMETRY_TYPES, cfg.odom_topic).name
        plan.poses, plan.fixed_frame = "odom", "odom"
    if not plan.poses:
        frames = sorted(plan.tf.frames()) if plan.tf is not None else []
        tf_has = f"; tf frames: {', '.join(frames)}" if frames else ""
        raise InputError(
            bag.path,
            f"nothing to map and no trajectory: no LaserScan, PointCloud2 or OccupancyGrid "
            f"topic, and no odometry, nor tf linking a fixed frame (map, odom) to a robot base "
            f"({', '.join(BASE_FRAMES)}){tf_has}; the bag has: {bag.describe_topics()}",
        )
    how = (
        f"{plan.base_frame} in '{plan.fixed_frame}' (tf)"
        if plan.poses == "tf"
        else f"the robot base in the odometry frame ({plan.odom_topic})"
    )
    plan.reasons.append(
        f"{nothing}: bag2world writes the robot's trajectory, {how}, as OUT/trajectory.tum "
        "(TUM), and no world"
    )


def robot_trajectory(bag: Bag, cfg: ScansConfig, plan: BagPlan) -> tuple[PoseTrack, str]:
    """The trajectory a :attr:`BagPlan.trajectory_only` plan names, within its time range, and
    what it is (``base_link in odom (odometry /odom)``): odometry as recorded (each message's
    stamp, bag time when zero), or tf's base frame in the fixed frame at every sample time of
    the dynamic edges between them where all of them are known (no extrapolation).

    Raises
    ------
    InputError
        No sample in the range, or tf that never gives the pose at one time.
    """
    lo = -(1 << 63) if plan.start_ns is None else plan.start_ns
    hi = (1 << 63) - 1 if plan.end_ns is None else plan.end_ns
    if plan.poses == "odom":
        assert plan.odom_topic is not None
        stamps, msgs = [], []
        for _, t_ns, msg in bag.messages([plan.odom_topic], plan.start_ns, plan.end_ns):
            stamps.append(t_ns)
            msgs.append(msg)
        if not msgs:
            raise InputError(bag.path, f"{plan.odom_topic}: no odometry message in range")
        track = odometry_track(
            np.asarray(stamps, dtype=np.int64), msgs, source=f"{bag.path}:{plan.odom_topic}"
        )
        what = f"{track.child_frame_id} in {track.frame_id} (odometry {plan.odom_topic})"
        return track, what
    tf = plan.tf or read_tf(bag, cfg)
    fixed, base = plan.fixed_frame, plan.base_frame
    times = tf.sample_times(fixed, base)
    times = times[(times >= lo) & (times <= hi)]
    valid, r, t = tf.lookup_many(fixed, base, times)
    if not valid.any():
        why = (
            tf.why_not(fixed, base, int(times[0]))
            if len(times)
            else "no tf sample moves it in range (static transforms only?)"
        )
        raise InputError(bag.path, f"no pose of '{base}' in '{fixed}' from tf: {why}")
    track = PoseTrack(
        times[valid],
        t[valid],
        matrices_to_quaternions(r[valid]),
        frame_id=fixed,
        child_frame_id=base,
    )
    return track, f"{base} in {fixed} (tf)"


def _short(msgtype: str | None) -> str:
    return (msgtype or "?").split("/")[-1]


def _plan_poses(bag: Bag, cfg: ScansConfig, plan: BagPlan) -> None:
    has_tf = bool(bag.topics_of_type(TF_TYPES))
    odoms = bag.topics_of_type(ODOMETRY_TYPES)
    choice = cfg.poses
    if choice == "auto":
        if cfg.pose is not None:
            choice = "fixed"
        elif cfg.trajectory is not None:
            choice = "trajectory"
        elif has_tf and _tf_reaches(bag, cfg, plan):
            choice = "tf"
        elif odoms or cfg.odom_topic:
            choice = "odom"
        else:
            why = "no /tf" if not has_tf else "the tf tree does not reach the sensor frame"
            raise InputError(
                bag.path,
                f"no pose for the scans ({why}, no odometry topic): give --trajectory FILE (TUM) "
                "or, for a stationary sensor, --pose X Y Z ROLL PITCH YAW",
            )
    plan.poses = choice
    if choice == "tf":
        if not has_tf:
            raise InputError(bag.path, "--poses tf, but the bag has no tf topic")
        if not plan.fixed_frame and not _tf_reaches(bag, cfg, plan):
            tf = plan.tf or read_tf(bag, cfg)
            fixed = normalise_frame(cfg.fixed_frame or "") or tf.fixed_frame() or "(none)"
            frame = next(iter(plan.sensor_frames.values()), "")
            raise InputError(
                bag.path,
                f"--poses tf: the tf tree does not link '{fixed}' to the sensor frame "
                f"'{frame}' ({tf.why_not(fixed, frame, bag.start_ns)}); tf has frames "
                f"{', '.join(sorted(tf.frames())) or 'none'}; choose one with --fixed-frame",
            )
        plan.reasons.append(
            f"poses: tf, sensor frame(s) {', '.join(sorted(set(plan.sensor_frames.values())))} "
            f"in fixed frame '{plan.fixed_frame}'"
        )
    elif choice == "odom":
        plan.odom_topic = bag.pick_topic(ODOMETRY_TYPES, cfg.odom_topic).name
        plan.fixed_frame = "odom"
        plan.reasons.append(f"poses: odometry on {plan.odom_topic} plus the sensor mount")
    elif choice == "trajectory":
        if cfg.trajectory is None:
            raise InputError(bag.path, "--poses trajectory needs --trajectory FILE")
        plan.fixed_frame = "trajectory"
        plan.reasons.append(f"poses: TUM trajectory {cfg.trajectory} plus the sensor mount")
    else:
        if cfg.pose is None:
            raise InputError(bag.path, "--poses fixed needs --pose X Y Z ROLL PITCH YAW")
        plan.fixed_frame = "fixed"
        plan.reasons.append(f"poses: one fixed sensor pose {cfg.pose}")


#: Fixed frames that SLAM, localisation or a survey publish: poses in them are not odometry.
MAP_FRAMES = frozenset({"map", "world", "earth", "utm"})


def odometry_only(plan: BagPlan) -> tuple[bool, str]:
    """Whether the plan's poses are raw odometry (what ``scans.correct: auto`` corrects), and
    why: odometry poses; or tf whose fixed frame is not a map frame (:data:`MAP_FRAMES`) and
    has one moving transform on the way to the sensor (odom -> base_link; a SLAM system adds
    map -> odom). A given trajectory or a fixed pose is not odometry."""
    if plan.poses == "odom":
        return True, "the poses are odometry"
    if plan.poses != "tf" or plan.tf is None:
        return False, f"the poses are a given {plan.poses}"
    fixed = plan.fixed_frame
    if fixed in MAP_FRAMES:
        return False, f"tf has the map frame '{fixed}' (poses a SLAM system made)"
    edges = {e.child: e for e in plan.tf.edges()}
    moving = set()
    for sensor in plan.sensor_frames.values():
        frame = sensor
        while frame in edges and frame != fixed:
            if not edges[frame].static:
                moving.add(frame)
            frame = edges[frame].parent
    if not moving:
        return False, f"the sensor does not move in the fixed frame '{fixed}' (static tf)"
    if len(moving) > 1:
        return False, f"tf has {len(moving)} moving frames above the sensor in '{fixed}'"
    return True, f"tf has no frame above the odometry frame '{fixed}'"


def _tf_reaches(bag: Bag, cfg: ScansConfig, plan: BagPlan) -> bool:
    """Whether the bag's tf tree links a fixed frame to every sensor frame; sets the frame."""
    if plan.tf is None:
        plan.tf = read_tf(bag, cfg)
    tf = plan.tf
    fixed = normalise_frame(cfg.fixed_frame) if cfg.fixed_frame else tf.fixed_frame()
    if fixed is None:
        return False
    frames = tf.frames()
    ok = fixed in frames and all(
        f in frames and _root(tf, f) == _root(tf, fixed) for f in plan.sensor_frames.values()
    )
    if ok:
        plan.fixed_frame = fixed
    return ok


def _root(tf: TfBuffer, frame: str) -> str:
    while (parent := tf.parent(frame)) is not None:
        frame = parent
    return frame


def read_tf(bag: Bag, cfg: ScansConfig) -> TfBuffer:
    """Every tf transform of the bag (/tf and /tf_static), in one pass."""
    tf = TfBuffer(max_gap_ns=round(cfg.max_gap * 1e9))
    topics = bag.topics_of_type(TF_TYPES)
    if topics:
        for topic, t_ns, msg in bag.messages(topics):
            tf.add_message(msg, static="static" in topic, bag_time_ns=t_ns)
    return tf


def _stamp(msg: Any, bag_ns: int) -> int:
    st = msg.header.stamp
    ns = int(st.sec) * 1_000_000_000 + int(st.nanosec)
    return ns if ns > 0 else bag_ns


class _Poser:
    """Poses of sensor frames at given times, from the plan's source."""

    def __init__(self, bag: Bag, cfg: ScansConfig, plan: BagPlan) -> None:
        self.plan = plan
        self.source, self.start_ns = bag.path, bag.start_ns  # for errors about a message
        self.tf: TfBuffer | None = None
        self.track: PoseTrack | None = None
        self.fixed: Transform | None = None
        self.mounts: dict[str, Transform] = {}
        gap = round(cfg.max_gap * 1e9)
        if plan.poses == "tf":
            self.tf = plan.tf or read_tf(bag, cfg)
            return
        if plan.poses == "fixed":
            assert cfg.pose is not None
            self.fixed = pose6(cfg.pose)
            return
        if plan.poses == "odom":
            assert plan.odom_topic is not None
            stamps, msgs = [], []
            for _, t_ns, msg in bag.messages([plan.odom_topic]):
                stamps.append(t_ns)
                msgs.append(msg)
            self.track = odometry_track(
                np.asarray(stamps, dtype=np.int64), msgs, max_gap_ns=gap, source=str(bag.path)
            )
        else:
            assert cfg.trajectory is not None
            self.track = read_tum(Path(cfg.trajectory), max_gap_ns=gap)
        base = self.track.child_frame_id or "base_link"
        tf = plan.tf or (read_tf(bag, cfg) if bag.topics_of_type(TF_TYPES) else None)
        for topic, frame in plan.sensor_frames.items():
            if cfg.mount is not None:
                self.mounts[topic] = pose6(cfg.mount)
                continue
            found = None
            if tf is not None and frame in tf.frames() and base in tf.frames():
                found = tf.lookup(base, frame, bag.start_ns)
            if found is None:
                found = Transform.identity()
                plan.reasons.append(
                    f"mount of {frame or topic} on {base}: not in /tf_static and no --mount: "
                    "identity"
                )
            else:
                plan.reasons.append(f"mount of {frame} on {base}: from tf")
            self.mounts[topic] = found

    def poses(
        self, topic: str, stamps: NDArray[np.int64]
    ) -> tuple[NDArray[np.bool_], NDArray[np.float64], NDArray[np.float64]]:
        """(valid, rotations (K, 3, 3), translations (K, 3)) of the sensor of ``topic``."""
        valid, r, t = self._recorded(topic, stamps)
        if self.plan.correction is not None:
            r, t = self.plan.correction.apply(stamps, r, t)
        return valid, r, t

    def _recorded(
        self, topic: str, stamps: NDArray[np.int64]
    ) -> tuple[NDArray[np.bool_], NDArray[np.float64], NDArray[np.float64]]:
        k = len(stamps)
        if self.fixed is not None:
            r = np.broadcast_to(self.fixed.rotation, (k, 3, 3))
            return np.ones(k, bool), r, np.broadcast_to(self.fixed.translation, (k, 3))
        if self.tf is not None:
            return self.tf.lookup_many(
                self.plan.fixed_frame, self.plan.sensor_frames[topic], stamps
            )
        assert self.track is not None
        valid, r, t = self.track.at_many(stamps)
        m = self.mounts[topic]
        return valid, r @ m.rotation, np.einsum("kij,j->ki", r, m.translation) + t

    def why_not(self, topic: str, stamp: int) -> str:
        if self.tf is not None:
            return self.tf.why_not(self.plan.fixed_frame, self.plan.sensor_frames[topic], stamp)
        if self.track is not None:
            return self.track.why_not(stamp)
        return ""


def posed_scans(
    bag: Bag, cfg: ScansConfig, plan: BagPlan, counts: ScanCounts, *, max_range: float = -1.0
) -> Iterator[Scan]:
    """Stream the plan's scans in the fixed frame (see the module docstring); ``counts`` is
    updated as they go. ``max_range`` (metres, < 0: none) also cuts PointCloud2 beams.

    LaserScans are read, computed and posed a batch at a time (:class:`_Batch`): their raw
    bytes as numpy views where rosbags reads them from bytes (ROS1 and CDR), the points of all
    scans of one beam count in one numpy pass and posed by one stacked matmul; each Scan's
    points, origin and rotation are views into the batch's arrays. The same scans, bit for bit,
    as one rosbags object, one :func:`~scan2terrain.readers.laserscan.laserscan_points` and one
    matmul per message, and the same refusals in the same order."""
    poser = _Poser(bag, cfg, plan)
    batch: list[tuple[Connection, int, Any]] = []
    raw = bag.raw_messages(plan.scan_topics, plan.start_ns, plan.end_ns)
    while True:
        try:
            for item in raw:
                batch.append(item)
                if len(batch) == BATCH:
                    break
            else:
                break
        except InputError:  # unreadable data: a message read before it may be refused first
            _Batch(bag, batch, max_range)
            raise
        yield from _Batch(bag, batch, max_range).posed(poser, counts)
        batch = []
    if batch:
        yield from _Batch(bag, batch, max_range).posed(poser, counts)


class _Batch:
    """:data:`BATCH` scan messages in bag order, decoded (see :func:`posed_scans`): LaserScans
    the fast path reads from bytes as rows of :class:`~scan2terrain.readers.laserscan.RawScans`,
    the rest decoded by the bag one by one (in bag order, so the first undecodable message is
    the one refused, as when every message was decoded); decoded LaserScans (a CARMEN log's, a
    layout of one message) are stacked by beam count and computed together too."""

    def __init__(
        self, bag: Bag, items: list[tuple[Connection, int, Any]], max_range: float
    ) -> None:
        self.bag, self.items = bag, items
        self.given_range = max_range  # what PointCloud2 and Foxglove scans are cut at
        self.max_range = max_range if max_range > 0 else None
        n = len(items)
        self.msgs: list[Any] = [None] * n
        self.stamps = np.zeros(n, dtype=np.int64)
        self.block_of = np.full(n, -1, dtype=np.intp)  # which block holds each LaserScan
        self.row_of = np.zeros(n, dtype=np.intp)
        self.blocks: list[tuple[NDArray[np.intp], ScanBlock]] = []
        done = np.zeros(n, dtype=bool)
        for wire, idx in self._wires().items():

            def template(k: int, idx: NDArray[np.intp] = idx) -> Any | None:
                return self._template(int(idx[k]))

            for group in raw_laserscans([items[i][2] for i in idx], wire[0], template):
                where = idx[group.index]
                done[where] = True
                self.stamps[where] = group.stamps_ns
                self._add_block(where, group.block)
        by_beams: dict[int, list[int]] = {}
        for i, (conn, t_ns, raw) in enumerate(items):
            if done[i]:
                continue
            msg: Any = self.msgs[i] if self.msgs[i] is not None else bag.decode(conn, t_ns, raw)
            self.msgs[i] = msg
            self.stamps[i] = _stamp_ns(msg)
            if _is_laserscan(msg):
                by_beams.setdefault(np.asarray(msg.ranges).size, []).append(i)
        for rows in by_beams.values():
            where = np.array(rows, dtype=np.intp)
            self._add_block(where, ScanBlock.of([self.msgs[i] for i in rows]))
        bag_ns = np.array([t for _, t, _ in items], dtype=np.int64)
        self.stamps = np.where(self.stamps > 0, self.stamps, bag_ns)

    def _wires(self) -> dict[tuple[str, int], NDArray[np.intp]]:
        """The LaserScan messages rosbags reads from bytes of a known layout, by encoding and
        typestore."""
        out: dict[tuple[str, int], list[int]] = {}
        known: dict[int, bool] = {}
        for i, (conn, _, _) in enumerate(self.items):
            if conn.msgtype != LASER_SCAN:
                continue
            if (wire := self.bag.wire(conn)) is None:
                continue
            kind, store = wire
            key = id(conn)
            if key not in known:
                known[key] = wire_layout_known(kind, store, conn.msgtype)
            if known[key]:
                out.setdefault((kind, id(store)), []).append(i)
        return {k: np.array(v, dtype=np.intp) for k, v in out.items()}

    def _template(self, i: int) -> Any | None:
        conn, t_ns, raw = self.items[i]
        try:
            self.msgs[i] = self.bag.decode(conn, t_ns, raw)
        except InputError:
            return None
        return self.msgs[i]

    def _add_block(self, where: NDArray[np.intp], block: ScanBlock) -> None:
        self.block_of[where] = len(self.blocks)
        self.row_of[where] = np.arange(len(where))
        self.blocks.append((where, block))

    def posed(self, poser: _Poser, counts: ScanCounts) -> Iterator[Scan]:
        """The batch's scans posed, sorted by stamp (stable), as :func:`posed_scans` yields."""
        n = len(self.items)
        by_topic: dict[str, list[int]] = {}
        for i, (conn, _, _) in enumerate(self.items):
            by_topic.setdefault(conn.topic, []).append(i)
        valid = np.zeros(n, dtype=bool)
        rot = np.empty((n, 3, 3))
        trans = np.empty((n, 3))
        for topic, rows in by_topic.items():
            where = np.array(rows, dtype=np.intp)
            v, r, t = poser.poses(topic, self.stamps[where])
            valid[where], rot[where], trans[where] = v, r, t
        laid = self._lay(valid, rot, trans)
        out: list[Scan] = []
        for topic, rows in by_topic.items():
            for i in rows:
                counts.messages += 1
                stamp = int(self.stamps[i])
                if not valid[i]:
                    counts.unposed += 1
                    if not counts.first_unposed:
                        counts.first_unposed = f"{topic} at stamp {stamp / 1e9:.3f} s: " + (
                            poser.why_not(topic, stamp)
                        )
                    continue
                scan = self._scan(i, topic, laid, rot[i], trans[i], poser)
                if scan is None:
                    counts.empty += 1
                    continue
                out.append(scan)
        out.sort(key=lambda s: s.stamp_ns)
        yield from out

    def _lay(
        self, valid: NDArray[np.bool_], rot: NDArray[np.float64], trans: NDArray[np.float64]
    ) -> list[tuple[BlockPoints, NDArray[np.float64], NDArray[np.int64]]]:
        """Per block: its points, every kept reading of its posed scans in the fixed frame (in
        scan and reading order), and each scan's first row in them."""
        laid = []
        for where, block in self.blocks:
            bp = block_points(block, self.max_range)
            keep = bp.keep & valid[where][:, None]
            # One BLAS gemm per scan, as the matmul of one scan's points did: the same bits.
            world = np.matmul(bp.points, np.ascontiguousarray(rot[where].transpose(0, 2, 1)))
            world += trans[where][:, None, :]
            starts = np.zeros(len(where) + 1, dtype=np.int64)
            np.cumsum(keep.sum(axis=1), out=starts[1:])
            laid.append((bp, world[keep], starts))
        return laid

    def _scan(
        self,
        i: int,
        topic: str,
        laid: list[tuple[BlockPoints, NDArray[np.float64], NDArray[np.int64]]],
        r_j: NDArray[np.float64],
        t_j: NDArray[np.float64],
        poser: _Poser,
    ) -> Scan | None:
        """Message ``i`` posed at ``r_j``, ``t_j`` (None: no points), or its refusal."""
        stamp = int(self.stamps[i])
        b = int(self.block_of[i])
        try:
            if b >= 0:
                bp, world, starts = laid[b]
                row = int(self.row_of[i])
                if bp.refused[row]:  # laserscan_points says why
                    laserscan_points(self._msg(i), self.max_range)
                    raise AssertionError("a LaserScan refused in bulk was accepted alone")
                pts = world[starts[row] : starts[row + 1]]
                mr = float(bp.cutoff[row])
                if len(pts) == 1:  # numpy takes one point through gemv: as it did
                    local = bp.points[row][bp.keep[row]]
                    pts = local @ np.ascontiguousarray(r_j.T)
                    pts += t_j
            else:
                msg = self.msgs[i]
                if isinstance(msg, (FoxglovePointCloud, FoxgloveLaserScan)):
                    local_pts, mr = msg.points(self.given_range)
                    if (local := msg.local_pose) is not None:  # the scan's origin in its frame
                        r_j, t_j = r_j @ local.rotation, r_j @ local.translation + t_j
                else:
                    local_pts, mr = pointcloud2_xyz(msg), self.given_range
                if len(local_pts) == 0:
                    return None
                pts = local_pts @ np.ascontiguousarray(r_j.T)  # a transposed view is slow
                pts += t_j
        except InputError as exc:  # about the message alone: name the bag and the message
            if exc.path is not None:
                raise
            at = (self.items[i][1] - poser.start_ns) / 1e9
            raise InputError(
                poser.source, f"message on {topic} at {at:.3f} s: {exc.problem}"
            ) from exc
        if len(pts) == 0:
            return None
        heading = math.atan2(float(r_j[1, 0]), float(r_j[0, 0]))
        return Scan(pts, t_j, mr, stamp, topic, heading, r_j)

    def _msg(self, i: int) -> Any:
        if self.msgs[i] is None:
            conn, t_ns, raw = self.items[i]
            self.msgs[i] = self.bag.decode(conn, t_ns, raw)
        return self.msgs[i]


def _is_laserscan(msg: Any) -> bool:
    """A LaserScan :func:`laserscan_points` reads (rosbags', a CARMEN log's), not Foxglove's."""
    return not isinstance(msg, (FoxglovePointCloud, FoxgloveLaserScan)) and hasattr(msg, "ranges")


def _stamp_ns(msg: Any) -> int:
    """A message's header stamp in ns (0 or less: none, :func:`_stamp` takes bag time)."""
    st = msg.header.stamp
    return int(st.sec) * 1_000_000_000 + int(st.nanosec)


def map_message(bag: Bag, plan: BagPlan, index: int) -> tuple[Any, int]:
    """The chosen OccupancyGrid message of the plan's map topic (``index`` -1: the last)."""
    assert plan.map_topic is not None
    chosen: tuple[Any, int] | None = None
    n = 0
    for _, t_ns, msg in bag.messages([plan.map_topic], plan.start_ns, plan.end_ns):
        if index < 0 or n == index:
            chosen = (msg, t_ns)
        n += 1
        if 0 <= index < n:
            break
    if chosen is None:
        raise InputError(
            bag.path, f"{plan.map_topic} has {n} message(s) in range, no message {index}"
        )
    return chosen


def occupancy_from_message(msg: Any) -> tuple[NDArray[np.int8], float, tuple[float, float, float]]:
    """nav_msgs/OccupancyGrid to (data int8 (H, W), resolution, origin (x, y, yaw))."""
    info = msg.info
    h, w = int(info.height), int(info.width)
    data = np.asarray(msg.data, dtype=np.int8)
    if h * w == 0 or data.size != h * w:
        raise ValueError(f"OccupancyGrid of {w} x {h} cells holds {data.size} values")
    q = info.origin.orientation
    yaw = math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))
    p = info.origin.position
    origin = (float(p.x), float(p.y), yaw)
    problem = extent_problem((h, w), float(info.resolution), Pose2D(*origin))
    if problem:
        raise ValueError(problem)
    return data.reshape(h, w), float(info.resolution), origin


def is_height_grid(msg: Any) -> bool:
    """Whether a map message holds heights (a ``foxglove.Grid`` with an elevation field)."""
    return isinstance(msg, FoxgloveGrid) and msg.is_elevation


def height_grid_from_message(msg: FoxgloveGrid) -> HeightGrid:
    """A ``foxglove.Grid`` elevation field to a height grid: z = the pose's z + the value,
    cells without a finite value unknown; the pose must be level (a yaw only).

    Raises
    ------
    ValueError
        A tilted pose, no finite height, a bad layout, or an extent out of range.
    """
    q = msg.info.origin.orientation
    norm = math.sqrt(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w)
    if norm == 0 or not math.isfinite(norm):
        raise ValueError(f"Grid pose orientation ({q.x}, {q.y}, {q.z}, {q.w}) is not a rotation")
    if math.hypot(q.x, q.y) / norm > 1e-6:
        raise ValueError(
            "Grid pose is tilted (roll or pitch); a height grid must lie level (a yaw only)"
        )
    values = msg.heights
    known = np.isfinite(values)
    if not known.any():
        raise ValueError("Grid elevation field holds no finite height")
    p = msg.info.origin.position
    if not all(math.isfinite(v) for v in (p.x, p.y, p.z)):
        raise ValueError(f"Grid pose position ({p.x}, {p.y}, {p.z}) is not finite")
    yaw = math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))
    origin = Pose2D(float(p.x), float(p.y), yaw)
    resolution = float(msg.info.resolution)
    problem = extent_problem(values.shape, resolution, origin)
    if problem:
        raise ValueError(problem)
    heights = np.where(known, values + float(p.z), 0.0).astype(np.float32)
    return HeightGrid(heights, known, resolution, origin)
