"""Foxglove messages in protobuf or JSON -> the ROS-shaped objects of
:mod:`scan2terrain.readers.foxglove`: one decoder per channel, made from the file's own schema
(protobuf from its FileDescriptorSet, JSON with ``json.loads``)."""

from __future__ import annotations

import base64
import binascii
import json
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import shown
from scan2terrain.readers.foxglove import (
    FRAME_TRANSFORM,
    FRAME_TRANSFORMS,
    GRID,
    LASER_SCAN,
    NS,
    POINT_CLOUD,
    POSE_IN_FRAME,
    Grid,
    GridInfo,
    Header,
    LaserScan,
    PackedField,
    PointCloud,
    Pose,
    PoseInFrame,
    PoseWithCovariance,
    Quaternion,
    TfTransform,
    Time,
    Transforms,
    TransformStamped,
    Vector3,
)

# --- reading protobuf and JSON messages alike ---------------------------------------------------


class _Fields:
    """A parsed JSON message's fields, checked as they are read: ``sub`` a nested message or
    None when it is absent, ``get`` a scalar or its default. :class:`_ProtoFields` reads a
    protobuf message the same way (its types are already checked by protobuf)."""

    json = True

    def __init__(self, msg: Any, what: str | Callable[[], str]) -> None:
        self.msg = msg
        self._what = what

    @property
    def what(self) -> str:
        """The field's name in the message, for errors (built when first asked for)."""
        return self._what if isinstance(self._what, str) else self._what()

    def sub(self, name: str) -> _Fields | None:
        value = self.msg.get(name)
        if value is None:
            return None
        if not isinstance(value, dict):
            raise ValueError(f"{self.what}.{name} is not an object")
        return _Fields(value, f"{self.what}.{name}")

    def items(self, name: str) -> list[_Fields]:
        values = self.msg.get(name) or []
        if not isinstance(values, list):
            raise ValueError(f"{self.what}.{name} is not a list")
        out = []
        for i, v in enumerate(values):
            if not isinstance(v, dict):
                raise ValueError(f"{self.what}.{name}[{i}] is not an object")
            out.append(_Fields(v, f"{self.what}.{name}[{i}]"))
        return out

    def number(self, name: str, default: float = 0.0) -> float:
        value = self.msg.get(name, default)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"{self.what}.{name} is not a number")
        return float(value)

    def integer(self, name: str) -> int:
        value = self.msg.get(name, 0)
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{self.what}.{name} is not an integer")
        return value

    def text(self, name: str) -> str:
        value = self.msg.get(name, "")
        if not isinstance(value, str):
            raise ValueError(f"{self.what}.{name} is not a string")
        return value

    def blob(self, name: str) -> bytes:
        value = self.msg.get(name, "")
        if not isinstance(value, str):
            raise ValueError(f"{self.what}.{name} is not a base64 string")
        try:
            return base64.b64decode(value, validate=True)
        except binascii.Error as exc:
            raise ValueError(f"{self.what}.{name} is not valid base64 ({exc})") from None

    def floats(self, name: str) -> NDArray[np.float64]:
        values = self.msg.get(name) or []
        if not isinstance(values, list) or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in values
        ):
            raise ValueError(f"{self.what}.{name} is not a list of numbers")
        return np.asarray(values, dtype=np.float64)


class _ProtoFields(_Fields):
    """A parsed protobuf message's fields, read as :class:`_Fields` reads JSON: protobuf has
    checked their types, so nothing is checked again (the message name is only built for an
    error)."""

    json = False

    def sub(self, name: str) -> _Fields | None:
        if not self.msg.HasField(name):
            return None
        return _ProtoFields(getattr(self.msg, name), lambda: f"{self.what}.{name}")

    def items(self, name: str) -> list[_Fields]:
        return [
            _ProtoFields(v, lambda i=i: f"{self.what}.{name}[{i}]")  # type: ignore[misc]
            for i, v in enumerate(getattr(self.msg, name))
        ]

    def number(self, name: str, default: float = 0.0) -> float:
        return float(getattr(self.msg, name))

    def integer(self, name: str) -> int:
        value: int = getattr(self.msg, name)
        return value

    def text(self, name: str) -> str:
        value: str = getattr(self.msg, name)
        return value

    def blob(self, name: str) -> bytes:
        return bytes(getattr(self.msg, name))

    def floats(self, name: str) -> NDArray[np.float64]:
        return np.asarray(getattr(self.msg, name), dtype=np.float64)


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
    if sec < 0 or not 0 <= nsec < NS:
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


def _proto_time(ts: Any, what: Callable[[], str]) -> Time:
    sec, nsec = ts.seconds, ts.nanos
    if sec < 0 or not 0 <= nsec < NS:
        raise ValueError(f"{what()}.timestamp ({sec} s, {nsec} ns) is not a time")
    return Time(sec, nsec)


def _proto_point_cloud(m: _Fields) -> PointCloud:
    """A protobuf ``foxglove.PointCloud`` as :func:`_point_cloud` reads it, without the field
    wrappers (a cloud message per scan)."""
    msg = m.msg
    return PointCloud(
        Header(_proto_time(msg.timestamp, lambda: POINT_CLOUD), msg.frame_id),
        _pose(m.sub("pose")).transform(),
        msg.point_stride,
        [PackedField(f.name, f.offset, f.type) for f in msg.fields],
        msg.data,
    )


def _proto_transform(t: Any, index: int | None = None) -> TransformStamped:
    """A protobuf ``foxglove.FrameTransform`` as :func:`_frame_transform` reads it, without the
    field wrappers: transforms are most of a recording's messages. An absent timestamp or
    translation reads as zeros and an absent rotation as the identity, as there."""
    stamp = _proto_time(
        t.timestamp,
        lambda: FRAME_TRANSFORM if index is None else f"{FRAME_TRANSFORMS}.transforms[{index}]",
    )
    v = t.translation
    q = Quaternion()
    if t.HasField("rotation"):
        r = t.rotation
        q = Quaternion(float(r.x), float(r.y), float(r.z), float(r.w))
    return TransformStamped(
        Header(stamp, t.parent_frame_id),
        t.child_frame_id,
        TfTransform(Vector3(float(v.x), float(v.y), float(v.z)), q),
    )


#: :data:`ADAPTERS` for protobuf messages: the transforms read directly.
PROTO_ADAPTERS: dict[str, Callable[[_Fields], object]] = {
    **ADAPTERS,
    POINT_CLOUD: _proto_point_cloud,
    FRAME_TRANSFORM: lambda m: Transforms([_proto_transform(m.msg)]),
    FRAME_TRANSFORMS: lambda m: Transforms(
        [_proto_transform(t, i) for i, t in enumerate(m.msg.transforms)]
    ),
}


def _adapted(
    name: str, parse: Callable[[bytes | memoryview], Any], fields: type[_Fields]
) -> Callable[[bytes | memoryview], object]:
    adapt = (PROTO_ADAPTERS if fields is _ProtoFields else ADAPTERS).get(name)

    def decode(raw: bytes | memoryview) -> object:
        msg = parse(raw)
        return msg if adapt is None else adapt(fields(msg, name))

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
    for f in files:  # proto2 strings are not checked: upb gives invalid UTF-8 as bytes
        if not all(isinstance(n, str) for n in (f.name, *f.dependency)):
            raise ValueError("its FileDescriptorSet names a file in bytes that are not UTF-8")
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
                f"its FileDescriptorSet lacks {shown(', '.join(missing)) or 'a file'} (circular?)"
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
    return _adapted(name, cls.FromString, _ProtoFields)  # parses a memoryview as it is


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
    return _adapted(name, lambda raw: _json_object(bytes(raw)), _Fields)
