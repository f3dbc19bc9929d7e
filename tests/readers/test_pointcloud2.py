"""sensor_msgs/PointCloud2 -> numpy, checked against a per-point struct encoder/decoder."""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from scan2terrain.errors import InputError
from scan2terrain.readers.pointcloud2 import pointcloud2_fields, pointcloud2_xyz
from tests.bagmaker import ros_msg

#: PointField datatype -> (struct code, numpy type, a value range that type holds).
TYPES: dict[int, tuple[str, str, tuple[float, float]]] = {
    1: ("b", "i1", (-128, 127)),
    2: ("B", "u1", (0, 255)),
    3: ("h", "i2", (-32768, 32767)),
    4: ("H", "u2", (0, 65535)),
    # Coordinates are metres: within MAX_COORDINATE_M (1e9), all four bytes still in use.
    5: ("i", "i4", (-(10**9), 10**9)),
    6: ("I", "u4", (0, 10**9)),
    7: ("f", "f4", (-1e4, 1e4)),
    8: ("d", "f8", (-5e6, 5e6)),
}


@dataclass
class F:
    """One field to encode: name, datatype, count, offset, and its values (points, count)."""

    name: str
    datatype: int
    offset: int
    values: np.ndarray
    count: int = 1


@dataclass
class Msg:
    """A plain stand-in with PointCloud2's attributes."""

    height: int
    width: int
    fields: list[Any]
    is_bigendian: bool
    point_step: int
    row_step: int
    data: Any
    is_dense: bool = False
    header: Any = field(default_factory=lambda: SimpleNamespace(frame_id="lidar"))


def encode(
    fields: list[F],
    *,
    height: int,
    width: int,
    point_step: int,
    row_pad: int = 0,
    bigendian: bool = False,
    order: list[int] | None = None,
) -> Msg:
    """Pack point by point with struct; unused record bytes are 0xAB, row padding 0xFF (a NaN if
    read as a float, so reading it by mistake shows)."""
    endian = ">" if bigendian else "<"
    rows = []
    for r in range(height):
        row = bytearray()
        for c in range(width):
            record = bytearray(b"\xab" * point_step)
            for f in fields:
                code = TYPES[f.datatype][0] * f.count
                vals = np.atleast_1d(f.values[r * width + c]).tolist()
                struct.pack_into(endian + code, record, f.offset, *vals)
            row += record
        rows.append(bytes(row) + b"\xff" * row_pad)
    infos = [
        SimpleNamespace(name=f.name, offset=f.offset, datatype=f.datatype, count=f.count)
        for f in fields
    ]
    if order is not None:
        infos = [infos[i] for i in order]
    return Msg(
        height=height,
        width=width,
        fields=infos,
        is_bigendian=bigendian,
        point_step=point_step,
        row_step=width * point_step + row_pad,
        data=np.frombuffer(b"".join(rows), dtype=np.uint8),
    )


def reference_xyz(msg: Msg) -> np.ndarray:
    """Per point, per field struct.unpack_from: slow and obvious."""
    endian = ">" if msg.is_bigendian else "<"
    by_name = {f.name: f for f in msg.fields}
    raw = bytes(msg.data)
    out = []
    for r in range(msg.height):
        for c in range(msg.width):
            base = r * msg.row_step + c * msg.point_step
            p = [
                struct.unpack_from(
                    endian + TYPES[by_name[a].datatype][0], raw, base + by_name[a].offset
                )[0]
                for a in "xyz"
            ]
            if all(np.isfinite(p)):
                out.append(p)
    return np.array(out, dtype=np.float64).reshape(-1, 3)


def values(datatype: int, n: int, count: int = 1, seed: int = 0) -> np.ndarray:
    lo, hi = TYPES[datatype][2]
    rng = np.random.default_rng(seed)
    if TYPES[datatype][1][0] == "f":
        v = rng.uniform(lo, hi, (n, count)).astype(TYPES[datatype][1])
    else:
        v = rng.integers(int(lo), int(hi), (n, count), endpoint=True).astype(TYPES[datatype][1])
    return v if count > 1 else v[:, 0].copy()


def xyz_fields(datatype: int, n: int, start: int = 0, seed: int = 0) -> list[F]:
    size = int(TYPES[datatype][1][1])
    return [
        F(a, datatype, start + i * size, values(datatype, n, seed=seed + i))
        for i, a in enumerate("xyz")
    ]


@pytest.mark.parametrize("datatype", sorted(TYPES))
@pytest.mark.parametrize("bigendian", [False, True])
def test_every_datatype_and_byte_order(datatype: int, bigendian: bool) -> None:
    fields = xyz_fields(datatype, 12)
    size = int(TYPES[datatype][1][1])
    msg = encode(fields, height=1, width=12, point_step=3 * size + 5, bigendian=bigendian)
    got = pointcloud2_xyz(msg)
    expected = np.stack([f.values.astype(np.float64) for f in fields], axis=1)
    assert got.dtype == np.float64 and got.shape == (12, 3)
    np.testing.assert_array_equal(got, expected)
    np.testing.assert_array_equal(got, reference_xyz(msg))


def test_extra_fields_in_odd_order_and_counts() -> None:
    n = 10
    fields = [
        F("normal", 7, 0, values(7, n, count=3, seed=9), count=3),  # 12 bytes before x
        F("ring", 4, 12, values(4, n, seed=5)),
        F("z", 8, 16, values(8, n, seed=2)),
        F("x", 7, 24, values(7, n, seed=0)),
        F("intensity", 2, 28, values(2, n, seed=4)),
        F("y", 5, 32, values(5, n, seed=1)),
        F("rgb", 7, 36, values(7, n, seed=6)),
    ]
    msg = encode(fields, height=2, width=5, point_step=48, order=[6, 4, 1, 3, 2, 5, 0])
    got = pointcloud2_xyz(msg)
    np.testing.assert_array_equal(got, reference_xyz(msg))
    np.testing.assert_array_equal(got[:, 2], fields[2].values)
    extra = pointcloud2_fields(msg, ["normal", "ring", "intensity"])
    assert extra["normal"].shape == (n, 3) and extra["normal"].dtype == np.float32
    np.testing.assert_array_equal(extra["normal"], fields[0].values)
    np.testing.assert_array_equal(extra["ring"], fields[1].values)
    assert extra["ring"].dtype == np.uint16
    np.testing.assert_array_equal(extra["intensity"], fields[4].values)


def test_big_endian_extra_fields_come_back_in_native_order() -> None:
    fields = [*xyz_fields(7, 6), F("ring", 4, 12, values(4, 6, seed=7))]
    msg = encode(fields, height=1, width=6, point_step=16, bigendian=True)
    ring = pointcloud2_fields(msg, ["ring"])["ring"]
    assert ring.dtype == np.dtype("=u2")
    np.testing.assert_array_equal(ring, fields[3].values)


def test_row_padding_is_skipped() -> None:
    fields = xyz_fields(7, 12)
    msg = encode(fields, height=3, width=4, point_step=16, row_pad=7)
    assert msg.row_step == 71
    got = pointcloud2_xyz(msg)
    assert got.shape == (12, 3)  # padding read as points would give NaNs, dropped -> fewer
    np.testing.assert_array_equal(got, reference_xyz(msg))
    np.testing.assert_array_equal(got, np.stack([f.values for f in fields], axis=1))


def test_last_row_may_omit_its_padding() -> None:
    full = encode(xyz_fields(7, 6), height=2, width=3, point_step=12, row_pad=4)
    msg = encode(xyz_fields(7, 6), height=2, width=3, point_step=12, row_pad=4)
    msg.data = msg.data[:-4]
    got = pointcloud2_xyz(msg)
    assert got.shape == (6, 3)
    np.testing.assert_array_equal(got, reference_xyz(full))
    msg.data = msg.data[:-1]  # one byte of the last point missing
    with pytest.raises(InputError, match=r"holds 75 bytes.*need 76"):
        pointcloud2_xyz(msg)


def test_organized_cloud_drops_non_finite_rows_in_row_major_order() -> None:
    h, w = 4, 5
    fields = xyz_fields(7, h * w)
    fields[0].values[[1, 7]] = np.nan
    fields[2].values[[7, 12]] = np.nan
    fields[1].values[19] = np.inf
    fields[2].values[0] = -np.inf
    msg = encode(fields, height=h, width=w, point_step=12, row_pad=4)
    got = pointcloud2_xyz(msg)
    keep = np.setdiff1d(np.arange(h * w), [0, 1, 7, 12, 19])
    assert got.shape == (15, 3)
    np.testing.assert_array_equal(got, np.stack([f.values[keep] for f in fields], axis=1))
    x = pointcloud2_fields(msg, ["x"])["x"]  # aligned with the kept points
    np.testing.assert_array_equal(x, got[:, 0].astype(np.float32))


def test_bytes_data_and_zero_row_step_for_one_row() -> None:
    msg = encode(xyz_fields(8, 3), height=1, width=3, point_step=24)
    expected = pointcloud2_xyz(msg)
    msg.data, msg.row_step = bytes(msg.data), 0
    np.testing.assert_array_equal(pointcloud2_xyz(msg), expected)


def test_empty_cloud() -> None:
    msg = encode(xyz_fields(7, 0), height=1, width=0, point_step=12)
    assert pointcloud2_xyz(msg).shape == (0, 3)
    assert pointcloud2_xyz(Msg(0, 0, [], False, 0, 0, np.zeros(0, np.uint8))).shape == (0, 3)
    msg.fields.append(SimpleNamespace(name="i", offset=0, datatype=7, count=1))
    assert pointcloud2_fields(msg, ["i"])["i"].shape == (0,)


def test_all_points_non_finite() -> None:
    fields = xyz_fields(7, 4)
    fields[0].values[:] = np.nan
    assert pointcloud2_xyz(encode(fields, height=2, width=2, point_step=12)).shape == (0, 3)


def test_points_beyond_the_physical_world_are_refused() -> None:
    # Their sum overflows to inf, so the quick all-finite check fails; the point with +inf and
    # -inf is a no-return and goes, the finite 1.5e308 m ones make no sense (issue 28): the
    # first is named, with its axis and value (and no overflow warning escapes).
    fields = xyz_fields(8, 4)
    fields[0].values[:] = 1.5e308
    fields[1].values[2] = np.inf
    fields[2].values[2] = -np.inf
    msg = encode(fields, height=2, width=2, point_step=24)
    with pytest.raises(InputError, match=r"PointCloud2 point 0: x = 1\.5e\+308 m makes no sense"):
        pointcloud2_xyz(msg)
    fields[0].values[:] = 1e9  # at the limit: read
    got = pointcloud2_xyz(encode(fields, height=2, width=2, point_step=24))
    assert got.shape == (3, 3) and got[:, 0].max() == 1e9


def good() -> Msg:
    return encode(xyz_fields(7, 4), height=2, width=2, point_step=12)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda m: m.fields.pop(2), "no field z"),
        (lambda m: setattr(m, "fields", []), "no field x, y, z .*none"),
        (lambda m: setattr(m, "data", m.data[:-1]), "holds 47 bytes.*need 48"),
        (lambda m: setattr(m, "point_step", 10), "'z' .*does not fit in point_step 10"),
        (lambda m: setattr(m.fields[1], "datatype", 9), "'y' has unknown datatype 9"),
        (lambda m: setattr(m.fields[1], "datatype", 0), "unknown datatype 0"),
        (lambda m: setattr(m, "row_step", 20), "row_step 20 is shorter than a row"),
        (lambda m: setattr(m.fields[0], "count", 3), "'x' has count 3"),
        (
            lambda m: m.fields.append(SimpleNamespace(name="x", offset=0, datatype=7, count=1)),
            "two fields named 'x'",
        ),
        (lambda m: setattr(m.fields[2], "offset", -4), "'z'.*does not fit"),
    ],
)
def test_bad_messages(change: Any, message: str) -> None:
    msg = good()
    change(msg)
    with pytest.raises(InputError, match=message) as info:
        pointcloud2_xyz(msg)
    assert info.value.path is None


def test_missing_named_field() -> None:
    with pytest.raises(InputError, match="no field ring"):
        pointcloud2_fields(good(), ["ring"])


def test_count_zero_means_one() -> None:
    msg = good()
    for f in msg.fields:
        f.count = 0
    np.testing.assert_array_equal(pointcloud2_xyz(msg), reference_xyz(good()))


def test_real_rosbags_message_round_trip() -> None:
    """A PointCloud2 as rosbags builds, serialises and deserialises it (data is a uint8 view)."""
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    pc2, pf = ts.types["sensor_msgs/msg/PointCloud2"], ts.types["sensor_msgs/msg/PointField"]
    header = ts.types["std_msgs/msg/Header"]
    stamp = ts.types["builtin_interfaces/msg/Time"](sec=1, nanosec=2)
    h, w = 3, 4
    fields = [
        F("intensity", 7, 0, values(7, h * w, seed=8)),
        F("x", 8, 8, values(8, h * w, seed=0)),
        F("y", 8, 16, values(8, h * w, seed=1)),
        F("z", 8, 24, values(8, h * w, seed=2)),
        F("ring", 4, 32, values(4, h * w, seed=3)),
    ]
    fields[2].values[5] = np.nan
    stand_in = encode(fields, height=h, width=w, point_step=40, row_pad=8, bigendian=True)
    msg = pc2(
        header=header(stamp=stamp, frame_id="velodyne"),
        height=h,
        width=w,
        fields=[pf(name=f.name, offset=f.offset, datatype=f.datatype, count=1) for f in fields],
        is_bigendian=True,
        point_step=40,
        row_step=stand_in.row_step,
        data=np.array(stand_in.data, dtype=np.uint8),
        is_dense=False,
    )
    back = ros_msg(ts.deserialize_cdr(ts.serialize_cdr(msg, msg.__msgtype__), msg.__msgtype__))
    assert isinstance(back.data, np.ndarray) and back.data.dtype == np.uint8
    got = pointcloud2_xyz(back)
    assert got.shape == (11, 3)
    np.testing.assert_array_equal(got, reference_xyz(stand_in))
    keep = np.arange(h * w) != 5
    np.testing.assert_array_equal(
        pointcloud2_fields(back, ["ring"])["ring"], fields[4].values[keep]
    )


@st.composite
def layouts(draw: st.DrawFn) -> Msg:
    dt = {a: draw(st.sampled_from(sorted(TYPES))) for a in "xyz"}
    extra = draw(st.lists(st.sampled_from(sorted(TYPES)), max_size=3))
    h, w = draw(st.integers(0, 4)), draw(st.integers(0, 5))
    specs = [(a, dt[a], 1) for a in "xyz"] + [
        (f"e{i}", t, draw(st.integers(1, 3))) for i, t in enumerate(extra)
    ]
    specs = draw(st.permutations(specs))
    fields, offset = [], 0
    for i, (name, t, count) in enumerate(specs):
        offset += draw(st.integers(0, 3))  # gaps between fields
        v = values(t, h * w, count=count, seed=i)
        if t >= 7 and h * w and draw(st.booleans()):
            v.reshape(-1)[draw(st.integers(0, v.size - 1))] = np.nan
        fields.append(F(name, t, offset, v, count))
        offset += count * int(TYPES[t][1][1])
    step = offset + draw(st.integers(0, 8))
    return encode(
        fields,
        height=h,
        width=w,
        point_step=step,
        row_pad=draw(st.integers(0, 9)),
        bigendian=draw(st.booleans()),
    )


@settings(max_examples=60, deadline=None)
@given(layouts())
def test_any_layout_matches_the_reference(msg: Msg) -> None:
    np.testing.assert_array_equal(pointcloud2_xyz(msg), reference_xyz(msg))
