"""Write small ROS1 / ROS 2 bags for tests with rosbags' own writers, and a synthetic room.

Messages are described as plain nested dicts (field name -> value; missing fields take ROS's
zero defaults; a ``builtin_interfaces/Time`` may be given as integer nanoseconds), so the same
description is written as ROS1 (``std_msgs/Header`` with ``seq``) or as ROS 2 (without): the
dict is turned into the typestore's message class only in :func:`write_bag`. Builders return
such dicts. ``Stores.ROS1_NOETIC`` has no ``tf2_msgs/TFMessage`` (nor ``tf/tfMessage``); both are
registered here from their one-line definitions.

:func:`synthetic_room` makes a known 2D room (10 m x 8 m of walls with a box inside) and a robot
driving an ellipse in it; scans are ray-cast analytically against the wall segments (numpy,
vectorised over scans x beams x segments), so tests know the true map and the true poses.
Walls lie 0.025 m off multiples of 0.05 m, so no hit falls on a cell or voxel boundary at 0.05
or 0.1 m resolution, and the true grid is exact at those resolutions.
"""

from __future__ import annotations

import base64
import json
import math
import struct
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from numpy.typing import NDArray
from rosbags.interfaces import Nodetype
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from scan2terrain.types import Transform

if TYPE_CHECKING:
    from scan2terrain.readers.bag import Bag

Fmt = Literal["ros1", "sqlite3", "mcap"]
FORMATS: tuple[Fmt, ...] = ("ros1", "sqlite3", "mcap")
#: (topic, msgtype, bag time ns, message dict or typestore object)
MsgSpec = tuple[str, str, int, Any]

LASER_SCAN = "sensor_msgs/msg/LaserScan"
POINT_CLOUD2 = "sensor_msgs/msg/PointCloud2"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
ODOMETRY = "nav_msgs/msg/Odometry"
OCCUPANCY_GRID = "nav_msgs/msg/OccupancyGrid"

_NUMPY = {
    "bool": np.bool_,
    "byte": np.uint8,
    "char": np.uint8,
    "octet": np.uint8,
    "int8": np.int8,
    "uint8": np.uint8,
    "int16": np.int16,
    "uint16": np.uint16,
    "int32": np.int32,
    "uint32": np.uint32,
    "int64": np.int64,
    "uint64": np.uint64,
    "float32": np.float32,
    "float64": np.float64,
}
_TIME_TYPES = {"builtin_interfaces/msg/Time", "builtin_interfaces/msg/Duration"}
_TRANSFORMS_DEF = "geometry_msgs/TransformStamped[] transforms"


def typestore(fmt: Fmt) -> Typestore:
    """The typestore bags of this format are written with (ROS1 Noetic or ROS 2 Humble)."""
    if fmt != "ros1":
        return get_typestore(Stores.ROS2_HUMBLE)
    ts = get_typestore(Stores.ROS1_NOETIC)
    ts.register(get_types_from_msg(_TRANSFORMS_DEF, TF_MESSAGE))
    ts.register(get_types_from_msg(_TRANSFORMS_DEF, "tf/msg/tfMessage"))
    return ts


def build(ts: Typestore, msgtype: str, value: Any) -> Any:
    """A typestore message object from a (partial) dict; objects pass through unchanged."""
    if not isinstance(value, Mapping):
        return value
    _, fields = ts.fielddefs[msgtype]
    names = {name for name, _ in fields}
    if unknown := set(value) - names:
        raise KeyError(f"{msgtype} has no field(s) {sorted(unknown)}")
    kwargs = {name: _field(ts, desc, value.get(name)) for name, desc in fields}
    return ts.types[msgtype](**kwargs)


def _field(ts: Typestore, desc: Any, value: Any) -> Any:
    node, sub = desc
    if node == Nodetype.BASE:
        typ = sub[0]
        if value is not None:
            return value
        if typ == "string":
            return ""
        return False if typ == "bool" else _NUMPY[typ](0).item()
    if node == Nodetype.NAME:
        if sub in _TIME_TYPES and isinstance(value, (int, np.integer)):
            sec, nsec = divmod(int(value), 1_000_000_000)
            return ts.types[sub](sec=sec, nanosec=nsec)
        return build(ts, sub, {} if value is None else value)
    (elem_node, elem_sub), length = sub
    if elem_node == Nodetype.BASE and elem_sub[0] != "string":
        dtype = _NUMPY[elem_sub[0]]
        if value is None:
            return np.zeros(length if node == Nodetype.ARRAY else 0, dtype=dtype)
        return np.ascontiguousarray(value, dtype=dtype)
    items = [] if value is None else list(value)
    if node == Nodetype.ARRAY and not items:
        items = [None] * length
    return [_field(ts, (elem_node, elem_sub), v) for v in items]


def write_bag(
    path: Path,
    fmt: Fmt,
    messages: Iterable[MsgSpec],
    *,
    extra_types: Mapping[str, str] | None = None,
) -> Path:
    """Write messages to a new bag and return its path.

    Parameters
    ----------
    path : Path
        A ``.bag`` file for ``ros1``, a new folder for ``sqlite3`` / ``mcap``.
    fmt : {"ros1", "sqlite3", "mcap"}
        Container. ROS 2 bags are rosbag2 version 9 with message definitions.
    messages : iterable of (topic, msgtype, t_ns, msg)
        ``msg`` is a dict (see :func:`build`) or a message object of :func:`typestore(fmt)`.
        Written sorted by time (stable); one connection per (topic, msgtype).
    extra_types : mapping of msgtype to .msg text, optional
        Custom types to register before writing.
    """
    ts = typestore(fmt)
    for name, text in (extra_types or {}).items():
        ts.register(get_types_from_msg(text, name))
    ordered = sorted(messages, key=lambda m: m[2])
    serialize = ts.serialize_ros1 if fmt == "ros1" else ts.serialize_cdr
    if fmt == "ros1":
        writer: Writer1 | Writer2 = Writer1(path)
    else:
        plugin = StoragePlugin.MCAP if fmt == "mcap" else StoragePlugin.SQLITE3
        writer = Writer2(path, version=9, storage_plugin=plugin)
    with writer:
        conns: dict[tuple[str, str], Any] = {}
        for topic, msgtype, t_ns, msg in ordered:
            key = (topic, msgtype)
            if key not in conns:
                conns[key] = writer.add_connection(topic, msgtype, typestore=ts)
            writer.write(conns[key], int(t_ns), serialize(build(ts, msgtype, msg), msgtype))
    return path


# --- messages read back, typed Any in this one place ---------------------------------------------
# rosbags makes a message's class at run time from its definition (per typestore, per bag), so
# mypy cannot know its fields: ``Bag.messages`` and ``Typestore.deserialize_*`` say ``object``.
# A test knows what it wrote or recorded, and reads fields (``msg.header.stamp.sec``) directly;
# these two helpers hand it the message as ``Any`` on purpose rather than a cast at every use.


def ros_msg(msg: object) -> Any:
    """``msg`` unchanged, typed ``Any``: a message object rosbags generated (see above)."""
    return msg


def read_messages(
    bag: Bag,
    topics: str | Iterable[str],
    start_ns: int | None = None,
    end_ns: int | None = None,
) -> Iterator[tuple[str, int, Any]]:
    """``bag.messages(...)`` unchanged, with each message typed ``Any`` (see :func:`ros_msg`)."""
    return bag.messages(topics, start_ns, end_ns)


# --- message builders (dicts, format-neutral) ----------------------------------------------------


def header(stamp_ns: int, frame: str) -> dict[str, Any]:
    return {"stamp": int(stamp_ns), "frame_id": frame}


def yaw_quaternion(yaw: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation by ``yaw`` about z."""
    return (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))


def _pose(xyz: Sequence[float], q_xyzw: Sequence[float]) -> dict[str, Any]:
    return {
        "position": dict(zip("xyz", map(float, xyz), strict=True)),
        "orientation": dict(zip("xyzw", map(float, q_xyzw), strict=True)),
    }


def laserscan_msg(
    stamp_ns: int,
    frame: str,
    angle_min: float,
    angle_increment: float,
    ranges: NDArray[np.floating] | Sequence[float],
    range_min: float,
    range_max: float,
    *,
    intensities: NDArray[np.floating] | Sequence[float] | None = None,
    scan_time: float = 0.1,
) -> dict[str, Any]:
    """A sensor_msgs/LaserScan; ``angle_max`` follows from the beam count."""
    r = np.asarray(ranges, dtype=np.float32)
    return {
        "header": header(stamp_ns, frame),
        "angle_min": float(angle_min),
        "angle_max": float(angle_min + (len(r) - 1) * angle_increment),
        "angle_increment": float(angle_increment),
        "time_increment": 0.0,
        "scan_time": float(scan_time),
        "range_min": float(range_min),
        "range_max": float(range_max),
        "ranges": r,
        "intensities": np.asarray([] if intensities is None else intensities, np.float32),
    }


_POINTFIELD_TYPE = {
    np.dtype(np.int8): 1,
    np.dtype(np.uint8): 2,
    np.dtype(np.int16): 3,
    np.dtype(np.uint16): 4,
    np.dtype(np.int32): 5,
    np.dtype(np.uint32): 6,
    np.dtype(np.float32): 7,
    np.dtype(np.float64): 8,
}


def pointcloud2_msg(
    stamp_ns: int,
    frame: str,
    points: NDArray[np.floating],
    extra: Mapping[str, NDArray[Any]] | None = None,
    *,
    point_step: int | None = None,
    is_dense: bool = True,
) -> dict[str, Any]:
    """An unorganised sensor_msgs/PointCloud2 (height 1), little-endian.

    ``points`` (N, 3) become float32 fields x, y, z at offsets 0, 4, 8; ``extra`` adds one
    field per named (N,) array after them; ``point_step`` larger than the packed size pads every
    point (as real drivers do).
    """
    pts = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    columns = {"x": pts[:, 0], "y": pts[:, 1], "z": pts[:, 2]}
    columns.update({k: np.asarray(v) for k, v in (extra or {}).items()})
    names, formats, offsets, fields = [], [], [], []
    offset = 0
    for name, col in columns.items():
        dt = col.dtype.newbyteorder("<")
        names.append(name)
        formats.append(dt)
        offsets.append(offset)
        fields.append(
            {"name": name, "offset": offset, "datatype": _POINTFIELD_TYPE[col.dtype], "count": 1}
        )
        offset += dt.itemsize
    step = offset if point_step is None else point_step
    if step < offset:
        raise ValueError(f"point_step {step} is smaller than the fields ({offset} bytes)")
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": step})
    packed = np.zeros(len(pts), dtype=dtype)
    for name, col in columns.items():
        packed[name] = col
    return {
        "header": header(stamp_ns, frame),
        "height": 1,
        "width": len(pts),
        "fields": fields,
        "is_bigendian": False,
        "point_step": step,
        "row_step": step * len(pts),
        "data": packed.view(np.uint8).reshape(-1),
        "is_dense": is_dense,
    }


def tf_msg(
    transforms: Iterable[
        tuple[str, str, int, Sequence[float], Sequence[float]]  # parent, child, ns, xyz, q_xyzw
    ],
) -> dict[str, Any]:
    """A tf2_msgs/TFMessage (also valid as ROS1 tf/tfMessage)."""
    return {
        "transforms": [
            {
                "header": header(stamp, parent),
                "child_frame_id": child,
                "transform": {
                    "translation": dict(zip("xyz", map(float, xyz), strict=True)),
                    "rotation": dict(zip("xyzw", map(float, q), strict=True)),
                },
            }
            for parent, child, stamp, xyz, q in transforms
        ]
    }


def odometry_msg(
    stamp_ns: int,
    frame: str,
    child: str,
    xyz: Sequence[float],
    q_xyzw: Sequence[float],
    *,
    linear: Sequence[float] = (0.0, 0.0, 0.0),
    angular: Sequence[float] = (0.0, 0.0, 0.0),
) -> dict[str, Any]:
    """A nav_msgs/Odometry: pose of ``child`` in ``frame``, twist in ``child``."""
    return {
        "header": header(stamp_ns, frame),
        "child_frame_id": child,
        "pose": {"pose": _pose(xyz, q_xyzw)},
        "twist": {
            "twist": {
                "linear": dict(zip("xyz", map(float, linear), strict=True)),
                "angular": dict(zip("xyz", map(float, angular), strict=True)),
            }
        },
    }


def occupancy_grid_msg(
    stamp_ns: int,
    frame: str,
    data: NDArray[np.integer],
    resolution: float,
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> dict[str, Any]:
    """A nav_msgs/OccupancyGrid from ``data`` (H, W) int8, row 0 = lowest y; origin (x, y, yaw)."""
    grid = np.asarray(data, dtype=np.int8)
    x, y, yaw = origin
    return {
        "header": header(stamp_ns, frame),
        "info": {
            "map_load_time": int(stamp_ns),
            "resolution": float(resolution),
            "width": int(grid.shape[1]),
            "height": int(grid.shape[0]),
            "origin": _pose((x, y, 0.0), yaw_quaternion(yaw)),
        },
        "data": grid.reshape(-1),
    }


# --- the synthetic room ---------------------------------------------------------------------------

Variant = Literal["tf", "odom", "slashes", "tf_gap", "cloud"]


def _box(x0: float, y0: float, x1: float, y1: float) -> list[tuple[float, float, float, float]]:
    return [(x0, y0, x1, y0), (x1, y0, x1, y1), (x1, y1, x0, y1), (x0, y1, x0, y0)]


#: Outer walls (10 m x 8 m) and an inner box (1.5 m x 1.5 m), map frame, metres.
ROOM = (-4.975, -3.975, 5.025, 4.025)
BOX = (2.025, -2.975, 3.525, -1.475)
WALL_HEIGHT = 2.5
BOX_HEIGHT = 0.8


def segment_distances(
    origins: NDArray[np.float64], angles: NDArray[np.float64], segments: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Distance along each 2D ray to each segment (inf where the ray misses it).

    Parameters
    ----------
    origins : (K, 2)
        Ray origins, one per scan.
    angles : (K, B)
        World-frame ray directions, radians.
    segments : (S, 4)
        x0, y0, x1, y1 each.

    Returns
    -------
    float64 (K, B, S)
    """
    d = np.stack([np.cos(angles), np.sin(angles)], axis=-1)[:, :, None, :]  # K B 1 2
    p = segments[None, None, :, :2]
    e = segments[None, None, :, 2:] - p  # 1 1 S 2
    w = p - origins[:, None, None, :]  # K 1 S 2
    denom = d[..., 0] * e[..., 1] - d[..., 1] * e[..., 0]  # K B S
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[..., 0] * e[..., 1] - w[..., 1] * e[..., 0]) / denom
        u = (w[..., 0] * d[..., 1] - w[..., 1] * d[..., 0]) / denom
    ok = (np.abs(denom) > 1e-12) & (t > 1e-9) & (u >= 0) & (u <= 1)
    return np.where(ok, t, np.inf)


def cast_rays(
    origins: NDArray[np.float64], angles: NDArray[np.float64], segments: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Distance along each 2D ray (K, B) to the first segment it meets (inf if none)."""
    nearest: NDArray[np.float64] = segment_distances(origins, angles, segments).min(axis=-1)
    return nearest


def cast_rays_3d(
    origin: NDArray[np.float64],
    azimuths: NDArray[np.float64],
    elevations: NDArray[np.float64],
    segments: NDArray[np.float64],
    heights: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Horizontal distance of each 3D ray to what it meets first: walls extruded from z = 0 to
    their height, and the floor z = 0; inf for rays that leave over the walls.

    ``origin`` (3,) is the sensor position; ``azimuths``/``elevations`` (B,) world-frame ray
    directions. The result is (B,).
    """
    t = segment_distances(origin[None, :2], azimuths[None, :], segments)[0]  # B S
    tan_e = np.tan(elevations)[:, None]
    z = origin[2] + t * tan_e
    t = np.where((z >= 0) & (z <= heights[None, :]), t, np.inf).min(axis=-1)
    with np.errstate(divide="ignore"):
        floor = np.where(tan_e[:, 0] < 0, origin[2] / -tan_e[:, 0], np.inf)
    first: NDArray[np.float64] = np.minimum(t, floor)
    return first


@dataclass(frozen=True)
class SyntheticRoom:
    """A synthetic recording and its ground truth.

    Attributes
    ----------
    messages : list of (topic, msgtype, t_ns, dict)
        Ready for :func:`write_bag`.
    occupied : bool (H, W)
        True wall cells, row 0 = lowest y (ROS grid order).
    inside : bool (H, W)
        Cells inside the room (free space truth is ``inside & ~occupied``).
    resolution : float
        Cell side of the truth grids, metres.
    origin : (float, float)
        Map-frame x, y of the lower-left corner of cell (0, 0) (a multiple of ``resolution``).
    stamps_ns : int64 (K,)
        Header stamps of the scans (bag times are 5 ms later).
    base_poses : float64 (K, 3)
        x, y, yaw of base_link in the map frame at each scan.
    sensor_poses : float64 (K, 3)
        x, y, yaw of the sensor in the map frame (the sensor is level, at ``mount`` height).
    mount : Transform
        base_link -> sensor.
    map_to_odom : Transform
    sensor_frame, scan_topic : str
    hits : list of float64 (N, 3)
        Every return of each scan in the map frame (same order as the messages).
    segments : float64 (S, 4) and heights (S,)
        The walls, for tests that need geometry.
    """

    messages: list[MsgSpec]
    occupied: NDArray[np.bool_]
    inside: NDArray[np.bool_]
    resolution: float
    origin: tuple[float, float]
    stamps_ns: NDArray[np.int64]
    base_poses: NDArray[np.float64]
    sensor_poses: NDArray[np.float64]
    mount: Transform
    map_to_odom: Transform
    sensor_frame: str
    scan_topic: str
    hits: list[NDArray[np.float64]] = field(repr=False)
    segments: NDArray[np.float64] = field(repr=False)
    heights: NDArray[np.float64] = field(repr=False)

    def write(self, path: Path, fmt: Fmt) -> Path:
        return write_bag(path, fmt, self.messages)

    def sensor_origins(self) -> NDArray[np.float64]:
        """(K, 3) sensor positions in the map frame."""
        z = np.full(len(self.sensor_poses), self.mount.translation[2])
        return np.column_stack([self.sensor_poses[:, :2], z])


def _rasterise(
    segments: NDArray[np.float64],
    resolution: float,
    origin: tuple[float, float],
    shape: tuple[int, int],
) -> NDArray[np.bool_]:
    grid = np.zeros(shape, dtype=bool)
    lengths = np.hypot(segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1])
    n = np.maximum(np.ceil(lengths / (resolution / 4)).astype(int), 1) + 1
    seg = np.repeat(np.arange(len(segments)), n)
    frac = np.concatenate([np.linspace(0.0, 1.0, k) for k in n])
    x = segments[seg, 0] + frac * (segments[seg, 2] - segments[seg, 0])
    y = segments[seg, 1] + frac * (segments[seg, 3] - segments[seg, 1])
    col = np.floor((x - origin[0]) / resolution).astype(int)
    row = np.floor((y - origin[1]) / resolution).astype(int)
    grid[row, col] = True
    return grid


def _compose2d(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Pose a (.., 3) times pose b (.., 3), both x, y, yaw."""
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack(
        [
            a[..., 0] + c * b[..., 0] - s * b[..., 1],
            a[..., 1] + s * b[..., 0] + c * b[..., 1],
            a[..., 2] + b[..., 2],
        ],
        axis=-1,
    )


def _inverse2d(a: NDArray[np.float64]) -> NDArray[np.float64]:
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack(
        [-(c * a[..., 0] + s * a[..., 1]), s * a[..., 0] - c * a[..., 1], -a[..., 2]], axis=-1
    )


def synthetic_room(
    variant: Variant = "tf",
    *,
    n_scans: int = 200,
    rate_hz: float = 10.0,
    start_ns: int = 1_700_000_000_000_000_000,
    beams: int = 360,
    range_max: float = 30.0,
    resolution: float = 0.05,
    map_to_odom: tuple[float, float, float] = (0.3, -0.2, 0.05),
    mount: tuple[float, float, float, float] = (0.2, 0.0, 0.3, 0.0),
    gap_s: tuple[float, float] = (8.0, 10.0),
    rings: int = 16,
    azimuths: int = 180,
) -> SyntheticRoom:
    """A robot driving one loop of an ellipse in a known room, scanning it.

    Variants
    --------
    ``tf``: /scan LaserScan (frame ``laser``); /tf with odom->base_link at twice the scan rate
    (every scan stamp has an exact sample) and map->odom at half the scan rate; /tf_static with
    base_link->laser once. ``slashes``: the same with ROS1-style tf names (``/map``, ``/odom``,
    ``/base_link``, ``/laser``) while header.frame_id stays ``laser``. ``tf_gap``: the same with
    no /tf between ``gap_s`` seconds after the start (scans continue). ``odom``: no tf at all;
    /odom Odometry (odom -> base_link) at the scan rate, map->odom is the identity and the mount
    must be given to the pipeline. ``cloud``: /points PointCloud2 in frame ``lidar`` (``rings``
    elevations from -15 to +15 degrees x ``azimuths``), walls 2.5 m high, the box 0.8 m, the
    floor at z = 0; tf as in ``tf``; the sensor mount is 1.0 m high unless given.

    Scans carry their header stamp; bag (record) times are 5 ms later.
    """
    if variant == "cloud" and mount == (0.2, 0.0, 0.3, 0.0):
        mount = (0.1, 0.0, 1.0, 0.0)
    rx0, ry0, rx1, ry1 = ROOM
    segments = np.array(_box(*ROOM) + _box(*BOX), dtype=np.float64)
    heights = np.array([WALL_HEIGHT] * 4 + [BOX_HEIGHT] * 4)

    # Trajectory: an ellipse around (-0.5, 0.5), radii 4 x 2.5, heading along the tangent; it
    # passes right of the box, so every wall face is seen from somewhere.
    period_ns = round(1e9 / rate_hz)
    stamps = start_ns + np.arange(n_scans, dtype=np.int64) * period_ns
    phase = np.linspace(0.0, 2 * np.pi, n_scans, endpoint=False)

    def base_at(ph: NDArray[np.float64]) -> NDArray[np.float64]:
        x, y = -0.5 + 4.0 * np.cos(ph), 0.5 + 2.5 * np.sin(ph)
        yaw = np.arctan2(2.5 * np.cos(ph), -4.0 * np.sin(ph))
        return np.stack([x, y, yaw], axis=-1)

    base = base_at(phase)
    m2o = np.zeros(3) if variant == "odom" else np.asarray(map_to_odom, dtype=np.float64)
    mnt = np.array([mount[0], mount[1], mount[3]])
    sensor = _compose2d(base, mnt)

    frame = "lidar" if variant == "cloud" else "laser"
    topic = "/points" if variant == "cloud" else "/scan"
    lag = 5_000_000
    messages: list[MsgSpec] = []
    hits: list[NDArray[np.float64]] = []
    if variant == "cloud":
        elev = np.repeat(np.deg2rad(np.linspace(-15.0, 15.0, rings)), azimuths)
        az = np.tile(np.linspace(-np.pi, np.pi, azimuths, endpoint=False), rings)
        z0 = mount[2]
        for k in range(n_scans):  # one cloud per iteration, vectorised over its rays
            origin = np.array([sensor[k, 0], sensor[k, 1], z0])
            dist = cast_rays_3d(origin, sensor[k, 2] + az, elev, segments, heights)
            v = np.isfinite(dist)
            pts = np.column_stack(
                [dist[v] * np.cos(az[v]), dist[v] * np.sin(az[v]), dist[v] * np.tan(elev[v])]
            )
            msg = pointcloud2_msg(int(stamps[k]), frame, pts)
            messages.append((topic, POINT_CLOUD2, int(stamps[k]) + lag, msg))
            c, s = math.cos(sensor[k, 2]), math.sin(sensor[k, 2])
            p32 = pts.astype(np.float32).astype(np.float64)  # what the bag holds
            hits.append(
                np.column_stack(
                    [
                        sensor[k, 0] + c * p32[:, 0] - s * p32[:, 1],
                        sensor[k, 1] + s * p32[:, 0] + c * p32[:, 1],
                        z0 + p32[:, 2],
                    ]
                )
            )
    else:
        inc = 2 * np.pi / beams
        local = -np.pi + inc * np.arange(beams)
        dist = cast_rays(sensor[:, :2], sensor[:, 2:3] + local[None, :], segments)
        ranges = dist.astype(np.float32)
        for k in range(n_scans):
            messages.append(
                (
                    topic,
                    LASER_SCAN,
                    int(stamps[k]) + lag,
                    laserscan_msg(int(stamps[k]), frame, -np.pi, inc, ranges[k], 0.05, range_max),
                )
            )
            ok = ranges[k] <= range_max
            wa = sensor[k, 2] + local[ok]
            r = ranges[k][ok].astype(np.float64)
            hits.append(
                np.column_stack(
                    [
                        sensor[k, 0] + r * np.cos(wa),
                        sensor[k, 1] + r * np.sin(wa),
                        np.full(len(r), mount[2]),
                    ]
                )
            )

    slash = "/" if variant == "slashes" else ""
    names = {n: slash + n for n in ("map", "odom", "base_link")}
    names["sensor"] = slash + frame
    if variant == "odom":
        for k in range(n_scans):
            x, y, yaw = base[k]
            messages.append(
                (
                    "/odom",
                    ODOMETRY,
                    int(stamps[k]) + 1_000_000,
                    odometry_msg(
                        int(stamps[k]), "odom", "base_link", (x, y, 0.0), yaw_quaternion(yaw)
                    ),
                )
            )
    else:
        # odom -> base_link at twice the scan rate: every scan stamp has a sample.
        tf_stamps = start_ns + np.arange(2 * n_scans, dtype=np.int64) * (period_ns // 2)
        odom_base = _compose2d(
            _inverse2d(m2o), base_at(np.linspace(0, 2 * np.pi, 2 * n_scans, endpoint=False))
        )
        gap = (start_ns + round(gap_s[0] * 1e9), start_ns + round(gap_s[1] * 1e9))
        for j, t_tf in enumerate(tf_stamps):
            t = int(t_tf)
            if variant == "tf_gap" and gap[0] <= t < gap[1]:
                continue
            x, y, yaw = odom_base[j]
            edges = [(names["odom"], names["base_link"], t, (x, y, 0.0), yaw_quaternion(yaw))]
            if j % 4 == 0:
                edges.append(
                    (names["map"], names["odom"], t, (m2o[0], m2o[1], 0.0), yaw_quaternion(m2o[2]))
                )
            messages.append(("/tf", TF_MESSAGE, t + 1_000_000, tf_msg(edges)))
        messages.append(
            (
                "/tf_static",
                TF_MESSAGE,
                start_ns,
                tf_msg(
                    [
                        (
                            names["base_link"],
                            names["sensor"],
                            start_ns,
                            mount[:3],
                            yaw_quaternion(mount[3]),
                        )
                    ]
                ),
            )
        )

    margin = 0.5
    ox = round(math.floor((rx0 - margin) / resolution) * resolution, 9)
    oy = round(math.floor((ry0 - margin) / resolution) * resolution, 9)
    shape = (
        math.ceil((ry1 + margin - oy) / resolution),
        math.ceil((rx1 + margin - ox) / resolution),
    )
    occupied = _rasterise(segments, resolution, (ox, oy), shape)
    cy = oy + (np.arange(shape[0]) + 0.5) * resolution
    cx = ox + (np.arange(shape[1]) + 0.5) * resolution
    q = resolution / 4  # cells whose centre lies on a wall are walls, not inside
    inside = ((cx[None, :] > rx0 + q) & (cx[None, :] < rx1 - q)) & (
        (cy[:, None] > ry0 + q) & (cy[:, None] < ry1 - q)
    )
    in_box = ((cx[None, :] > BOX[0] - q) & (cx[None, :] < BOX[2] + q)) & (
        (cy[:, None] > BOX[1] - q) & (cy[:, None] < BOX[3] + q)
    )
    return SyntheticRoom(
        messages=messages,
        occupied=occupied,
        inside=inside & ~in_box,
        resolution=resolution,
        origin=(ox, oy),
        stamps_ns=stamps,
        base_poses=base,
        sensor_poses=sensor,
        mount=Transform.from_quaternion(mount[:3], yaw_quaternion(mount[3])),
        map_to_odom=Transform.from_quaternion((m2o[0], m2o[1], 0.0), yaw_quaternion(m2o[2])),
        sensor_frame=frame,
        scan_topic=topic,
        hits=hits,
        segments=segments,
        heights=heights,
    )


# --- ROS1 bags rewritten as MCAP (what `mcap convert` makes of them) ------------------------------

McapCompression = Literal["zstd", "lz4", "none"]

#: id -> (compression, summary, chunked)
LAYOUTS: dict[str, tuple[McapCompression, bool, bool]] = {
    "zstd": ("zstd", True, True),
    "lz4": ("lz4", True, True),
    "none": ("none", True, True),
    "zstd-no-summary": ("zstd", False, True),
    "lz4-no-summary": ("lz4", False, True),
    "unchunked": ("none", True, False),
    "unchunked-no-summary": ("none", False, False),
}


def ros1_bag_to_mcap(
    bag: Path,
    out: Path,
    *,
    compression: McapCompression = "zstd",
    summary: bool = True,
    chunked: bool = True,
    chunk_size: int = 256 * 1024,
) -> Path:
    """Rewrite a ROS1 ``.bag`` as a ROS1 MCAP file (profile ``ros1``), as ``mcap convert`` does.

    One channel per connection (message encoding ``ros1``, its ``md5sum`` and ``callerid`` in the
    metadata), one ``ros1msg`` schema per type (the ROS1 name, ``sensor_msgs/LaserScan``, and
    the connection's full definition text), the raw ROS1 bytes and log times of every message,
    in the order rosbags reads them. ``summary=False`` writes no summary section at all (no
    statistics, indexes, or repeated schemas: a streaming writer's file); ``chunked=False``
    writes the messages as top-level records.
    """
    from mcap.writer import CompressionType, IndexType
    from mcap.writer import Writer as McapWriter
    from rosbags.interfaces import ConnectionExtRosbag1
    from rosbags.rosbag1 import Reader as Reader1

    kinds = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
    options: dict[str, Any] = {}
    if not summary:
        options = {
            "index_types": IndexType.NONE,
            "repeat_channels": False,
            "repeat_schemas": False,
            "use_statistics": False,
            "use_summary_offsets": False,
        }
    with Reader1(bag) as reader, out.open("wb") as f:
        writer = McapWriter(
            f,
            chunk_size=chunk_size,
            compression=kinds[compression],
            use_chunking=chunked,
            **options,
        )
        writer.start(profile="ros1", library="scan2terrain tests")
        schemas: dict[str, int] = {}
        channels: dict[int, int] = {}
        for conn in reader.connections:
            ros1_name = conn.msgtype.replace("/msg/", "/")
            if ros1_name not in schemas:
                schemas[ros1_name] = writer.register_schema(
                    ros1_name, "ros1msg", conn.msgdef.data.encode()
                )
            meta = {"md5sum": conn.digest}
            if isinstance(conn.ext, ConnectionExtRosbag1) and conn.ext.callerid:
                meta["callerid"] = conn.ext.callerid
            channels[conn.id] = writer.register_channel(
                conn.topic, "ros1", schemas[ros1_name], meta
            )
        for seq, (conn, t_ns, raw) in enumerate(reader.messages()):
            writer.add_message(channels[conn.id], int(t_ns), bytes(raw), int(t_ns), seq)
        writer.finish()  # type: ignore[no-untyped-call]
    return out


def first_chunk_data(data: bytes) -> int:
    """Offset of the first chunk's compressed bytes in a file (after magic and header)."""
    pos = 8
    while True:
        opcode, length = struct.unpack_from("<BQ", data, pos)
        if opcode == 0x06:  # chunk: times, size, crc, compression string, data length
            (n,) = struct.unpack_from("<I", data, pos + 9 + 28)
            return int(pos + 9 + 32 + n + 8)
        pos += 9 + length


def one_message_mcap(path: Path, channels: list[tuple[str, str, str, int | None]]) -> Path:
    """A small MCAP: per channel (topic, message encoding, schema encoding, schema id or None
    for a schema of its own), one message."""
    from mcap.writer import CompressionType
    from mcap.writer import Writer as McapWriter

    with path.open("wb") as f:
        w = McapWriter(f, compression=CompressionType.NONE)
        w.start(profile="", library="test")
        for n, (topic, encoding, schema_encoding, given) in enumerate(channels):
            schema_id = given
            if schema_id is None:
                schema_id = w.register_schema("pkg/Thing", schema_encoding, b"int32 x\n")
            cid = w.register_channel(topic, encoding, schema_id)
            w.add_message(cid, 1000 + n, b"\x01\x00\x00\x00", 1000 + n)
        w.finish()  # type: ignore[no-untyped-call]
    return path


# --- Foxglove schemas in MCAP (issue 16) ------------------------------------------------------

FoxgloveEncoding = Literal["protobuf", "json"]
#: sensor_msgs/PointField datatype -> foxglove.PackedElementField.NumericType
_FOXGLOVE_NUMERIC = {1: 2, 2: 1, 3: 4, 4: 3, 5: 6, 6: 5, 7: 7, 8: 8}


def _fg_time(ns: int) -> dict[str, int]:
    sec, nsec = divmod(int(ns), 1_000_000_000)
    return {"sec": sec, "nsec": nsec}


def _fg_stamp(msg: Any) -> dict[str, int]:
    return {"sec": int(msg.header.stamp.sec), "nsec": int(msg.header.stamp.nanosec)}


def _fg_xyz(v: Any) -> dict[str, float]:
    return {"x": float(v.x), "y": float(v.y), "z": float(v.z)}


def _fg_quat(q: Any) -> dict[str, float]:
    return {"x": float(q.x), "y": float(q.y), "z": float(q.z), "w": float(q.w)}


def _fg_pose(p: Any) -> dict[str, Any]:
    return {"position": _fg_xyz(p.position), "orientation": _fg_quat(p.orientation)}


def ros_to_foxglove(msgtype: str, msg: Any, *, split_tf: bool = False) -> list[tuple[str, Any]]:
    """A deserialised ROS message as Foxglove messages ``(schema name, dict in Foxglove's JSON
    form, bytes as bytes)``: LaserScan (readings below ``range_min`` as NaN; Foxglove has no
    ``range_max``: read them with ``--max-range`` set to it, or readings at or beyond it are hits
    and +inf readings are dropped),
    PointCloud2 (fields of count 1; rows repacked),
    TFMessage (one FrameTransforms, or one FrameTransform each with ``split_tf``), Odometry
    (PoseInFrame: the child frame is lost), OccupancyGrid (Grid, one INT8 field
    ``occupancy``); [] for other types."""
    if msgtype == "sensor_msgs/msg/LaserScan":
        n = len(msg.ranges)
        start = float(msg.angle_min)
        return [
            (
                "foxglove.LaserScan",
                {
                    "timestamp": _fg_stamp(msg),
                    "frame_id": msg.header.frame_id,
                    "start_angle": start,
                    "end_angle": start + (n - 1) * float(msg.angle_increment),
                    # Foxglove has no range_min: what ROS drops as too close is NaN here.
                    "ranges": [float(r) if r >= msg.range_min else math.nan for r in msg.ranges],
                    "intensities": [float(r) for r in msg.intensities],
                },
            )
        ]
    if msgtype == "sensor_msgs/msg/PointCloud2":
        assert not msg.is_bigendian
        step, width, height = int(msg.point_step), int(msg.width), int(msg.height)
        flat = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
        rows = flat[: height * int(msg.row_step)].reshape(height, int(msg.row_step))
        data = np.ascontiguousarray(rows[:, : width * step]).tobytes()
        fields = [
            {"name": f.name, "offset": int(f.offset), "type": _FOXGLOVE_NUMERIC[int(f.datatype)]}
            for f in msg.fields
            if int(f.count) == 1
        ]
        return [
            (
                "foxglove.PointCloud",
                {
                    "timestamp": _fg_stamp(msg),
                    "frame_id": msg.header.frame_id,
                    "point_stride": step,
                    "fields": fields,
                    "data": data,
                },
            )
        ]
    if msgtype in ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage"):
        transforms = [
            {
                "timestamp": _fg_stamp(t),
                "parent_frame_id": t.header.frame_id,
                "child_frame_id": t.child_frame_id,
                "translation": _fg_xyz(t.transform.translation),
                "rotation": _fg_quat(t.transform.rotation),
            }
            for t in msg.transforms
        ]
        if split_tf:
            return [("foxglove.FrameTransform", t) for t in transforms]
        return [("foxglove.FrameTransforms", {"transforms": transforms})]
    if msgtype == "nav_msgs/msg/Odometry":
        return [
            (
                "foxglove.PoseInFrame",
                {
                    "timestamp": _fg_stamp(msg),
                    "frame_id": msg.header.frame_id,
                    "pose": _fg_pose(msg.pose.pose),
                },
            )
        ]
    if msgtype == "nav_msgs/msg/OccupancyGrid":
        info = msg.info
        res = float(info.resolution)
        return [
            (
                "foxglove.Grid",
                {
                    "timestamp": _fg_stamp(msg),
                    "frame_id": msg.header.frame_id,
                    "pose": _fg_pose(info.origin),
                    "column_count": int(info.width),
                    "cell_size": {"x": res, "y": res},
                    "row_stride": int(info.width),
                    "cell_stride": 1,
                    "fields": [{"name": "occupancy", "offset": 0, "type": 2}],
                    "data": np.asarray(msg.data, dtype=np.int8).tobytes(),
                },
            )
        ]
    return []


def _to_protobuf(pb: Any, value: dict[str, Any]) -> Any:
    """Fill a protobuf message from a dict in Foxglove's JSON form (times ``sec``/``nsec``)."""
    pb.SetInParent()
    for key, v in value.items():
        fd = pb.DESCRIPTOR.fields_by_name[key]
        repeated = getattr(fd, "is_repeated", None)
        repeated = fd.label == fd.LABEL_REPEATED if repeated is None else repeated
        if fd.message_type is None:
            if repeated:
                getattr(pb, key).extend(v)
            else:
                setattr(pb, key, v)
        elif fd.message_type.full_name == "google.protobuf.Timestamp":
            getattr(pb, key).seconds, getattr(pb, key).nanos = v["sec"], v["nsec"]
        elif repeated:
            for item in v:
                _to_protobuf(getattr(pb, key).add(), item)
        else:
            _to_protobuf(getattr(pb, key), v)
    return pb


def foxglove_message_bytes(name: str, value: dict[str, Any], encoding: FoxgloveEncoding) -> bytes:
    """One Foxglove message (dict in Foxglove's JSON form) serialised as protobuf or JSON."""
    if encoding == "json":
        return json.dumps(
            value, default=lambda b: base64.b64encode(bytes(b)).decode(), allow_nan=True
        ).encode()
    import importlib

    module = importlib.import_module(f"foxglove_schemas_protobuf.{name.split('.')[1]}_pb2")
    cls = getattr(module, name.split(".")[1])
    return bytes(_to_protobuf(cls(), value).SerializeToString())


def foxglove_schema(name: str, encoding: FoxgloveEncoding) -> tuple[str, bytes]:
    """``(schema encoding, schema bytes)`` of a Foxglove schema: the FileDescriptorSet of the
    generated class (as mcap-protobuf-support writes it), or a JSON schema (not validated by the
    reader: only its name matters)."""
    if encoding == "json":
        return "jsonschema", json.dumps({"title": name, "type": "object"}).encode()
    import importlib

    from mcap_protobuf.schema import build_file_descriptor_set

    module = importlib.import_module(f"foxglove_schemas_protobuf.{name.split('.')[1]}_pb2")
    fds = build_file_descriptor_set(getattr(module, name.split(".")[1]))
    return "protobuf", bytes(fds.SerializeToString())


def write_foxglove_mcap(
    out: Path,
    messages: Iterable[tuple[str, str, int, Any]],
    encoding: FoxgloveEncoding,
    *,
    compression: McapCompression = "zstd",
    summary: bool = True,
) -> Path:
    """Write ``(topic, schema name, log time ns, dict in Foxglove's JSON form)`` messages as an
    MCAP file of Foxglove schemas (profile ``""``), one channel per topic."""
    from mcap.writer import CompressionType, IndexType
    from mcap.writer import Writer as McapWriter

    kinds = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
    options: dict[str, Any] = {}
    if not summary:
        options = {
            "index_types": IndexType.NONE,
            "repeat_channels": False,
            "repeat_schemas": False,
            "use_statistics": False,
            "use_summary_offsets": False,
        }
    with out.open("wb") as f:
        writer = McapWriter(f, compression=kinds[compression], **options)
        writer.start(profile="", library="scan2terrain tests")
        schemas: dict[str, int] = {}
        channels: dict[str, int] = {}
        for seq, (topic, name, t_ns, value) in enumerate(messages):
            if name not in schemas:
                schema_encoding, data = foxglove_schema(name, encoding)
                schemas[name] = writer.register_schema(name, schema_encoding, data)
            if topic not in channels:
                channels[topic] = writer.register_channel(topic, encoding, schemas[name])
            raw = foxglove_message_bytes(name, value, encoding)
            writer.add_message(channels[topic], int(t_ns), raw, int(t_ns), seq)
        writer.finish()  # type: ignore[no-untyped-call]
    return out


def ros_bag_to_foxglove_mcap(
    bag: Path,
    out: Path,
    encoding: FoxgloveEncoding,
    *,
    compression: McapCompression = "zstd",
    summary: bool = True,
    split_tf: bool = False,
) -> Path:
    """Re-encode a ROS bag's scans, tf, odometry and maps as Foxglove schemas in MCAP (see
    :func:`ros_to_foxglove`; other topics are left out), in the bag's order and log times."""
    from rosbags.highlevel import AnyReader

    converted: list[tuple[str, str, int, Any]] = []
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        for conn, t_ns, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            for name, value in ros_to_foxglove(conn.msgtype, msg, split_tf=split_tf):
                converted.append((conn.topic, name, int(t_ns), value))
    return write_foxglove_mcap(out, converted, encoding, compression=compression, summary=summary)
