"""Foxglove's own schemas in MCAP (protobuf and JSON) -> the objects the ROS paths give.

For :mod:`scan2terrain.readers._mcap`: channels whose messages are ``protobuf`` (schema encoding
``protobuf``) or ``json`` (schema encoding ``jsonschema``), as the Foxglove SDKs and dataset
converters (nuScenes and others) write them. A message is parsed, then, for the schemas the
pipeline uses, turned into a small object shaped like the ROS message it stands for, so the
readers downstream (:mod:`~scan2terrain.readers.scans`, :mod:`~scan2terrain.readers.tf`,
:mod:`~scan2terrain.readers.tracks`) read it as they read a ROS one. Choices:

* **Parsing.** protobuf with protobuf's dynamic descriptor pool, built from the
  ``FileDescriptorSet`` the MCAP schema record carries (what the file holds, so no generated
  classes and no per-schema package are needed, and any protobuf schema parses); JSON with
  :func:`json.loads` (the JSON schema is not validated, only parsed once to check it is JSON).
  JSON follows Foxglove's JSON schemas: times ``{"sec", "nsec"}``, bytes as base64 strings,
  a quaternion's missing ``w`` is 1. A message that does not parse, or JSON that is not an
  object, raises; :class:`~scan2terrain.readers.bag.Bag` says so in one line naming the file.
  Other schemas (images, scene entities...) are decoded (protobuf message or dict) and left
  unused, as a ROS bag's image topics are.
* **What each schema becomes.**

  - ``foxglove.PointCloud`` -> :class:`PointCloud`: the packed ``fields`` (name, byte offset,
    numeric type, little-endian) read as a strided numpy structured array, as
    :mod:`~scan2terrain.readers.pointcloud2` reads a PointCloud2; ``len(data) // point_stride``
    points (as Foxglove Studio counts them); at least two of x, y, z (a missing one is 0, as
    Foxglove draws it); points with a non-finite coordinate dropped.
  - ``foxglove.LaserScan`` -> :class:`LaserScan`: reading i at ``start_angle + i * (end_angle -
    start_angle) / (n - 1)``. The schema has no ``range_min`` / ``range_max``, so **every finite
    positive range is a hit** and every other reading (0, negative, NaN, +-inf) is dropped: no
    beam only clears space unless a ``--max-range`` is given, which cuts beams as for a ROS
    LaserScan (readings at or beyond it only clear, up to it).
  - Both carry ``pose``, the scan's origin in its ``frame_id``: :meth:`PointCloud.points` and
    :meth:`LaserScan.points` give points in that scan origin's frame and :attr:`local_pose` the
    origin, which the scan reader composes with the frame's pose (so rays start at the scan's
    origin, not the frame's). No pose, or the identity, is ``None``: nothing is composed.
  - ``foxglove.FrameTransform`` / ``foxglove.FrameTransforms`` -> :class:`Transforms`, a
    ``tf2_msgs/TFMessage`` look-alike (``transforms`` of ``TransformStamped`` look-alikes:
    ``header.frame_id`` the parent, ``child_frame_id``, ``transform.translation/rotation``), fed
    to the tf buffer exactly as ``/tf`` is (``static`` when the topic name says so, as for ROS).
    A missing rotation is the identity; a zero quaternion is refused by the buffer as ROS ones are.
  - ``foxglove.PoseInFrame`` -> :class:`PoseInFrame`, a ``nav_msgs/Odometry`` look-alike (the
    pose of the robot base in ``frame_id``; no child frame: ``base_link``).
  - ``foxglove.Grid`` -> :class:`Grid`, a ``nav_msgs/OccupancyGrid`` look-alike: square cells
    (``cell_size.x == cell_size.y``), ``len(data) // row_stride`` rows of ``column_count`` cells,
    row 0 at the pose's origin (as nav_msgs). The occupancy is the field named ``occupancy``
    (else ``data``, else the only field that is not a colour channel): INT8 / UINT8 values as
    nav_msgs' (0-100 occupied probability, -1 / 255 unknown), FLOAT32 / FLOAT64 as a
    probability in [0, 1] (x 100, rounded; NaN unknown). Other layouts are refused when the map
    is read (an elevation grid is not an occupancy grid).
"""

from __future__ import annotations

import base64
import binascii
import json
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError
from scan2terrain.readers.laserscan import laserscan_points
from scan2terrain.types import Transform

POINT_CLOUD = "foxglove.PointCloud"
LASER_SCAN = "foxglove.LaserScan"
FRAME_TRANSFORM = "foxglove.FrameTransform"
FRAME_TRANSFORMS = "foxglove.FrameTransforms"
POSE_IN_FRAME = "foxglove.PoseInFrame"
GRID = "foxglove.Grid"
SCAN_TYPES = frozenset({POINT_CLOUD, LASER_SCAN})
TF_TYPES = frozenset({FRAME_TRANSFORM, FRAME_TRANSFORMS})
#: How each schema the pipeline reads is used (for ``inspect``).
USES = {
    POINT_CLOUD: "read as scans (points)",
    LASER_SCAN: "read as scans (laser)",
    FRAME_TRANSFORM: "read as tf",
    FRAME_TRANSFORMS: "read as tf",
    POSE_IN_FRAME: "read as odometry",
    GRID: "read as an occupancy grid",
}

#: foxglove.PackedElementField.NumericType -> numpy type (little-endian).
NUMERIC_TYPES: dict[int, str] = {
    1: "<u1",  # UINT8
    2: "<i1",  # INT8
    3: "<u2",  # UINT16
    4: "<i2",  # INT16
    5: "<u4",  # UINT32
    6: "<i4",  # INT32
    7: "<f4",  # FLOAT32
    8: "<f8",  # FLOAT64
}
_TYPE_NAMES = {1: "UINT8", 2: "INT8", 3: "UINT16", 4: "INT16", 5: "UINT32", 6: "INT32"}
_TYPE_NAMES |= {7: "FLOAT32", 8: "FLOAT64"}
_COLOURS = frozenset({"red", "green", "blue", "alpha"})
_NS = 1_000_000_000


# --- the ROS-shaped objects ---------------------------------------------------------------------


@dataclass(frozen=True)
class Time:
    sec: int
    nanosec: int


@dataclass(frozen=True)
class Header:
    stamp: Time
    frame_id: str


@dataclass(frozen=True)
class Vector3:
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0


@dataclass(frozen=True)
class Quaternion:
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    w: float = 1.0


@dataclass(frozen=True)
class Pose:
    position: Vector3 = field(default_factory=Vector3)
    orientation: Quaternion = field(default_factory=Quaternion)

    def transform(self) -> Transform | None:
        """The pose as a transform, None for the identity."""
        p, q = self.position, self.orientation
        if (p.x, p.y, p.z, q.x, q.y, q.z, q.w) == (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0):
            return None
        if not all(math.isfinite(v) for v in (p.x, p.y, p.z)):
            raise ValueError(f"pose position ({p.x}, {p.y}, {p.z}) is not finite")
        return Transform.from_quaternion((p.x, p.y, p.z), (q.x, q.y, q.z, q.w))


@dataclass(frozen=True)
class TfTransform:
    translation: Vector3
    rotation: Quaternion


@dataclass(frozen=True)
class TransformStamped:
    header: Header
    child_frame_id: str
    transform: TfTransform


@dataclass(frozen=True)
class Transforms:
    """``foxglove.FrameTransform(s)`` as a ``tf2_msgs/TFMessage``."""

    transforms: list[TransformStamped]


@dataclass(frozen=True)
class PoseWithCovariance:
    pose: Pose


@dataclass(frozen=True)
class PoseInFrame:
    """``foxglove.PoseInFrame`` as a ``nav_msgs/Odometry`` (no child frame)."""

    header: Header
    pose: PoseWithCovariance
    child_frame_id: str = ""


@dataclass(frozen=True)
class PackedField:
    name: str
    offset: int
    type: int


def _packed_dtype(fields: list[PackedField], stride: int, what: str) -> np.dtype[np.void]:
    names: list[str] = []
    formats: list[str] = []
    offsets: list[int] = []
    for f in fields:
        if f.type not in NUMERIC_TYPES:
            raise ValueError(f"{what} field {f.name!r} has an unknown numeric type {f.type}")
        size = int(NUMERIC_TYPES[f.type][2])
        if f.offset < 0 or f.offset + size > stride:
            raise ValueError(
                f"{what} field {f.name!r} (offset {f.offset}, {size} bytes) does not fit in its "
                f"stride of {stride} bytes"
            )
        if f.name in names:
            raise ValueError(f"{what} has two fields named {f.name!r}")
        names.append(f.name)
        formats.append(NUMERIC_TYPES[f.type])
        offsets.append(f.offset)
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": stride})


@dataclass(frozen=True)
class PointCloud:
    """``foxglove.PointCloud``: ``header``, the scan origin ``local_pose``, and its points."""

    header: Header
    local_pose: Transform | None
    point_stride: int
    fields: list[PackedField]
    data: bytes

    def points(self, max_range: float = -1.0) -> tuple[NDArray[np.float64], float]:
        """The finite points (float64 (N, 3), in the cloud's origin frame, in data order) and
        the max range to insert them with (``max_range`` as given: clouds have none).

        Raises
        ------
        InputError
            (naming no file) Fewer than two coordinate fields, a field that does not fit or has
            an unknown type, two fields of one name.
        """
        try:
            return self._points(max_range)
        except ValueError as exc:
            raise InputError(None, str(exc)) from None

    def _points(self, max_range: float) -> tuple[NDArray[np.float64], float]:
        stride = self.point_stride
        axes = [f for f in self.fields if f.name in ("x", "y", "z")]
        if sum(1 for a in ("x", "y", "z") if any(f.name == a for f in axes)) < 2:
            raise ValueError(
                "PointCloud needs at least two of the fields x, y, z; it has "
                + (", ".join(f.name for f in self.fields) or "none")
            )
        if stride <= 0:
            if not self.data:
                return np.zeros((0, 3)), max_range
            raise ValueError(f"PointCloud point_stride is {stride}")
        records = np.frombuffer(
            self.data,
            dtype=_packed_dtype(axes, stride, "PointCloud"),
            count=len(self.data) // stride,
        )
        xyz = np.zeros((records.size, 3))
        with np.errstate(invalid="ignore"):  # a signalling NaN, dropped below
            for axis, name in enumerate(("x", "y", "z")):
                if name in records.dtype.names:  # type: ignore[operator]
                    xyz[:, axis] = records[name]
        with np.errstate(over="ignore", invalid="ignore"):
            total = xyz.sum()
        if not np.isfinite(total):
            finite = np.isfinite(xyz)
            xyz = np.compress(finite[:, 0] & finite[:, 1] & finite[:, 2], xyz, axis=0)
        return xyz, max_range


@dataclass(frozen=True)
class LaserScan:
    """``foxglove.LaserScan``: ``header``, the scan origin ``local_pose``, and its readings."""

    header: Header
    local_pose: Transform | None
    start_angle: float
    end_angle: float
    ranges: NDArray[np.float64]

    def points(self, max_range: float = -1.0) -> tuple[NDArray[np.float64], float]:
        """Points in the scan origin's frame (z = 0) and the max range to insert them with:
        every finite positive reading is a hit (-1: no cut), or, with ``max_range`` > 0,
        readings at or beyond it only clear, as :func:`laserscan_points` cuts a ROS scan."""
        r = self.ranges
        n = r.size
        if not (math.isfinite(self.start_angle) and math.isfinite(self.end_angle)):
            raise InputError(
                None,
                f"LaserScan angles must be finite (start {self.start_angle}, end {self.end_angle})",
            )
        increment = (self.end_angle - self.start_angle) / (n - 1) if n > 1 else 0.0
        with np.errstate(invalid="ignore"):
            usable = np.isfinite(r) & (r > 0)
        cleaned = np.where(usable, r, np.nan)
        cut = max_range > 0
        # Without a cut, a range_max beyond every reading (all are hits; capped to stay finite).
        top = float(r[usable].max()) if usable.any() else 0.0
        limit = max_range if cut else min(top * 2 + 1, np.finfo(np.float64).max)
        scan = SimpleNamespace(
            ranges=cleaned,
            angle_min=self.start_angle,
            angle_increment=increment,
            range_min=0.0,
            range_max=limit,
        )
        pts, cutoff = laserscan_points(scan)
        return pts, (cutoff if cut else -1.0)


@dataclass(frozen=True)
class GridInfo:
    width: int
    height: int
    resolution: float
    origin: Pose


@dataclass(frozen=True)
class Grid:
    """``foxglove.Grid`` as a ``nav_msgs/OccupancyGrid``: ``header``, ``info``, and ``data``
    (int8, row-major, row 0 at the origin), decoded from its field when first read."""

    header: Header
    info: GridInfo
    cell_size: tuple[float, float]
    row_stride: int
    cell_stride: int
    fields: list[PackedField]
    raw: bytes = field(repr=False)

    @property
    def data(self) -> NDArray[np.int8]:
        """Occupancy values as nav_msgs has them (see the module docstring).

        Raises
        ------
        ValueError
            Cells that are not square, a layout that does not fit, or no occupancy field.
        """
        sx, sy = self.cell_size
        if sx != sy:
            raise ValueError(f"Grid cells are {sx} x {sy} m; only square cells are read")
        chosen = self._occupancy_field()
        w, h = self.info.width, self.info.height
        if w <= 0 or self.row_stride <= 0 or self.cell_stride <= 0:
            raise ValueError(
                f"Grid of {w} columns, row_stride {self.row_stride}, cell_stride {self.cell_stride}"
            )
        if self.cell_stride * w > self.row_stride:
            raise ValueError(
                f"Grid rows of {w} cells of {self.cell_stride} bytes do not fit in "
                f"row_stride {self.row_stride}"
            )
        dtype = _packed_dtype([chosen], self.cell_stride, "Grid")
        cells = np.ndarray(  # a strided view of the bytes: rows row_stride apart
            shape=(h, w), dtype=dtype, buffer=self.raw, strides=(self.row_stride, self.cell_stride)
        )
        values = cells[chosen.name]
        kind = np.dtype(NUMERIC_TYPES[chosen.type])
        if kind.kind == "f":
            with np.errstate(invalid="ignore"):
                p = values.astype(np.float64)
                if np.any(np.isfinite(p) & ((p < 0) | (p > 1))):
                    raise ValueError(
                        f"Grid field {chosen.name!r} ({_TYPE_NAMES[chosen.type]}) holds values "
                        "outside [0, 1]; float cells are read as occupancy probabilities"
                    )
                return np.where(np.isfinite(p), np.rint(p * 100), -1).astype(np.int8)
        if kind.itemsize != 1:
            raise ValueError(
                f"Grid field {chosen.name!r} is {_TYPE_NAMES[chosen.type]}; occupancy is read "
                "from INT8, UINT8, FLOAT32 or FLOAT64 cells"
            )
        out: NDArray[np.int8] = np.array(values).view(np.int8)  # a copy: 255 -> -1
        return out

    def _occupancy_field(self) -> PackedField:
        by_name = {f.name: f for f in self.fields}
        for name in ("occupancy", "data"):
            if name in by_name:
                return by_name[name]
        others = [f for f in self.fields if f.name not in _COLOURS]
        if len(others) == 1:
            return others[0]
        listed = ", ".join(f.name for f in self.fields) or "none"
        raise ValueError(
            f"Grid has no occupancy field (named 'occupancy', 'data', or its only non-colour "
            f"field); its fields: {listed}"
        )


# --- reading protobuf and JSON messages alike ---------------------------------------------------


class _Fields:
    """A parsed message's fields, protobuf or JSON: ``sub`` a nested message or None when it is
    absent, ``get`` a scalar or its default."""

    def __init__(self, msg: Any, what: str) -> None:
        self.msg = msg
        self.what = what
        self.json = isinstance(msg, dict)

    def sub(self, name: str) -> _Fields | None:
        if self.json:
            value = self.msg.get(name)
            if value is None:
                return None
            if not isinstance(value, dict):
                raise ValueError(f"{self.what}.{name} is not an object")
            return _Fields(value, f"{self.what}.{name}")
        if not self.msg.HasField(name):
            return None
        return _Fields(getattr(self.msg, name), f"{self.what}.{name}")

    def items(self, name: str) -> list[_Fields]:
        values = (self.msg.get(name) or []) if self.json else getattr(self.msg, name)
        if not isinstance(values, Iterable) or isinstance(values, (str, dict)):
            raise ValueError(f"{self.what}.{name} is not a list")
        out = []
        for i, v in enumerate(values):
            if self.json and not isinstance(v, dict):
                raise ValueError(f"{self.what}.{name}[{i}] is not an object")
            out.append(_Fields(v, f"{self.what}.{name}[{i}]"))
        return out

    def number(self, name: str, default: float = 0.0) -> float:
        value = self.msg.get(name, default) if self.json else getattr(self.msg, name)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"{self.what}.{name} is not a number")
        return float(value)

    def integer(self, name: str) -> int:
        value = self.msg.get(name, 0) if self.json else getattr(self.msg, name)
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{self.what}.{name} is not an integer")
        return value

    def text(self, name: str) -> str:
        value = self.msg.get(name, "") if self.json else getattr(self.msg, name)
        if not isinstance(value, str):
            raise ValueError(f"{self.what}.{name} is not a string")
        return value

    def blob(self, name: str) -> bytes:
        if not self.json:
            return bytes(getattr(self.msg, name))
        value = self.msg.get(name, "")
        if not isinstance(value, str):
            raise ValueError(f"{self.what}.{name} is not a base64 string")
        try:
            return base64.b64decode(value, validate=True)
        except binascii.Error as exc:
            raise ValueError(f"{self.what}.{name} is not valid base64 ({exc})") from None

    def floats(self, name: str) -> NDArray[np.float64]:
        if not self.json:
            return np.asarray(getattr(self.msg, name), dtype=np.float64)
        values = self.msg.get(name) or []
        if not isinstance(values, list) or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in values
        ):
            raise ValueError(f"{self.what}.{name} is not a list of numbers")
        return np.asarray(values, dtype=np.float64)


def _time(m: _Fields) -> Time:
    t = m.sub("timestamp")
    if t is None:
        return Time(0, 0)
    sec, nsec = (
        (t.integer("sec"), t.integer("nsec"))
        if m.json
        else (
            t.integer("seconds"),
            t.integer("nanos"),
        )
    )
    if sec < 0 or not 0 <= nsec < _NS:
        raise ValueError(f"{m.what}.timestamp ({sec} s, {nsec} ns) is not a time")
    return Time(sec, nsec)


def _header(m: _Fields, frame: str = "frame_id") -> Header:
    return Header(_time(m), m.text(frame))


def _vector(m: _Fields | None) -> Vector3:
    if m is None:
        return Vector3()
    return Vector3(m.number("x"), m.number("y"), m.number("z"))


def _quaternion(m: _Fields | None) -> Quaternion:
    if m is None:
        return Quaternion()
    return Quaternion(m.number("x"), m.number("y"), m.number("z"), m.number("w", 1.0))


def _pose(m: _Fields | None) -> Pose:
    if m is None:
        return Pose()
    return Pose(_vector(m.sub("position")), _quaternion(m.sub("orientation")))


def _fields(m: _Fields) -> list[PackedField]:
    return [
        PackedField(f.text("name"), f.integer("offset"), f.integer("type"))
        for f in m.items("fields")
    ]


def _point_cloud(m: _Fields) -> PointCloud:
    return PointCloud(
        _header(m),
        _pose(m.sub("pose")).transform(),
        m.integer("point_stride"),
        _fields(m),
        m.blob("data"),
    )


def _laser_scan(m: _Fields) -> LaserScan:
    return LaserScan(
        _header(m),
        _pose(m.sub("pose")).transform(),
        m.number("start_angle"),
        m.number("end_angle"),
        m.floats("ranges"),
    )


def _frame_transform(m: _Fields) -> TransformStamped:
    return TransformStamped(
        _header(m, "parent_frame_id"),
        m.text("child_frame_id"),
        TfTransform(_vector(m.sub("translation")), _quaternion(m.sub("rotation"))),
    )


def _grid(m: _Fields) -> Grid:
    cell = m.sub("cell_size")
    sx, sy = (cell.number("x"), cell.number("y")) if cell is not None else (0.0, 0.0)
    w, row_stride = m.integer("column_count"), m.integer("row_stride")
    raw = m.blob("data")
    h = len(raw) // row_stride if row_stride > 0 else 0
    return Grid(
        _header(m),
        GridInfo(w, h, sx, _pose(m.sub("pose"))),
        (sx, sy),
        row_stride,
        m.integer("cell_stride"),
        _fields(m),
        raw,
    )


#: Schema name -> the ROS-shaped object of a parsed message.
ADAPTERS: dict[str, Callable[[_Fields], object]] = {
    POINT_CLOUD: _point_cloud,
    LASER_SCAN: _laser_scan,
    FRAME_TRANSFORM: lambda m: Transforms([_frame_transform(m)]),
    FRAME_TRANSFORMS: lambda m: Transforms([_frame_transform(t) for t in m.items("transforms")]),
    POSE_IN_FRAME: lambda m: PoseInFrame(_header(m), PoseWithCovariance(_pose(m.sub("pose")))),
    GRID: _grid,
}


def _adapted(name: str, parse: Callable[[bytes], Any]) -> Callable[[bytes | memoryview], object]:
    adapt = ADAPTERS.get(name)

    def decode(raw: bytes | memoryview) -> object:
        msg = parse(bytes(raw))
        return msg if adapt is None else adapt(_Fields(msg, name))

    return decode


def protobuf_decoder(name: str, schema: bytes) -> Callable[[bytes | memoryview], object]:
    """Messages of the protobuf type ``name``, described by ``schema`` (a serialised
    ``FileDescriptorSet``), decoded (and adapted when the pipeline reads the type).

    Raises
    ------
    ValueError
        The descriptor set cannot be read, or does not define ``name``.
    """
    from google.protobuf import (  # type: ignore[import-untyped, unused-ignore]
        descriptor_pb2,
        descriptor_pool,
        message_factory,
    )
    from google.protobuf.message import DecodeError  # type: ignore[import-untyped, unused-ignore]

    try:
        files = descriptor_pb2.FileDescriptorSet.FromString(schema).file
    except DecodeError as exc:
        raise ValueError(f"its FileDescriptorSet cannot be parsed ({exc})") from None
    pool = descriptor_pool.DescriptorPool()
    pending = {f.name: f for f in files}
    added: set[str] = set()
    while pending:  # dependencies first, whatever order the set lists them in
        ready = [f for f in pending.values() if all(d in added for d in f.dependency)]
        if not ready:
            missing = sorted(
                {d for f in pending.values() for d in f.dependency} - added - set(pending)
            )
            raise ValueError(
                f"its FileDescriptorSet lacks {', '.join(missing) or 'a file'} (circular?)"
            )
        for f in ready:
            try:
                pool.Add(f)
            except Exception as exc:  # protobuf's TypeError / KeyError on a bad descriptor
                raise ValueError(f"its descriptor {f.name} cannot be used ({exc})") from None
            added.add(f.name)
            del pending[f.name]
    try:
        cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(name))
    except KeyError:
        raise ValueError(f"its FileDescriptorSet does not define {name}") from None
    return _adapted(name, cls.FromString)


def _json_object(raw: bytes) -> dict[str, Any]:
    value = json.loads(raw)
    if not isinstance(value, dict):
        raise ValueError(f"a JSON message is an object, not {type(value).__name__}")
    return value


def json_decoder(name: str, schema: bytes) -> Callable[[bytes | memoryview], object]:
    """Messages of the JSON schema ``name`` (``schema`` is checked to be JSON, not applied).

    Raises
    ------
    ValueError
        The schema is not JSON.
    """
    if schema:
        try:
            json.loads(schema)
        except ValueError as exc:
            raise ValueError(f"its JSON schema is not JSON ({exc})") from None
    return _adapted(name, _json_object)
