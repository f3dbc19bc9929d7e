"""Foxglove's schemas in MCAP read as the ROS paths read theirs (issue 16): the decoding choices
of :mod:`scan2terrain.readers.foxglove` one by one, in protobuf and JSON alike. The
command-level twins are in tests/test_bag2world_foxglove.py."""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from scan2terrain.config import ScansConfig
from scan2terrain.readers.bag import open_bag
from scan2terrain.readers.foxglove import Grid, LaserScan, PointCloud, PoseInFrame
from scan2terrain.readers.scans import (
    BagPlan,
    occupancy_from_message,
    plan_bag,
    posed_scans,
    read_tf,
)
from scan2terrain.types import ScanCounts
from tests.bagmaker import FoxgloveEncoding, ros_bag_to_foxglove_mcap, write_foxglove_mcap
from tests.fixtures import EMBARK_ROS1

ENCODINGS: list[FoxgloveEncoding] = ["protobuf", "json"]
T0 = 1_700_000_000_000_000_000
STAMP = {"sec": 1_700_000_000, "nsec": 0}


def one(tmp: Path, name: str, value: dict[str, Any], encoding: FoxgloveEncoding) -> Any:
    path = write_foxglove_mcap(tmp / f"{encoding}.mcap", [("/t", name, T0, value)], encoding)
    with open_bag(path) as bag:
        ((_, _, msg),) = list(bag.messages("/t"))
    return msg


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_pointcloud_points_as_the_pointcloud2(tmp_path: Path, encoding: FoxgloveEncoding) -> None:
    from scan2terrain.readers.pointcloud2 import pointcloud2_xyz

    mcap = ros_bag_to_foxglove_mcap(EMBARK_ROS1, tmp_path / "e.mcap", encoding)
    with open_bag(EMBARK_ROS1) as a, open_bag(mcap) as b:
        assert b.topics["/luminar_pointcloud"].msgtype == "foxglove.PointCloud"
        assert b.frame_ids("/luminar_pointcloud") == a.frame_ids("/luminar_pointcloud")
        want = [pointcloud2_xyz(m) for _, _, m in a.messages("/luminar_pointcloud")]
        got = [
            m.points()[0]
            for _, _, m in b.messages("/luminar_pointcloud")
            if isinstance(m, PointCloud)  # every one is: the length is checked below
        ]
    assert len(got) == len(want) == 5
    for g, w in zip(got, want, strict=True):
        assert np.array_equal(g, w)


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_pointcloud_two_fields_strides_types_and_nan(
    tmp_path: Path, encoding: FoxgloveEncoding
) -> None:
    rec = np.zeros(
        3,
        dtype=np.dtype(
            {"names": ["y", "x"], "formats": ["<f8", "<i2"], "offsets": [0, 8], "itemsize": 12}
        ),
    )
    rec["x"] = [1, -2, 3]
    rec["y"] = [0.5, math.nan, 2.5]
    value = {
        "timestamp": STAMP,
        "frame_id": "lidar",
        "point_stride": 12,
        "fields": [{"name": "y", "offset": 0, "type": 8}, {"name": "x", "offset": 8, "type": 4}],
        "data": rec.tobytes() + b"\x00" * 5,  # a partial point at the end is not a point
    }
    msg = one(tmp_path, "foxglove.PointCloud", value, encoding)
    assert isinstance(msg, PointCloud) and msg.local_pose is None
    pts, mr = msg.points(-1.0)
    assert mr == -1.0
    assert pts.tolist() == [[1.0, 0.5, 0.0], [3.0, 2.5, 0.0]]


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_laserscan_readings_follow_rep_117(tmp_path: Path, encoding: FoxgloveEncoding) -> None:
    """+inf is no return within range: with --max-range (Foxglove has no range_max) it clears
    up to it, as a ROS scan's +inf clears up to range_max; without, nothing says how far, so it
    is dropped. NaN, -inf (too close), 0 and negatives are no information: always dropped."""
    ranges = [1.0, 0.0, -1.0, math.inf, math.nan, 2.0, 50.0, -math.inf]
    value = {
        "timestamp": STAMP,
        "frame_id": "laser",
        "start_angle": 0.0,
        "end_angle": 7 * math.pi / 6,
        "ranges": ranges,
    }
    msg = one(tmp_path, "foxglove.LaserScan", value, encoding)
    assert isinstance(msg, LaserScan)
    pts, mr = msg.points(-1.0)
    assert mr == -1.0
    step = math.pi / 6
    want = [(r * math.cos(i * step), r * math.sin(i * step)) for i, r in [(0, 1), (5, 2), (6, 50)]]
    np.testing.assert_allclose(pts[:, :2], want, atol=1e-12)
    # --max-range: at or beyond it, and +inf, a beam only clears (as a ROS scan's range_max)
    pts, mr = msg.points(10.0)
    assert mr == pytest.approx(10.0, rel=1e-4) and len(pts) == 4
    angles = np.arctan2(pts[:, 1], pts[:, 0]) % (2 * math.pi)
    np.testing.assert_allclose(angles, np.array([0, 3, 5, 6]) * step, atol=1e-12)
    distance = np.hypot(pts[:, 0], pts[:, 1])
    np.testing.assert_allclose(distance[[0, 2]], [1.0, 2.0])
    assert (distance[[1, 3]] > mr).all()


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_laserscan_points_equal_the_ros_laserscans(
    tmp_path: Path, encoding: FoxgloveEncoding
) -> None:
    """The same readings as a ROS LaserScan (range_max R) and a Foxglove one read with
    --max-range R: the same points and the same cut, +inf and NaN included."""
    from types import SimpleNamespace

    from scan2terrain.readers.laserscan import laserscan_points

    rng = np.random.default_rng(7)
    ranges = rng.uniform(0.1, 12.0, 360).astype(np.float32)
    ranges[rng.choice(360, 60, replace=False)] = np.inf
    ranges[rng.choice(360, 20, replace=False)] = np.nan
    ranges[rng.choice(360, 10, replace=False)] = -np.inf
    ranges[:5] = 8.0  # exactly range_max: clear only
    inc = np.float32(2 * np.pi / 360)
    ros = SimpleNamespace(
        ranges=ranges, angle_min=-np.pi, angle_increment=float(inc), range_min=0.0, range_max=8.0
    )
    value = {
        "timestamp": STAMP,
        "frame_id": "laser",
        "start_angle": -np.pi,
        "end_angle": -np.pi + 359 * float(inc),
        "ranges": [float(r) for r in ranges],
    }
    msg = one(tmp_path, "foxglove.LaserScan", value, encoding)
    want, want_mr = laserscan_points(ros)
    got, got_mr = msg.points(8.0)
    informative = int(np.count_nonzero(ranges > 0))  # not NaN, not -inf
    assert got_mr == want_mr and got.shape == want.shape == (informative, 3)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_scan_pose_is_composed_with_its_frame(tmp_path: Path, encoding: FoxgloveEncoding) -> None:
    """A scan's pose in its frame moves its points and the ray origin (ray casting)."""
    yaw = 0.5
    pose = {
        "position": {"x": 1.0, "y": 2.0, "z": 0.5},
        "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2), "w": math.cos(yaw / 2)},
    }
    value = {
        "timestamp": STAMP,
        "frame_id": "laser",
        "pose": pose,
        "start_angle": 0.0,
        "end_angle": 0.0,
        "ranges": [2.0],
    }
    path = write_foxglove_mcap(
        tmp_path / "p.mcap", [("/scan", "foxglove.LaserScan", T0, value)], encoding
    )
    cfg = ScansConfig(pose=[10.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    with open_bag(path) as bag:
        plan = plan_bag(bag, cfg)
        (scan,) = list(posed_scans(bag, cfg, plan, ScanCounts()))
    np.testing.assert_allclose(scan.origin, [11.0, 2.0, 0.5], atol=1e-12)
    want = [11.0 + 2 * math.cos(yaw), 2.0 + 2 * math.sin(yaw), 0.5]
    np.testing.assert_allclose(scan.points, [want], atol=1e-12)
    assert scan.heading == pytest.approx(yaw)


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_frame_transforms_feed_tf_as_tf_messages(
    tmp_path: Path, encoding: FoxgloveEncoding
) -> None:
    from tests.bagmaker import synthetic_room

    room = synthetic_room("tf", n_scans=20)
    bag = room.write(tmp_path / "room.bag", "ros1")
    for split in (False, True):
        mcap = ros_bag_to_foxglove_mcap(bag, tmp_path / f"{split}.mcap", encoding, split_tf=split)
        cfg = ScansConfig()
        with open_bag(bag) as a, open_bag(mcap) as b:
            ta, tb = read_tf(a, cfg), read_tf(b, cfg)
            assert tb.edges() == ta.edges()
            stamps = room.stamps_ns[:-1]
            for x, y in zip(
                ta.lookup_many("map", "laser", stamps),
                tb.lookup_many("map", "laser", stamps),
                strict=True,
            ):
                assert np.array_equal(x, y)


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_pose_in_frame_is_odometry(tmp_path: Path, encoding: FoxgloveEncoding) -> None:
    from tests.bagmaker import synthetic_room

    room = synthetic_room("odom", n_scans=20)
    bag = room.write(tmp_path / "odom.bag", "ros1")
    mcap = ros_bag_to_foxglove_mcap(bag, tmp_path / "odom.mcap", encoding)
    cfg = ScansConfig()
    with open_bag(mcap) as b:
        assert b.topics["/odom"].msgtype == "foxglove.PoseInFrame"
        (_, _, msg) = next(iter(b.messages("/odom")))
        assert isinstance(msg, PoseInFrame)
        plan: BagPlan = plan_bag(b, cfg)
    assert plan.poses == "odom" and plan.odom_topic == "/odom"


def grid_value(data: bytes, fields: list[dict[str, Any]], **kw: Any) -> dict[str, Any]:
    return {
        "timestamp": STAMP,
        "frame_id": "map",
        "column_count": 3,
        "cell_size": {"x": 0.5, "y": 0.5},
        "row_stride": 3,
        "cell_stride": 1,
        "fields": fields,
        "data": data,
        **kw,
    }


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_grid_layouts(tmp_path: Path, encoding: FoxgloveEncoding) -> None:
    uint8 = grid_value(bytes([0, 100, 255, 50, 0, 0]), [{"name": "cost", "offset": 0, "type": 1}])
    msg = one(tmp_path, "foxglove.Grid", uint8, encoding)
    assert isinstance(msg, Grid)
    data, res, origin = occupancy_from_message(msg)
    assert data.tolist() == [[0, 100, -1], [50, 0, 0]] and res == 0.5 and origin == (0, 0, 0)
    # padded rows and cells, a colour beside a float occupancy probability
    cells = np.zeros(
        (2, 4),
        dtype=np.dtype(
            {
                "names": ["red", "occupancy"],
                "formats": ["u1", "<f4"],
                "offsets": [0, 4],
                "itemsize": 8,
            }
        ),
    )
    cells["occupancy"] = [[0.0, 1.0, math.nan, 0], [0.5, 0.25, 0.0, 0]]
    floats = grid_value(
        cells.tobytes(),
        [{"name": "red", "offset": 0, "type": 1}, {"name": "occupancy", "offset": 4, "type": 7}],
        row_stride=32,
        cell_stride=8,
    )
    msg = one(tmp_path, "foxglove.Grid", floats, encoding)
    data, _, _ = occupancy_from_message(msg)
    assert data.tolist() == [[0, 100, -1], [50, 25, 0]]


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_elevation_grid_heights(tmp_path: Path, encoding: FoxgloveEncoding) -> None:
    """A field named elevation (grid_map's layer) makes a height grid, of any numeric type,
    beside colour channels, in padded rows; it is not an occupancy grid."""
    cells = np.zeros(
        (2, 4),  # 3 columns and a padding cell per row
        dtype=np.dtype(
            {"names": ["red", "elevation"], "formats": ["u1", "<i2"], "offsets": [0, 2],
             "itemsize": 4}
        ),
    )  # fmt: skip
    cells["elevation"] = [[-3, 0, 7, 99], [120, 5, -1, 99]]
    value = grid_value(
        cells.tobytes(),
        [{"name": "red", "offset": 0, "type": 1}, {"name": "elevation", "offset": 2, "type": 4}],
        row_stride=16,
        cell_stride=4,
    )
    msg = one(tmp_path, "foxglove.Grid", value, encoding)
    assert isinstance(msg, Grid) and msg.is_elevation
    assert msg.heights.tolist() == [[-3, 0, 7], [120, 5, -1]]
    with pytest.raises(ValueError, match="Grid has no occupancy field"):
        _ = msg.data


@pytest.mark.parametrize(
    ("change", "problem"),
    [
        ({"cell_size": {"x": 0.5, "y": 0.25}}, "only square cells are read"),
        (
            {
                "fields": [
                    {"name": "elevation", "offset": 0, "type": 7},
                    {"name": "height", "offset": 0, "type": 1},
                ]
            },
            "Grid has no occupancy field",
        ),
        ({"fields": [{"name": "occupancy", "offset": 0, "type": 5}]}, "does not fit"),
        ({"cell_stride": 2}, "do not fit in row_stride 3"),
    ],
)
def test_grids_that_are_not_occupancy_are_refused(
    tmp_path: Path, change: dict[str, Any], problem: str
) -> None:
    value = grid_value(bytes(6), [{"name": "occupancy", "offset": 0, "type": 2}]) | change
    msg = one(tmp_path, "foxglove.Grid", value, "json")
    with pytest.raises(ValueError, match=problem):
        occupancy_from_message(msg)


@pytest.mark.parametrize("encoding", ENCODINGS)
@pytest.mark.parametrize(
    ("name", "value", "where"),
    [
        ("foxglove.PointCloud", {"frame_id": "l", "point_stride": 12}, "foxglove.PointCloud"),
        (
            "foxglove.FrameTransform",
            {"parent_frame_id": "a", "child_frame_id": "b"},
            "foxglove.FrameTransform",
        ),
        (
            "foxglove.FrameTransforms",
            {"transforms": "two, the second bad"},
            "foxglove.FrameTransforms.transforms[1]",
        ),
    ],
)
def test_a_timestamp_that_is_not_a_time_is_refused(
    tmp_path: Path, encoding: FoxgloveEncoding, name: str, value: dict[str, Any], where: str
) -> None:
    from scan2terrain.errors import InputError

    bad = {"sec": 1, "nsec": 2_000_000_000}
    if name == "foxglove.FrameTransforms":
        good = {"timestamp": STAMP, "parent_frame_id": "a", "child_frame_id": "b"}
        value = {"transforms": [good, good | {"timestamp": bad}]}
    else:
        value = value | {"timestamp": bad}
    with pytest.raises(
        InputError, match=re.escape(f"{where}.timestamp (1 s, 2000000000 ns) is not")
    ):
        one(tmp_path, name, value, encoding)


@pytest.mark.parametrize(
    ("fields", "named"),
    [
        (b"\x0a\x01a" + b"\x1a\x03\xff\xfeb", "names a file in bytes that are not UTF-8"),
        (b"\x0a\x03\xff\xfeb", "names a file in bytes that are not UTF-8"),
        (b"\x0a\x01a" + b"\x1a\x03b\x1dc", "lacks b\\x1dc (circular?)"),
    ],
)
def test_a_descriptor_set_naming_files_in_bytes_or_controls_is_refused(
    fields: bytes, named: str
) -> None:
    """Seen (fuzz mcap-foxglove/flip4@5): a dependency in bytes that are not UTF-8 ended in a
    TypeError (exit 1), as the refusal joined them as text."""
    from scan2terrain.readers._foxglove_decode import protobuf_decoder

    descriptor_set = b"\x0a" + bytes([len(fields)]) + fields  # FileDescriptorSet.file[0]
    with pytest.raises(ValueError, match=re.escape(named)):
        protobuf_decoder("foxglove.LaserScan", descriptor_set)
