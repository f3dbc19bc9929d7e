"""CARMEN logs (``.clf``, ``.log``, plain, gzip or bzip2) read as recordings, like a bag.

The classic 2D SLAM benchmark logs (Radish, Freiburg: Intel, ACES, FR079, MIT CSAIL...) are
CARMEN logs. :func:`~scan2terrain.readers.bag.open_bag` opens one as another container, as it
opens Foxglove MCAP: :class:`CarmenFile` offers what :class:`~scan2terrain.readers.bag.Bag`
reads through (topics, connections, time span, messages in time order, decoding), and its
messages are objects shaped like the ROS messages they stand for, so planning, posing,
``inspect``, ``convert``, ``bag2world`` and ``--stream`` read a log as they read a bag. The
records are parsed and checked by :mod:`scan2terrain.readers._carmen_records`. The log presents:

* ``/scan`` (frame ``laser``): the front laser's records, ``FLASER`` or ``ROBOTLASER1``;
  ``/rear_scan`` (frame ``rear_laser``): ``RLASER`` or ``ROBOTLASER2``. A log holding both kinds
  for one laser gives the ROBOTLASER ones a topic of their own (``/robotlaser1``, frame
  ``robotlaser1``; ``/robotlaser2``), and the plan asks for ``--topic`` as for any bag with two
  scan topics. As ``sensor_msgs/LaserScan`` (:class:`LaserScan`): ranges as logged (float32),
  angles and ``range_max`` as :func:`~scan2terrain.readers._carmen_records.geometry` says;
  ``range_min`` :data:`RANGE_MIN` (a 0 reading says nothing). Readings at or beyond
  ``range_max`` are no return: they clear and are never hits
  (:func:`~scan2terrain.readers.laserscan.laserscan_points`).
* ``/odom`` (``nav_msgs/Odometry``, ``odom`` -> ``base_link``): the ODOM records when the log has
  them, else every laser record's odometry pose.
* ``/tf_static``: ``base_link`` -> each laser frame, the mount: PARAM
  ``robot_frontlaser_offset``, ``robot_frontlaser_side_offset``,
  ``robot_frontlaser_angular_offset`` (``robot_rearlaser_*``; metres forward and left, radians:
  CARMEN's robot module puts the laser at ``robot_pose`` plus these), any of them given (the
  others 0, as CARMEN takes them); else the laser pose less the odometry pose of the records,
  when it is the same on every record; else nothing is known and the identity is used.
* **Raw or corrected.** In a raw log (MIT CSAIL, Intel, ACES, FR079...) every record's laser pose
  is its odometry pose plus one mount (within :data:`SAME_POSE_M`, :data:`SAME_POSE_RAD`): poses
  come from odometry, there is no ``map`` frame, and ``--poses auto`` picks the odometry.
  When the laser poses are *corrected* (a SLAM system's output), ``/tf`` also holds
  ``map`` -> ``odom`` and ``odom`` -> ``base_link`` at every record of a corrected laser, such
  that ``map`` -> ``odom`` -> ``base_link`` -> laser is the logged laser pose: the plan poses
  by tf in the fixed frame ``map``, as for a recording made under SLAM.
* **Time.** Messages come in timestamp order (ties in the order asked for, then line order), as a
  bag's index gives them, with every stamp as logged: the logs whose timestamps step back (the
  Intel log: 631 of 13,631 scans stamped up to 0.9 s after the next ones) are read as a bag made
  of them would be, each scan still paired with its own record's poses. How many records step
  back, and how far, is in the plan's notes. ``/tf_static`` is stamped at the first record.
* **Parsed once per process**: opening the same unchanged file again (``--stream`` opens the
  recording once per slice) reuses the parsed arrays (:func:`_parsed`).
"""

from __future__ import annotations

import functools
import math
import re
from collections.abc import Callable, Collection, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from rosbags.interfaces import (
    Connection,
    ConnectionExtRosbag1,
    MessageDefinition,
    MessageDefinitionFormat,
    TopicInfo,
)

from scan2terrain.errors import InputError
from scan2terrain.readers._carmen_records import (
    LASER_SIDES,
    Geometry,
    Lasers,
    Log,
    geometry,
    open_text,
    read_records,
)
from scan2terrain.readers.foxglove import (
    Header,
    Pose,
    PoseWithCovariance,
    Quaternion,
    TfTransform,
    Time,
    Transforms,
    TransformStamped,
    Vector3,
)

__all__ = [
    "RANGE_MIN",
    "CarmenFile",
    "LaserScan",
    "Odometry",
    "is_carmen_log",
    "named_like_log",
]

#: What a path named like a log ends with (then ``.gz`` / ``.bz2`` or not).
LOG_SUFFIXES = (".clf", ".log")
#: metres: readings below are no information (CARMEN logs 0 for nothing measured).
RANGE_MIN = 0.001
#: A laser pose within this of the odometry pose plus the mount, on every record, is raw.
SAME_POSE_M, SAME_POSE_RAD = 1e-3, 1e-3
#: Record types a log starts with (CARMEN's header lists them), for recognising one by content.
_RECORDS = re.compile(
    rb"(PARAM|SYNC|ODOM|FLASER|RLASER|ROBOTLASER[0-9]|RAWLASER[0-9]|LASER[0-9]|TRUEPOS|"
    rb"GLOBALPOS|NMEAGGA|NMEARMC|SONAR|BUMPER|COMMENT|REMISSION[A-Z0-9]+)\s"
)
_LASER_SCAN = "sensor_msgs/msg/LaserScan"
_ODOMETRY = "nav_msgs/msg/Odometry"
_TF = "tf2_msgs/msg/TFMessage"
_NS = 1_000_000_000


# --- the ROS-shaped messages ------------------------------------------------------------------


@dataclass(frozen=True)
class LaserScan:
    """A laser record as a ``sensor_msgs/LaserScan`` (angles in radians, ranges in metres)."""

    header: Header
    angle_min: float
    angle_max: float
    angle_increment: float
    range_min: float
    range_max: float
    ranges: NDArray[np.float32]
    time_increment: float = 0.0
    scan_time: float = 0.0
    intensities: NDArray[np.float32] = field(default_factory=lambda: np.zeros(0, np.float32))


@dataclass(frozen=True)
class Odometry:
    """An odometry pose as a ``nav_msgs/Odometry`` (``odom`` -> ``base_link``)."""

    header: Header
    child_frame_id: str
    pose: PoseWithCovariance


def _header(stamp_ns: int, frame: str) -> Header:
    return Header(Time(stamp_ns // _NS, stamp_ns % _NS), frame)


def _yaw(theta: float) -> Quaternion:
    return Quaternion(0.0, 0.0, math.sin(theta / 2), math.cos(theta / 2))


def _edge(parent: str, child: str, stamp_ns: int, pose: NDArray[np.float64]) -> TransformStamped:
    x, y, theta = (float(v) for v in pose)
    return TransformStamped(
        _header(stamp_ns, parent), child, TfTransform(Vector3(x, y, 0.0), _yaw(theta))
    )


# --- 2D poses (x, y, theta) --------------------------------------------------------------------


def _wrap(a: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.arctan2(np.sin(a), np.cos(a))


def _compose(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """``a (+) b``: b's pose, given in a's frame, in a's parent frame ((K, 3) or (3,))."""
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = a[..., 0] + c * b[..., 0] - s * b[..., 1]
    y = a[..., 1] + s * b[..., 0] + c * b[..., 1]
    return np.stack([x, y, _wrap(a[..., 2] + b[..., 2])], axis=-1)


def _inverse(a: NDArray[np.float64]) -> NDArray[np.float64]:
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = -c * a[..., 0] - s * a[..., 1]
    y = s * a[..., 0] - c * a[..., 1]
    return np.stack([x, y, _wrap(-a[..., 2])], axis=-1)


# --- what each laser becomes -------------------------------------------------------------------


@dataclass(frozen=True)
class _Laser:
    """One laser record type as a topic: its records, beams, mount and pose kind."""

    topic: str
    frame: str
    records: Lasers
    beams: Geometry
    mount: NDArray[np.float64]  #: x, y, theta of the laser on base_link
    mount_from: str
    corrected: bool
    offset_m: float  #: the largest distance from the laser pose to odometry plus mount
    offset_rad: float


def _names(kinds: Collection[str]) -> dict[str, tuple[str, str]]:
    """Laser record type -> (topic, frame)."""
    out = {}
    for kind in kinds:
        front = LASER_SIDES[kind] == "front"
        if kind in ("FLASER", "RLASER"):
            out[kind] = ("/scan", "laser") if front else ("/rear_scan", "rear_laser")
        else:
            old = "FLASER" if front else "RLASER"
            if old in kinds:
                out[kind] = (f"/{kind.lower()}", kind.lower())
            else:
                out[kind] = ("/scan", "laser") if front else ("/rear_scan", "rear_laser")
    return out


def _laser(path: Path, log: Log, lasers: Lasers, topic: str, frame: str) -> _Laser:
    side = "frontlaser" if LASER_SIDES[lasers.kind] == "front" else "rearlaser"
    names = (f"robot_{side}_offset", f"robot_{side}_side_offset", f"robot_{side}_angular_offset")
    given = [log.param(path, n) for n in names]
    # The laser pose on the robot, per record: constant in a raw log.
    seen = _compose(_inverse(lasers.odom_poses), lasers.laser_poses)
    ref = seen[0]
    spread_m = float(np.hypot(seen[:, 0] - ref[0], seen[:, 1] - ref[1]).max())
    spread_rad = float(np.abs(_wrap(seen[:, 2] - ref[2])).max())
    constant = spread_m <= SAME_POSE_M and spread_rad <= SAME_POSE_RAD
    if any(v is not None for v in given):
        for name, v in zip(names, given, strict=True):
            if v is not None and abs(v) > 100:
                _, line = log.params[name]
                raise InputError(path, f"line {line}: PARAM {name} {v:g} is not a laser's offset")
        mount = np.array([v or 0.0 for v in given])
        listed = ", ".join(f"{n} {v:g}" for n, v in zip(names, given, strict=True) if v is not None)
        mount_from = f"PARAM {listed}"
    elif constant:
        yaw = ref[2] + _wrap(seen[:, 2] - ref[2]).mean()
        mount = np.round([seen[:, 0].mean(), seen[:, 1].mean(), yaw], 9) + 0.0  # not -0.0
        mount_from = "the records' laser pose less their odometry pose, the same on every record"
    else:
        mount = np.zeros(3)
        mount_from = (
            f"not known (no PARAM {names[0]}, and the laser poses are corrected): the identity; "
            "the scans still land at the logged laser poses"
        )
    mount_from += f" (x {mount[0]:.4g} m, y {mount[1]:.4g} m, yaw {mount[2]:.4g} rad)"
    expected = _compose(lasers.odom_poses, mount)
    dist = np.hypot(*(lasers.laser_poses[:, :2] - expected[:, :2]).T)
    turn = np.abs(_wrap(lasers.laser_poses[:, 2] - expected[:, 2]))
    offset_m, offset_rad = float(dist.max()), float(turn.max())
    if constant and (offset_m > SAME_POSE_M or offset_rad > SAME_POSE_RAD):
        mount_from += (
            f" (the records put the laser {offset_m:.3f} m, {offset_rad:.3f} rad from there, the "
            "same on every record: the PARAM is used)"
        )
    return _Laser(
        topic, frame, lasers, geometry(path, log, lasers), mount, mount_from,
        not constant, offset_m, offset_rad,
    )  # fmt: skip


# --- the file ----------------------------------------------------------------------------------


@functools.lru_cache(maxsize=1)
def _parsed(path: Path, _key: tuple[str, int, int, int]) -> tuple[Log, tuple[_Laser, ...]]:
    """The log's records and lasers; ``_key`` (the file's resolved path, size, change time and
    inode) makes a changed file parse again."""
    log = read_records(path)
    names = _names(list(log.lasers))
    lasers = tuple(_laser(path, log, log.lasers[k], *names[k]) for k in log.lasers)
    topics = [las.topic for las in lasers]
    if len(set(topics)) != len(topics):  # pragma: no cover - _names gives each its own
        raise AssertionError(topics)
    return log, lasers


def _file_key(path: Path) -> tuple[str, int, int, int]:
    st = path.stat()
    return (str(path.resolve()), st.st_size, st.st_mtime_ns, st.st_ino)


@dataclass
class _Topic:
    """One topic's messages: bag times, lines (for ties) and how to build message i."""

    msgtype: str
    times: NDArray[np.int64]
    lines: NDArray[np.int64]
    build: Callable[[int], object]
    how: str


class CarmenFile:
    """A CARMEN log opened for :class:`~scan2terrain.readers.bag.Bag` (see the module docstring):
    ``connections``, ``topics``, ``start_time``, ``end_time`` (one past the last message),
    ``message_count``, ``messages`` (the raw item is the message's index in its topic),
    ``decode``, ``undecodable``; and ``notes``, what the plan is to say about the log.

    Raises
    ------
    InputError
        Damaged input, naming ``named`` and the line.
    """

    def __init__(self, path: Path, named: Path | None = None) -> None:
        self.path = path
        self._named = named or path
        try:
            self.log, self.lasers = _parsed(self._named, _file_key(path))
        except OSError as exc:
            raise InputError(self._named, f"cannot read the log ({exc.strerror or exc})") from exc
        self._topics: dict[str, _Topic] = {}
        for las in self.lasers:
            self._topics[las.topic] = self._scan_topic(las)
        self._topics["/odom"] = self._odom_topic()
        first = min(int(t.times.min()) for t in self._topics.values())
        mounts = [_edge("base_link", las.frame, first, las.mount) for las in self.lasers]
        self._topics["/tf_static"] = _Topic(
            _TF,
            np.array([first], dtype=np.int64),
            np.zeros(1, dtype=np.int64),
            lambda _: Transforms(mounts),
            "; ".join(f"base_link -> {las.frame}: {las.mount_from}" for las in self.lasers),
        )
        corrected = [las for las in self.lasers if las.corrected]
        if corrected:
            self._topics["/tf"] = self._map_topic(corrected)
        self.connections: list[Connection] = []
        self._by_id: dict[int, tuple[Connection, _Topic]] = {}
        for cid, (name, topic) in enumerate(sorted(self._topics.items())):
            conn = Connection(
                cid, name, topic.msgtype, MessageDefinition(MessageDefinitionFormat.NONE, ""),
                "", len(topic.times), ConnectionExtRosbag1(None, 0), self,
            )  # fmt: skip
            self.connections.append(conn)
            self._by_id[cid] = (conn, topic)
        times = np.concatenate([t.times for t in self._topics.values()])
        self.start_time = int(times.min())
        self.end_time = int(times.max()) + 1
        self.notes = self._notes()

    # topics ---------------------------------------------------------------------------------

    def _scan_topic(self, las: _Laser) -> _Topic:
        rec, beams = las.records, las.beams
        offsets, ranges = rec.offsets, rec.ranges
        ranges.setflags(write=False)
        stamps = rec.stamps_ns

        def build(i: int) -> LaserScan:
            n = int(offsets[i + 1] - offsets[i])
            lo, inc = float(beams.angle_min[i]), float(beams.angle_increment[i])
            return LaserScan(
                _header(int(stamps[i]), las.frame), lo, lo + (n - 1) * inc, inc, RANGE_MIN,
                float(beams.range_max[i]), ranges[offsets[i] : offsets[i + 1]],
            )  # fmt: skip

        counts = rec.counts
        beams_text = (
            f"{counts[0]} readings"
            if (counts == counts[0]).all()
            else f"{counts.min()}-{counts.max()} readings"
        )
        first, inc = math.degrees(beams.angle_min[0]), math.degrees(beams.angle_increment[0])
        top = beams.range_max
        top_text = f"{top[0]:g} m" if (top == top[0]).all() else f"{top.min():g}-{top.max():g} m"
        how = (
            f"{rec.kind} records, {beams_text}, {inc:g} deg apart from {first:g} deg "
            f"({beams.spacing}), range_max {top_text} ({beams.limit})"
        )
        return _Topic(_LASER_SCAN, stamps, rec.lines, build, how)

    def _odom_topic(self) -> _Topic:
        odom = self.log.odom
        if odom is not None:
            stamps, lines, poses = odom.stamps_ns, odom.lines, odom.poses
            how = "the ODOM records"
        else:
            stamps = np.concatenate([las.records.stamps_ns for las in self.lasers])
            lines = np.concatenate([las.records.lines for las in self.lasers])
            poses = np.concatenate([las.records.odom_poses for las in self.lasers])
            order = np.lexsort((lines, stamps))
            stamps, lines, poses = stamps[order], lines[order], poses[order]
            kinds = " and ".join(las.records.kind for las in self.lasers)
            how = f"the {kinds} records' odometry poses; the log has no ODOM records"

        def build(i: int) -> Odometry:
            x, y, theta = (float(v) for v in poses[i])
            pose = Pose(Vector3(x, y, 0.0), _yaw(theta))
            return Odometry(_header(int(stamps[i]), "odom"), "base_link", PoseWithCovariance(pose))

        return _Topic(_ODOMETRY, stamps, lines, build, how)

    def _map_topic(self, corrected: list[_Laser]) -> _Topic:
        """``map`` -> ``odom`` and ``odom`` -> ``base_link`` at every corrected record."""
        stamps = np.concatenate([las.records.stamps_ns for las in corrected])
        lines = np.concatenate([las.records.lines for las in corrected])
        odom = np.concatenate([las.records.odom_poses for las in corrected])
        # map -> odom = laser pose (-) mount (-) odometry pose
        to_base = [_compose(las.records.laser_poses, _inverse(las.mount)) for las in corrected]
        map_odom = _compose(np.concatenate(to_base), _inverse(odom))
        order = np.lexsort((lines, stamps))
        stamps, lines, odom, map_odom = stamps[order], lines[order], odom[order], map_odom[order]

        def build(i: int) -> Transforms:
            t = int(stamps[i])
            return Transforms(
                [_edge("map", "odom", t, map_odom[i]), _edge("odom", "base_link", t, odom[i])]
            )

        kinds = " and ".join(las.records.kind for las in corrected)
        how = f"map -> odom and odom -> base_link at every {kinds} record (corrected poses)"
        return _Topic(_TF, stamps, lines, build, how)

    def _notes(self) -> list[str]:
        notes = []
        for las in self.lasers:
            notes.append(f"mount of {las.frame} on base_link (/tf_static): {las.mount_from}")
        if any(las.corrected for las in self.lasers):
            worst = max(self.lasers, key=lambda las: las.offset_m)
            notes.append(
                f"CARMEN log with corrected laser poses (up to {worst.offset_m:.2f} m, "
                f"{worst.offset_rad:.2f} rad from odometry plus the mount: a SLAM result): "
                "/tf map -> odom puts each scan at its logged laser pose"
            )
        else:
            notes.append(
                "raw CARMEN log: every laser pose is the odometry pose plus the mount; poses "
                f"from odometry, no map frame (/odom: {self._topics['/odom'].how})"
            )
        if self.log.backward:
            steps = ", ".join(
                f"{n:,} {kind} (up to {s:.3f} s back)" for kind, (n, s) in self.log.backward.items()
            )
            notes.append(
                f"timestamps step back: {steps} records stamped before one of their kind above "
                "them: read in time order, stamps as logged"
            )
        return notes

    # what Bag reads ---------------------------------------------------------------------------

    @property
    def message_count(self) -> int:
        return sum(len(t.times) for t in self._topics.values())

    @property
    def topics(self) -> dict[str, TopicInfo]:
        return {
            conn.topic: TopicInfo(conn.msgtype, conn.msgdef, conn.msgcount, [conn])
            for conn, _ in self._by_id.values()
        }

    @property
    def described(self) -> str:
        """How the log was read, for ``inspect``: its lines and the records not used."""
        held = self.log.skipped
        unused = ", ".join(f"{k} {v:,}" for k, v in held.items())
        return f"{self.log.lines:,} lines" + (f"; not used: {unused}" if unused else "")

    def encodings(self) -> dict[str, str]:
        """Per topic, what it is made of."""
        return {name: t.how for name, t in self._topics.items()}

    def undecodable(self, conn: Connection) -> str | None:
        return None

    def decode(self, conn: Connection, raw: object) -> object:
        _, topic = self._by_id[conn.id]
        assert isinstance(raw, int)
        return topic.build(raw)

    def messages(
        self,
        connections: Collection[Connection] = (),
        start: int | None = None,
        stop: int | None = None,
    ) -> Iterator[tuple[Connection, int, int]]:
        """``(connection, time ns, index)`` for ``start <= time < stop``, in time order; ties in
        the order the connections are asked for (as rosbags merges a ROS1 bag's), then in line
        order."""
        order = [c.id for c in connections] if connections else sorted(self._by_id)
        lo = -(1 << 63) if start is None else start
        hi = (1 << 63) - 1 if stop is None else stop
        parts = []
        for asked, cid in enumerate(dict.fromkeys(order)):
            topic = self._by_id[cid][1]
            index = np.flatnonzero((topic.times >= lo) & (topic.times < hi))
            parts.append((topic.times[index], np.full(index.size, asked), topic.lines[index],
                          np.full(index.size, cid), index))  # fmt: skip
        if not parts:
            return
        t, ranks, lines, cids, indices = (np.concatenate(p) for p in zip(*parts, strict=True))
        for j in np.lexsort((lines, ranks, t)):
            yield self._by_id[int(cids[j])][0], int(t[j]), int(indices[j])

    def close(self) -> None:
        """Nothing is held open: the log was read when it was opened."""


# --- recognising a log -------------------------------------------------------------------------


def named_like_log(path: Path) -> bool:
    """Whether the name is a CARMEN log's: ``*.clf`` or ``*.log``, then ``.gz`` / ``.bz2`` or
    not."""
    suffixes = [s.lower() for s in path.suffixes[-2:]]
    if suffixes and suffixes[-1] in (".gz", ".bz2"):
        suffixes = suffixes[:-1]
    return bool(suffixes) and suffixes[-1] in LOG_SUFFIXES


def is_carmen_log(path: Path) -> bool:
    """Whether ``path`` is to be read as a CARMEN log: a regular file named like one
    (:func:`named_like_log`), or whose text (decompressed) starts with CARMEN's comments and
    records."""
    if not path.is_file():
        return False
    if named_like_log(path):
        return True
    try:
        with open_text(path) as f:
            head = f.read(4096)
    except (OSError, EOFError, ValueError):
        return False
    lines = head.splitlines()
    for line in lines[:-1] if len(head) == 4096 else lines:
        text = line.strip()
        if text and not text.startswith(b"#"):
            return _RECORDS.match(text + b" ") is not None
    return False
