"""The test helpers themselves: bags written by bagmaker/carmen read back with open_bag."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from scan2terrain.readers.bag import TF_MESSAGE_ROS1_OLD, TF_TYPES, open_bag
from scan2terrain.types import Transform, normalise_frame
from tests.bagmaker import (
    FORMATS,
    LASER_SCAN,
    OCCUPANCY_GRID,
    ODOMETRY,
    POINT_CLOUD2,
    TF_MESSAGE,
    Fmt,
    build,
    laserscan_msg,
    occupancy_grid_msg,
    odometry_msg,
    pointcloud2_msg,
    read_messages,
    synthetic_room,
    tf_msg,
    typestore,
    write_bag,
    yaw_quaternion,
)
from tests.carmen import (
    DEFAULT_LOG,
    RANGE_MAX,
    carmen_messages,
    carmen_scans,
    carmen_to_bag,
    read_carmen,
)

T0 = 1_700_000_000_123_456_789


def bag_path(tmp_path: Path, name: str, fmt: Fmt) -> Path:
    return tmp_path / (f"{name}.bag" if fmt == "ros1" else f"{name}_{fmt}")


def stamp_ns(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def cloud_xyz(msg: Any) -> np.ndarray:
    """x, y, z of an unorganised little-endian PointCloud2 (test-side decoder)."""
    names = [f.name for f in msg.fields]
    offsets = [f.offset for f in msg.fields]
    kinds = {7: "<f4", 8: "<f8", 1: "i1", 2: "u1", 3: "<i2", 4: "<u2", 5: "<i4", 6: "<u4"}
    dtype = np.dtype(
        {
            "names": names,
            "formats": [kinds[f.datatype] for f in msg.fields],
            "offsets": offsets,
            "itemsize": msg.point_step,
        }
    )
    arr = np.frombuffer(np.asarray(msg.data).tobytes(), dtype=dtype)
    return np.column_stack([arr["x"], arr["y"], arr["z"]])


def tf_pose(t: Any) -> Transform:
    tr, q = t.transform.translation, t.transform.rotation
    return Transform.from_quaternion((tr.x, tr.y, tr.z), (q.x, q.y, q.z, q.w))


def test_build_fills_ros_defaults_per_format() -> None:
    ros1 = build(typestore("ros1"), LASER_SCAN, {"header": {"stamp": 5_000_000_001}})
    ros2 = build(typestore("sqlite3"), LASER_SCAN, {"header": {"frame_id": "laser"}})
    assert ros1.header.seq == 0
    assert (ros1.header.stamp.sec, ros1.header.stamp.nanosec) == (5, 1)
    assert not hasattr(ros2.header, "seq")
    assert ros2.header.frame_id == "laser"
    assert ros2.ranges.dtype == np.float32
    assert len(ros2.ranges) == 0
    with pytest.raises(KeyError, match="rangez"):
        build(typestore("ros1"), LASER_SCAN, {"rangez": [1.0]})


@pytest.mark.parametrize("fmt", FORMATS)
def test_every_builder_round_trips(tmp_path: Path, fmt: Fmt) -> None:
    ranges = np.array([1.0, 2.5, np.inf, 0.5], dtype=np.float32)
    pts = np.array([[1, 2, 3], [4, 5, 6], [-1, -2, -3.5]], dtype=np.float32)
    intensity = np.array([10, 20, 30], dtype=np.float32)
    grid = np.array([[0, 100, -1], [50, 0, 0]], dtype=np.int8)
    messages = [
        ("/scan", LASER_SCAN, T0 + 10, laserscan_msg(T0, "laser", -1.0, 0.5, ranges, 0.1, 20.0)),
        (
            "/points",
            POINT_CLOUD2,
            T0 + 20,
            pointcloud2_msg(T0 + 1, "lidar", pts, {"intensity": intensity}, point_step=32),
        ),
        (
            "/tf",
            TF_MESSAGE,
            T0 + 30,
            tf_msg([("odom", "base_link", T0 + 2, (1, 2, 0), yaw_quaternion(0.5))]),
        ),
        (
            "/odom",
            ODOMETRY,
            T0 + 40,
            odometry_msg(T0 + 3, "odom", "base_link", (3, 4, 0), yaw_quaternion(-1.0)),
        ),
        ("/map", OCCUPANCY_GRID, T0 + 50, occupancy_grid_msg(T0 + 4, "map", grid, 0.05, (1, 2, 0))),
    ]
    path = write_bag(bag_path(tmp_path, "all", fmt), fmt, reversed(messages))
    with open_bag(path) as bag:
        assert {t.name: (t.msgtype, t.count) for t in bag.topics.values()} == {
            topic: (msgtype, 1) for topic, msgtype, _, _ in messages
        }
        assert bag.skipped == {}
        assert (bag.start_ns, bag.end_ns) == (T0 + 10, T0 + 50)
        got = {topic: (t, msg) for topic, t, msg in read_messages(bag, list(bag.topics))}
    assert [got[m[0]][0] for m in messages] == [m[2] for m in messages]
    scan = got["/scan"][1]
    assert stamp_ns(scan) == T0
    np.testing.assert_array_equal(scan.ranges, ranges)
    assert scan.angle_max == pytest.approx(0.5)
    cloud = got["/points"][1]
    assert (cloud.point_step, cloud.width, cloud.row_step) == (32, 3, 96)
    assert [(f.name, f.offset, f.datatype) for f in cloud.fields] == [
        ("x", 0, 7),
        ("y", 4, 7),
        ("z", 8, 7),
        ("intensity", 12, 7),
    ]
    np.testing.assert_array_equal(cloud_xyz(cloud), pts)
    tf = got["/tf"][1].transforms[0]
    assert (tf.header.frame_id, tf.child_frame_id, stamp_ns(tf)) == ("odom", "base_link", T0 + 2)
    assert tf.transform.rotation.z == pytest.approx(math.sin(0.25))
    odom = got["/odom"][1]
    assert (odom.child_frame_id, odom.pose.pose.position.x) == ("base_link", 3.0)
    occ = got["/map"][1]
    assert (occ.info.width, occ.info.height, occ.info.resolution) == (3, 2, pytest.approx(0.05))
    np.testing.assert_array_equal(np.asarray(occ.data).reshape(2, 3), grid)


def test_old_ros1_tf_type_is_a_tf_source(tmp_path: Path) -> None:
    msg = tf_msg([("/odom", "/base_link", T0, (0, 0, 0), (0, 0, 0, 1))])
    path = write_bag(tmp_path / "old.bag", "ros1", [("/tf", TF_MESSAGE_ROS1_OLD, T0, msg)])
    with open_bag(path) as bag:
        assert bag.topics["/tf"].msgtype == TF_MESSAGE_ROS1_OLD
        assert bag.topics_of_type(TF_TYPES) == ["/tf"]
        assert bag.frame_ids("/tf") == {"odom", "base_link"}


# --- the synthetic room ---------------------------------------------------------------------------


@pytest.mark.parametrize("variant", ["tf", "cloud"])
def test_room_hits_lie_on_the_true_walls(variant: Any) -> None:
    room = synthetic_room(variant, n_scans=40)
    hits = np.concatenate(room.hits)
    above_floor = hits[:, 2] > 1e-6
    col = np.floor((hits[:, 0] - room.origin[0]) / room.resolution).astype(int)
    row = np.floor((hits[:, 1] - room.origin[1]) / room.resolution).astype(int)
    assert room.occupied[row[above_floor], col[above_floor]].all()
    assert not (room.inside & room.occupied).any()
    # 10 m x 8 m of walls plus the 1.5 m box, one cell thick.
    assert room.occupied.sum() == pytest.approx((2 * (10 + 8) + 4 * 1.5) / room.resolution, abs=8)
    if variant == "cloud":
        assert (~above_floor).any()  # the floor is seen too
        assert hits[:, 2].max() <= 2.5 + 1e-6


def test_room_scans_agree_across_formats(tmp_path: Path) -> None:
    room = synthetic_room("tf", n_scans=20)
    ranges = {}
    for fmt in FORMATS:
        with open_bag(room.write(bag_path(tmp_path, "room", fmt), fmt)) as bag:
            assert {t: i.count for t, i in bag.topics.items()} == {
                "/scan": 20,
                "/tf": 40,
                "/tf_static": 1,
            }
            ranges[fmt] = np.stack([m.ranges for _, _, m in read_messages(bag, "/scan")])
    np.testing.assert_array_equal(ranges["ros1"], ranges["sqlite3"])
    np.testing.assert_array_equal(ranges["ros1"], ranges["mcap"])


@pytest.mark.parametrize("variant", ["tf", "slashes", "cloud"])
def test_room_tf_tree_gives_the_true_sensor_pose(tmp_path: Path, variant: Any) -> None:
    room = synthetic_room(variant, n_scans=24)
    path = room.write(tmp_path / "room.bag", "ros1")
    edges: dict[tuple[str, str, int], Transform] = {}
    static: dict[tuple[str, str], Transform] = {}
    raw_names: set[str] = set()
    scans: list[tuple[int, str]] = []
    with open_bag(path) as bag:
        topics = ["/tf", "/tf_static", room.scan_topic]
        for topic, _, m in read_messages(bag, topics):
            if topic == room.scan_topic:
                scans.append((stamp_ns(m), m.header.frame_id))
                continue
            for t in m.transforms:
                raw_names.update((t.header.frame_id, t.child_frame_id))
                key = (normalise_frame(t.header.frame_id), normalise_frame(t.child_frame_id))
                if topic == "/tf_static":
                    static[key] = tf_pose(t)
                else:
                    parent, child = key
                    edges[(parent, child, stamp_ns(t))] = tf_pose(t)
    slash = "/" if variant == "slashes" else ""
    assert raw_names == {slash + n for n in ("map", "odom", "base_link", room.sensor_frame)}
    assert [s for s, _ in scans] == room.stamps_ns.tolist()
    assert {f for _, f in scans} == {room.sensor_frame}
    mount = static[("base_link", room.sensor_frame)]
    np.testing.assert_allclose(mount.translation, room.mount.translation)
    map_odom = next(v for k, v in edges.items() if k[:2] == ("map", "odom"))
    np.testing.assert_allclose(map_odom.translation, room.map_to_odom.translation)
    for k, (stamp, _) in enumerate(scans):
        sensor = map_odom.compose(edges[("odom", "base_link", stamp)]).compose(mount)
        yaw = math.atan2(sensor.rotation[1, 0], sensor.rotation[0, 0])
        x, y, true_yaw = room.sensor_poses[k]
        np.testing.assert_allclose(sensor.translation, [x, y, room.mount.translation[2]], atol=1e-9)
        assert math.remainder(yaw - true_yaw, 2 * math.pi) == pytest.approx(0, abs=1e-9)


def test_room_cloud_points_are_the_hits(tmp_path: Path) -> None:
    room = synthetic_room("cloud", n_scans=6, rings=8, azimuths=90)
    with open_bag(room.write(tmp_path / "c", "mcap")) as bag:
        clouds = [m for _, _, m in bag.messages("/points")]
    for k, cloud in enumerate(clouds):
        x, y, yaw = room.sensor_poses[k]
        sensor = Transform.from_quaternion((x, y, room.mount.translation[2]), yaw_quaternion(yaw))
        np.testing.assert_allclose(sensor.apply(cloud_xyz(cloud)), room.hits[k], atol=1e-9)


def test_room_tf_gap_and_odom_variants(tmp_path: Path) -> None:
    gap = synthetic_room("tf_gap", n_scans=150, gap_s=(8.0, 10.0))
    with open_bag(gap.write(tmp_path / "gap.bag", "ros1")) as bag:
        tf_times = np.array([t for _, t, _ in bag.messages("/tf")])
        scan_times = np.array([t for _, t, _ in bag.messages("/scan")])
    rel_tf = (tf_times - gap.stamps_ns[0]) / 1e9
    rel_scan = (scan_times - gap.stamps_ns[0]) / 1e9
    assert not ((rel_tf > 8.0 + 0.002) & (rel_tf < 10.0)).any()
    assert ((rel_scan > 8.0) & (rel_scan < 10.0)).sum() == 20
    assert len(tf_times) == 300 - 40

    odom = synthetic_room("odom", n_scans=30)
    with open_bag(odom.write(tmp_path / "odom", "sqlite3")) as bag:
        assert set(bag.topics) == {"/odom", "/scan"}
        msgs = [m for _, _, m in read_messages(bag, "/odom")]
    assert {(m.header.frame_id, m.child_frame_id) for m in msgs} == {("odom", "base_link")}
    xy = np.array([[m.pose.pose.position.x, m.pose.pose.position.y] for m in msgs])
    np.testing.assert_allclose(xy, odom.base_poses[:, :2])
    np.testing.assert_array_equal(odom.map_to_odom.translation, np.zeros(3))


# --- CARMEN ---------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def carmen_log() -> Any:
    return read_carmen()


def test_carmen_log_catalogue(carmen_log: Any) -> None:
    assert len(carmen_log) == 1988
    assert carmen_log.ranges.shape == (1988, 361)
    assert carmen_log.angle_min == pytest.approx(-math.pi / 2)
    assert carmen_log.angle_increment == pytest.approx(math.radians(0.5))
    assert np.all(np.diff(carmen_log.stamps_ns) > 0)
    assert (carmen_log.stamps_ns[-1] - carmen_log.stamps_ns[0]) / 1e9 == pytest.approx(424.0, 0.01)
    assert carmen_log.stamps_ns[0] == 1_134_864_629_895_182_000
    # In this log the "laser pose" is the odometry pose on every line.
    np.testing.assert_array_equal(carmen_log.laser_poses, carmen_log.odom_poses)
    no_return = carmen_log.ranges > RANGE_MAX
    assert 0.01 < no_return.mean() < 0.1
    assert carmen_log.ranges[~no_return].max() < 45.0


def test_carmen_bag_round_trip(tmp_path: Path, carmen_log: Any) -> None:
    log = read_carmen(every=10)
    assert len(log) == 199
    np.testing.assert_array_equal(log.ranges, carmen_log.ranges[::10])
    path = carmen_to_bag(tmp_path / "mit.bag", log)
    with open_bag(path) as bag:
        assert {t: (i.msgtype, i.count) for t, i in bag.topics.items()} == {
            "/scan": (LASER_SCAN, 199),
            "/tf": (TF_MESSAGE, 199),
            "/tf_static": (TF_MESSAGE, 1),
        }
        assert bag.start_ns == log.stamps_ns[0]
        scans = [m for _, _, m in read_messages(bag, "/scan")]
        tfs = [m.transforms[0] for _, _, m in read_messages(bag, "/tf")]
        mount = tf_pose(next(m for _, _, m in read_messages(bag, "/tf_static")).transforms[0])
    np.testing.assert_array_equal(np.stack([s.ranges for s in scans]), log.ranges)
    assert [stamp_ns(s) for s in scans] == log.stamps_ns.tolist()
    for k in (0, 100, 198):
        laser = tf_pose(tfs[k]).compose(mount)
        np.testing.assert_allclose(laser.translation[:2], log.laser_poses[k, :2], atol=1e-9)
        yaw = math.atan2(laser.rotation[1, 0], laser.rotation[0, 0])
        assert math.remainder(yaw - log.laser_poses[k, 2], 2 * math.pi) == pytest.approx(0)


def test_carmen_scans_match_the_bag_geometry(carmen_log: Any) -> None:
    scans = carmen_scans(carmen_log, mount_z=0.3)
    assert len(scans) == 1988
    for k in (0, 700, 1987):
        pts, origin = scans[k]
        np.testing.assert_allclose(origin, [*carmen_log.laser_poses[k, :2], 0.3])
        r = carmen_log.ranges[k]
        valid = r[(r >= 0.05) & (r <= RANGE_MAX)]
        np.testing.assert_allclose(np.linalg.norm(pts - origin, axis=1), valid, rtol=1e-6)
        assert np.all(pts[:, 2] == 0.3)
    assert len(carmen_messages(read_carmen(max_scans=3))) == 1 + 2 * 3


def test_carmen_reads_robotlaser1_lines(tmp_path: Path) -> None:
    ranges = " ".join(["1.5"] * 5)
    line = (
        f"ROBOTLASER1 0 -1.0 2.0 0.5 30.0 0.01 0 5 {ranges} 2 7 8 "
        "1.0 2.0 0.3 0.9 2.0 0.3 0 0 0 0 0 1134864629.5 host 0.1\n"
    )
    path = tmp_path / "x.clf"
    path.write_text("# comment\nODOM 1 2 3 0 0 0 1 host 0\n" + line + line)
    log = read_carmen(path)
    assert len(log) == 2
    assert (log.angle_min, log.angle_increment) == (-1.0, 0.5)
    np.testing.assert_array_equal(log.laser_poses[0], [1.0, 2.0, 0.3])
    np.testing.assert_array_equal(log.odom_poses[0], [0.9, 2.0, 0.3])
    assert log.stamps_ns[0] == 1_134_864_629_500_000_000
    path.write_text("FLASER 3 1.0 2.0\n")
    with pytest.raises(ValueError, match=r"x\.clf: line 1: FLASER is cut short"):
        read_carmen(path)
    assert DEFAULT_LOG.is_file()
