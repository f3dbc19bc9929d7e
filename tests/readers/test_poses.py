"""Poses for each scan: tf trees, odometry, TUM files and fixed poses, checked against scipy."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.highlevel import AnyReader
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from scipy.spatial.transform import Rotation, Slerp

from scan2terrain.errors import InputError
from scan2terrain.readers.poses import DEFAULT_MAX_GAP_NS, fixed_pose, mount, rpy_matrix
from scan2terrain.readers.tf import TfBuffer
from scan2terrain.readers.tracks import OdometryArrays, PoseTrack, odometry_track, read_tum
from scan2terrain.types import Transform, normalise_frame

S = 1_000_000_000  # nanoseconds per second
TS2 = get_typestore(Stores.ROS2_HUMBLE)


def random_quaternions(rng: np.random.Generator, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return np.asarray(q / np.linalg.norm(q, axis=1, keepdims=True), dtype=np.float64)


def yaw_quaternion(yaw: float) -> tuple[float, float, float, float]:
    return (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))


def assert_same(a: Transform | None, b: Transform, atol: float = 1e-12) -> None:
    assert a is not None
    np.testing.assert_allclose(a.rotation, b.rotation, atol=atol)
    np.testing.assert_allclose(a.translation, b.translation, atol=atol)


# ------------------------------------------------------------------------------ PoseTrack


def test_normalise_frame() -> None:
    assert normalise_frame("/base_link") == "base_link"
    assert normalise_frame(" base_link \n") == "base_link"
    assert normalise_frame("//map") == "map"
    assert normalise_frame("odom") == "odom"


def test_track_is_exact_at_samples_and_matches_scipy_slerp_between() -> None:
    rng = np.random.default_rng(0)
    times = np.array([0, 1 * S, 3 * S, 3 * S + 7, 10 * S], dtype=np.int64)
    trans = rng.normal(size=(5, 3)) * 10
    quats = random_quaternions(rng, 5) * rng.uniform(0.5, 2, (5, 1))  # not normalised on input
    track = PoseTrack(times, trans, quats)
    for k in range(5):
        got = track.at(int(times[k]))
        assert got is not None
        np.testing.assert_array_equal(got.translation, trans[k])  # bit for bit
        assert_same(got, Transform.from_quaternion(trans[k], quats[k]), atol=1e-15)
    query = np.sort(rng.integers(0, 10 * S, 200))
    valid, rot, tr = track.at_many(query)
    assert valid.all()
    ref_rot = Slerp(times / S, Rotation.from_quat(quats))(query / S).as_matrix()
    np.testing.assert_allclose(rot, ref_rot, atol=1e-12)
    ref_tr = np.stack([np.interp(query, times, trans[:, i]) for i in range(3)], axis=1)
    np.testing.assert_allclose(tr, ref_tr, atol=1e-12)
    # the midpoint of two samples: translation halfway, rotation half the relative turn
    mid = track.at(S // 2)
    assert mid is not None
    np.testing.assert_allclose(mid.translation, (trans[0] + trans[1]) / 2, atol=1e-12)
    rel = Rotation.from_quat(quats[0]).inv() * Rotation.from_quat(quats[1])
    half = Rotation.from_quat(quats[0]) * Rotation.from_rotvec(rel.as_rotvec() / 2)
    np.testing.assert_allclose(mid.rotation, half.as_matrix(), atol=1e-12)


def test_at_and_at_many_agree_and_invalid_is_nan() -> None:
    rng = np.random.default_rng(1)
    times = np.arange(0, 5 * S, S // 2, dtype=np.int64)
    track = PoseTrack(times, rng.normal(size=(10, 3)), random_quaternions(rng, 10))
    query = np.array([-1, 0, S // 3, 4 * S + S // 2, 4 * S + S // 2 + 1, 2 * S + 1])
    valid, rot, tr = track.at_many(query)
    np.testing.assert_array_equal(valid, [False, True, True, True, False, True])
    assert np.isnan(rot[~valid]).all()
    assert np.isnan(tr[~valid]).all()
    for k, t in enumerate(query):
        one = track.at(int(t))
        if valid[k]:
            assert one is not None
            np.testing.assert_array_equal(one.rotation, rot[k])
            np.testing.assert_array_equal(one.translation, tr[k])
        else:
            assert one is None


def test_track_sorts_and_keeps_the_last_of_equal_times() -> None:
    times = [2 * S, 0, 2 * S, 1 * S]
    trans = [[2, 0, 0], [0, 0, 0], [9, 0, 0], [1, 0, 0]]
    track = PoseTrack(times, trans, [yaw_quaternion(0)] * 4, frame_id="/odom")
    np.testing.assert_array_equal(track.times_ns, [0, S, 2 * S])
    np.testing.assert_array_equal(track.translations[:, 0], [0, 1, 9])
    assert track.frame_id == "odom"
    assert len(track) == 3
    assert (track.start_ns, track.end_ns) == (0, 2 * S)
    assert not track.times_ns.flags.writeable


def test_sign_flips_take_the_short_way() -> None:
    # A slow yaw ramp whose publisher flips q <-> -q every other sample (the same rotations).
    yaws = np.linspace(0, 3.0, 7)
    quats = np.array([yaw_quaternion(y) for y in yaws])
    quats[1::2] *= -1
    times = np.arange(7, dtype=np.int64) * S
    track = PoseTrack(times, np.zeros((7, 3)), quats)
    dots = np.einsum("ij,ij->i", track.quaternions_xyzw[1:], track.quaternions_xyzw[:-1])
    assert (dots > 0).all()
    query = np.arange(0, 6 * S, S // 4)
    _, rot, _ = track.at_many(query)
    got_yaw = np.arctan2(rot[:, 1, 0], rot[:, 0, 0])
    np.testing.assert_allclose(got_yaw, np.interp(query, times, yaws), atol=1e-12)
    ref = Slerp(times / S, Rotation.from_quat(quats))(query / S).as_matrix()
    np.testing.assert_allclose(rot, ref, atol=1e-12)


def test_no_extrapolation_with_a_reason() -> None:
    track = PoseTrack([10 * S, 20 * S], np.zeros((2, 3)), [yaw_quaternion(0)] * 2)
    assert track.at(10 * S - 1) is None
    assert track.at(20 * S + 1) is None
    assert "no data before 10.000 s" in track.why_not(9 * S)
    assert "no data after 20.000 s" in track.why_not(21 * S)
    assert track.why_not(15 * S) == ""


def test_gap_longer_than_max_gap_is_refused_but_its_samples_are_not() -> None:
    times = [0, S // 10, 2 * S // 10, 5 * S, 5 * S + S // 10]
    track = PoseTrack(times, np.zeros((5, 3)), [yaw_quaternion(0)] * 5, max_gap_ns=S)
    assert track.at(S // 20) is not None
    assert track.at(3 * S) is None
    assert track.at(5 * S) is not None  # a sample inside the gap's ends is known
    assert track.at(2 * S // 10) is not None
    reason = track.why_not(3 * S)
    assert "gap of 4.800 s" in reason
    assert "1.000 s" in reason
    # Without a gap limit the gap is interpolated: x moves with time here, 3.0 m at 3 s.
    along = np.c_[np.array(times) / S, np.zeros(5), np.zeros(5)]
    pose = PoseTrack(times, along, [yaw_quaternion(0)] * 5).at(3 * S)
    assert pose is not None
    np.testing.assert_allclose(pose.translation, [3.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(pose.rotation, np.eye(3), atol=1e-12)


def test_single_sample_track_is_valid_only_at_its_time() -> None:
    track = PoseTrack([5], [[1, 2, 3]], [yaw_quaternion(1)])
    got = track.at(5)
    assert got is not None
    np.testing.assert_array_equal(got.translation, [1, 2, 3])
    assert track.at(4) is None
    assert track.at(6) is None


@pytest.mark.parametrize(
    ("times", "trans", "quats", "name"),
    [
        ([], np.zeros((0, 3)), np.zeros((0, 4)), "times_ns"),
        ([0.5], [[0, 0, 0]], [[0, 0, 0, 1]], "times_ns"),
        ([0], [[0, 0]], [[0, 0, 0, 1]], "translations"),
        ([0], [[0, 0, 0]], [[0, 0, 1]], "quaternions_xyzw"),
        ([0], [[0, 0, np.nan]], [[0, 0, 0, 1]], "translations"),
        ([0], [[0, 0, 0]], [[0, 0, 0, 0]], "quaternions_xyzw"),
    ],
)
def test_track_validation_names_the_parameter(
    times: Any, trans: Any, quats: Any, name: str
) -> None:
    with pytest.raises(ValueError, match=name):
        PoseTrack(times, trans, quats)


def test_max_gap_validation() -> None:
    with pytest.raises(ValueError, match="max_gap_ns"):
        PoseTrack([0], [[0, 0, 0]], [[0, 0, 0, 1]], max_gap_ns=-1)
    with pytest.raises(ValueError, match="max_gap_ns"):
        TfBuffer(max_gap_ns=0.5)  # type: ignore[arg-type]


# -------------------------------------------------------------------------------- TfBuffer

MOUNT = mount(0.2, 0.0, 0.5, roll=0.0, pitch=0.1, yaw=math.pi / 2)
IMU = mount(-0.1, 0.05, 0.2, roll=0.3)


def robot_buffer() -> TfBuffer:
    """map -> odom -> base_link (dynamic, 0..10 s) with static laser and imu mounts.

    Names carry ROS 1's leading slash on some edges, as real bags do.
    """
    buf = TfBuffer()
    for k in range(11):
        t = k * S
        buf.add("/map", "/odom", t, (0.1 * k, -0.05 * k, 0.0), yaw_quaternion(0.01 * k))
        buf.add("odom", "base_link", t, (1.0 * k, 0.5 * k, 0.0), yaw_quaternion(0.2 * k))
    buf.add("base_link", "/laser", 0, MOUNT.translation, quaternion_of(MOUNT), static=True)
    buf.add("/base_link", "imu", 0, IMU.translation, quaternion_of(IMU), static=True)
    return buf


def quaternion_of(t: Transform) -> np.ndarray:
    return np.asarray(Rotation.from_matrix(t.rotation).as_quat(), dtype=np.float64)


def manual_base_in_map(t_s: float) -> Transform:
    """map -> odom -> base_link interpolated by hand: linear position, linear yaw (planar)."""
    k = t_s
    odom = Transform.from_quaternion((0.1 * k, -0.05 * k, 0.0), yaw_quaternion(0.01 * k))
    base = Transform.from_quaternion((1.0 * k, 0.5 * k, 0.0), yaw_quaternion(0.2 * k))
    return odom.compose(base)


@pytest.mark.parametrize("t_s", [0.0, 2.0, 3.25, 7.5, 10.0])
def test_tree_lookup_laser_in_map_and_its_inverse(t_s: float) -> None:
    buf = robot_buffer()
    t = round(t_s * S)
    expected = manual_base_in_map(t_s).compose(MOUNT)
    got = buf.lookup("map", "laser", t)
    assert_same(got, expected)
    assert_same(buf.lookup("/map", "/laser", t), expected)  # slashes are the same frames
    back = buf.lookup("laser", "map", t)
    assert_same(back, expected.inverse())
    assert got is not None
    assert back is not None
    assert_same(got.compose(back), Transform.identity())


def test_lookup_across_branches_through_the_common_ancestor() -> None:
    buf = robot_buffer()
    # laser and imu meet at base_link: laser in imu = IMU^-1 * MOUNT, at any time
    for t in (-100 * S, 5 * S, 10**18):
        assert_same(buf.lookup("imu", "laser", t), IMU.inverse().compose(MOUNT))
    # odom in laser crosses base_link and the laser mount
    expected = MOUNT.inverse().compose(
        Transform.from_quaternion((4.0, 2.0, 0.0), yaw_quaternion(0.8)).inverse()
    )
    assert_same(buf.lookup("laser", "odom", 4 * S), expected)
    assert_same(buf.lookup("laser", "laser", 123), Transform.identity())


def test_static_edges_hold_at_every_time_and_keep_the_latest() -> None:
    buf = TfBuffer()
    buf.add("base_link", "laser", 5 * S, (1, 0, 0), (0, 0, 0, 1), static=True)
    buf.add("base_link", "laser", 6 * S, (2, 0, 0), (0, 0, 0, 1), static=True)
    for t in (0, 5 * S, -(10**15), 10**18):
        got = buf.lookup("base_link", "laser", t)
        assert got is not None
        np.testing.assert_array_equal(got.translation, [2, 0, 0])
    (edge,) = buf.edges()
    assert (edge.static, edge.samples, edge.first_ns, edge.last_ns) == (True, 2, 5 * S, 6 * S)


def test_extrapolation_refused_with_the_edge_named() -> None:
    buf = robot_buffer()
    buf.add("odom", "base_link", 11 * S, (11, 5.5, 0), yaw_quaternion(2.2))  # odom runs longer
    assert buf.lookup("odom", "laser", 11 * S) is not None
    assert buf.lookup("map", "laser", 11 * S) is None
    reason = buf.why_not("map", "laser", 11 * S)
    assert reason.startswith("tf 'map -> odom' has no data after 10.000 s")
    assert "no extrapolation" in reason
    assert buf.lookup("map", "laser", -1) is None
    assert "no data before" in buf.why_not("map", "laser", -1)
    assert buf.why_not("map", "laser", 5 * S) == ""


def test_gap_refused_in_the_buffer() -> None:
    buf = TfBuffer()  # default 1 s
    assert buf.max_gap_ns == DEFAULT_MAX_GAP_NS
    for t in (0, S // 2, 3 * S, 3 * S + S // 2):
        buf.add("odom", "base_link", t, (t / S, 0, 0), (0, 0, 0, 1))
    assert buf.lookup("odom", "base_link", S // 4) is not None
    assert buf.lookup("odom", "base_link", 2 * S) is None
    assert "gap of 2.500 s" in buf.why_not("odom", "base_link", 2 * S)
    loose = TfBuffer(max_gap_ns=None)
    for t in (0, 3 * S):
        loose.add("odom", "base_link", t, (t / S, 0, 0), (0, 0, 0, 1))
    got = loose.lookup("odom", "base_link", 2 * S)
    assert got is not None
    np.testing.assert_allclose(got.translation, [2, 0, 0])


def test_unknown_and_unconnected_frames_have_reasons() -> None:
    buf = robot_buffer()
    buf.add("world", "gps", 0, (0, 0, 0), (0, 0, 0, 1), static=True)
    assert buf.lookup("map", "velodyne", 0) is None
    assert buf.why_not("map", "velodyne", 0).startswith("frame 'velodyne' is not in the tf data")
    assert buf.lookup("map", "gps", 0) is None
    reason = buf.why_not("map", "/gps", 0)
    assert "not connected" in reason
    assert "'gps' hangs from 'world'" in reason
    assert "'map' from 'map'" in reason
    valid, rot, _ = buf.lookup_many("map", "gps", [0, 1])
    assert not valid.any()
    assert np.isnan(rot).all()


def test_parent_conflicts_loops_and_bad_samples_are_counted() -> None:
    buf = robot_buffer()
    for t in range(3):
        buf.add("odom_alt", "base_link", t, (0, 0, 0), (0, 0, 0, 1))  # a second parent
    buf.add("odom", "base_link", 0, (0, 0, 0), (0, 0, 0, 1), static=True)  # static vs dynamic
    buf.add("laser", "map", 0, (0, 0, 0), (0, 0, 0, 1))  # would close a loop
    buf.add("", "x", 0, (0, 0, 0), (0, 0, 0, 1))
    buf.add("x", "/x", 0, (0, 0, 0), (0, 0, 0, 1))
    buf.add("a", "b", 0, (0, 0, 0), (0, 0, 0, 0))
    buf.add("a", "b", 0, (np.nan, 0, 0), (0, 0, 0, 1))
    assert buf.parent("base_link") == "odom"
    assert buf.conflict_count == 5
    by_parent = {c.parent: c for c in buf.conflicts()}
    assert by_parent["odom_alt"].samples == 3
    assert by_parent["odom_alt"].kept_parent == "odom"
    assert "already has parent 'odom'" in by_parent["odom_alt"].reason
    assert by_parent["odom"].static
    assert "/tf first, then on /tf_static" in by_parent["odom"].reason
    assert "loop" in by_parent["laser"].reason
    assert by_parent["laser"].kept_parent is None
    assert buf.rejected == {
        "empty frame name": 1,
        "child frame equals its parent": 1,
        "non-finite number or zero quaternion": 2,
    }
    assert len(buf.problems()) == 6
    assert {"a", "b", "x", "odom_alt"}.isdisjoint(buf.frames())
    assert_same(buf.lookup("map", "laser", 0), manual_base_in_map(0).compose(MOUNT))


def test_frames_edges_and_fixed_frame() -> None:
    buf = robot_buffer()
    assert buf.frames() == {"map", "odom", "base_link", "laser", "imu"}
    assert buf.fixed_frame() == "map"
    edges = {(e.parent, e.child): e for e in buf.edges()}
    assert set(edges) == {
        ("map", "odom"),
        ("odom", "base_link"),
        ("base_link", "laser"),
        ("base_link", "imu"),
    }
    e = edges["odom", "base_link"]
    assert (e.static, e.samples, e.first_ns, e.last_ns) == (False, 11, 0, 10 * S)
    odom_only = TfBuffer()
    odom_only.add("odom", "base_link", 0, (0, 0, 0), (0, 0, 0, 1))
    assert odom_only.fixed_frame() == "odom"
    other = TfBuffer()
    other.add("world", "base_link", 0, (0, 0, 0), (0, 0, 0, 1))
    assert other.fixed_frame() is None


def test_new_samples_after_a_lookup_rebuild_the_track() -> None:
    buf = TfBuffer()
    buf.add("odom", "base_link", 0, (0, 0, 0), (0, 0, 0, 1))
    buf.add("odom", "base_link", S // 2, (1, 0, 0), (0, 0, 0, 1))
    assert buf.lookup("odom", "base_link", S) is None
    buf.add("odom", "base_link", S, (2, 0, 0), (0, 0, 0, 1))
    buf.add("odom", "base_link", S // 2, (5, 0, 0), (0, 0, 0, 1))  # same time again: newest wins
    got = buf.lookup("odom", "base_link", S)
    assert got is not None
    np.testing.assert_array_equal(got.translation, [2, 0, 0])
    half = buf.lookup("odom", "base_link", S // 2)
    assert half is not None
    np.testing.assert_array_equal(half.translation, [5, 0, 0])
    assert buf.edges()[0].samples == 3


def test_lookup_many_matches_single_lookups() -> None:
    buf = robot_buffer()
    times = np.array([-S, 0, S // 3, 5 * S + 17, 10 * S, 10 * S + 1])
    valid, rot, tr = buf.lookup_many("imu", "/map", times)
    np.testing.assert_array_equal(valid, [False, True, True, True, True, False])
    for k, t in enumerate(times):
        one = buf.lookup("imu", "map", int(t))
        if valid[k]:
            assert one is not None
            np.testing.assert_allclose(one.rotation, rot[k], atol=1e-15)
            np.testing.assert_allclose(one.translation, tr[k], atol=1e-15)
        else:
            assert one is None
            assert np.isnan(tr[k]).all()
    # static-only paths broadcast to every time
    valid, rot, _ = buf.lookup_many("base_link", "laser", [1, 2, 3])
    assert valid.all()
    np.testing.assert_allclose(rot, np.broadcast_to(MOUNT.rotation, (3, 3, 3)), atol=1e-15)


def test_add_many_and_add_track() -> None:
    track = PoseTrack(
        [0, S],
        [[0, 0, 0], [2, 0, 0]],
        [[0, 0, 0, 1]] * 2,
        frame_id="odom",
        child_frame_id="base_footprint",
    )
    buf = TfBuffer()
    buf.add_track(track)
    buf.add_many(
        "base_footprint",
        "lidar",
        [0, S, 2 * S],
        np.zeros((3, 3)),
        [[0, 0, 0, 1], [0, 0, 0, 1], [0, 0, 0, 0]],
    )  # the last row is refused
    got = buf.lookup("odom", "lidar", S // 2)
    assert got is not None
    np.testing.assert_allclose(got.translation, [1, 0, 0])
    assert buf.rejected == {"non-finite number or zero quaternion": 1}
    # single samples and arrays interleaved: the newest of equal times wins
    buf.add("base_footprint", "lidar", S, (7, 0, 0), (0, 0, 0, 1))
    buf.add_many("base_footprint", "lidar", [S], [[8, 0, 0]], [[0, 0, 0, 1]])
    buf.add("base_footprint", "lidar", 2 * S, (9, 0, 0), (0, 0, 0, 1))
    newest = buf.lookup("base_footprint", "lidar", S)
    assert newest is not None
    np.testing.assert_array_equal(newest.translation, [8, 0, 0])
    with pytest.raises(ValueError, match="times_ns"):
        buf.add_many("a", "b", [0.5], [[0, 0, 0]], [[0, 0, 0, 1]])


# ------------------------------------------------------------------------ rosbags messages


def tf_message(ts: Any, items: list[tuple[str, str, int, tuple[float, ...], Any]]) -> Any:
    """A TFMessage of (parent, child, t_ns, xyz, xyzw) in typestore ``ts``."""
    t = ts.types
    header_fields = t["std_msgs/msg/Header"].__dataclass_fields__
    out = []
    for parent, child, stamp, xyz, q in items:
        time = t["builtin_interfaces/msg/Time"](sec=stamp // S, nanosec=stamp % S)
        header = (
            t["std_msgs/msg/Header"](seq=0, stamp=time, frame_id=parent)
            if "seq" in header_fields
            else t["std_msgs/msg/Header"](stamp=time, frame_id=parent)
        )
        transform = t["geometry_msgs/msg/Transform"](
            translation=t["geometry_msgs/msg/Vector3"](*map(float, xyz)),
            rotation=t["geometry_msgs/msg/Quaternion"](*map(float, q)),
        )
        out.append(t["geometry_msgs/msg/TransformStamped"](header, child, transform))
    return t["tf2_msgs/msg/TFMessage"](transforms=out)


def test_add_message_with_rosbags_types() -> None:
    buf = TfBuffer()
    for k in range(3):
        msg = tf_message(
            TS2,
            [
                ("map", "odom", k * S, (0, 0, 0), (0, 0, 0, 1)),
                ("odom", "base_link", k * S + 7, (k, 0, 0), yaw_quaternion(0.1 * k)),
            ],
        )
        buf.add_message(msg, static=False)
    buf.add_message(tf_message(TS2, [("base_link", "laser", 0, (0, 0, 1), (0, 0, 0, 1))]), True)
    # a zero stamp falls back to the bag time when one is given
    buf.add_message(
        tf_message(TS2, [("base_link", "cam", 0, (0, 1, 0), (0, 0, 0, 1))]),
        False,
        bag_time_ns=2 * S,
    )
    got = buf.lookup("map", "laser", S + 7)
    assert_same(got, Transform.from_quaternion((1, 0, 1), yaw_quaternion(0.1)))
    (cam,) = (e for e in buf.edges() if e.child == "cam")
    assert cam.first_ns == 2 * S


def test_tf_from_ros1_and_ros2_bags(tmp_path: Path) -> None:
    """tf read back from bags written with rosbags: ROS 1 names with slashes, ROS 2 mcap."""
    ts1 = get_typestore(Stores.ROS1_NOETIC)
    ts1.register(
        get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage")
    )
    kind = "tf2_msgs/msg/TFMessage"
    ros1 = tmp_path / "run.bag"
    with Writer1(ros1) as w:
        tf = w.add_connection("/tf", kind, typestore=ts1)
        static = w.add_connection("/tf_static", kind, typestore=ts1)
        w.write(
            static,
            0,
            ts1.serialize_ros1(
                tf_message(ts1, [("/base_link", "/laser", 0, (0, 0, 1), (0, 0, 0, 1))]), kind
            ),
        )
        for k in range(5):
            msg = tf_message(ts1, [("/odom", "/base_link", k * S, (k, 0, 0), (0, 0, 0, 1))])
            w.write(tf, k * S + 1, ts1.serialize_ros1(msg, kind))
    ros2 = tmp_path / "run2"
    with Writer2(ros2, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        tf = w.add_connection("/tf", kind, typestore=TS2)
        static = w.add_connection("/tf_static", kind, typestore=TS2)
        w.write(
            static,
            0,
            TS2.serialize_cdr(
                tf_message(TS2, [("base_link", "laser", 0, (0, 0, 1), (0, 0, 0, 1))]), kind
            ),
        )
        for k in range(5):
            msg = tf_message(TS2, [("odom", "base_link", k * S, (k, 0, 0), (0, 0, 0, 1))])
            w.write(tf, k * S + 1, TS2.serialize_cdr(msg, kind))
    for path in (ros1, ros2):
        buf = TfBuffer()
        with AnyReader([path], default_typestore=TS2) as reader:
            for conn, t_ns, raw in reader.messages():
                msg = reader.deserialize(raw, conn.msgtype)
                buf.add_message(msg, static=conn.topic == "/tf_static", bag_time_ns=t_ns)
        assert buf.frames() == {"odom", "base_link", "laser"}
        got = buf.lookup("odom", "laser", 5 * S // 2)
        assert got is not None
        np.testing.assert_allclose(got.translation, [2.5, 0, 1])


# -------------------------------------------------------------------------------- odometry


def odometry_message(stamp: int, frame: str, child: str, xyz: tuple[float, ...], q: Any) -> Any:
    t = TS2.types
    pose = t["geometry_msgs/msg/PoseWithCovariance"](
        pose=t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](*map(float, xyz)),
            orientation=t["geometry_msgs/msg/Quaternion"](*map(float, q)),
        ),
        covariance=np.zeros(36),
    )
    twist = t["geometry_msgs/msg/TwistWithCovariance"](
        twist=t["geometry_msgs/msg/Twist"](
            linear=t["geometry_msgs/msg/Vector3"](0.0, 0.0, 0.0),
            angular=t["geometry_msgs/msg/Vector3"](0.0, 0.0, 0.0),
        ),
        covariance=np.zeros(36),
    )
    header = t["std_msgs/msg/Header"](
        stamp=t["builtin_interfaces/msg/Time"](sec=stamp // S, nanosec=stamp % S), frame_id=frame
    )
    return t["nav_msgs/msg/Odometry"](header=header, child_frame_id=child, pose=pose, twist=twist)


def test_odometry_with_empty_child_and_zero_stamps() -> None:
    msgs = [
        odometry_message(k * S if k != 2 else 0, "/odom", "", (k, 2 * k, 0), yaw_quaternion(k))
        for k in range(1, 5)
    ]
    bag_times = [k * S + 5 for k in range(1, 5)]
    track = odometry_track(bag_times, msgs)
    assert (track.frame_id, track.child_frame_id) == ("odom", "base_link")
    np.testing.assert_array_equal(track.times_ns, [S, 2 * S + 5, 3 * S, 4 * S])  # bag time for 0
    np.testing.assert_array_equal(track.translations[:, 1], [2, 4, 6, 8])
    assert track.max_gap_ns == DEFAULT_MAX_GAP_NS
    named = odometry_track(bag_times, msgs, default_child_frame="base_footprint")
    assert named.child_frame_id == "base_footprint"


def test_odometry_from_arrays() -> None:
    arrays = OdometryArrays(
        np.array([0, 0, 2 * S]),
        np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], dtype=float),
        np.tile([0.0, 0, 0, 1], (3, 1)),
        child_frame_id="chassis",
    )
    track = odometry_track([0, S, 2 * S], arrays, max_gap_ns=None)
    assert (track.frame_id, track.child_frame_id) == ("odom", "chassis")
    np.testing.assert_array_equal(track.times_ns, [0, S, 2 * S])


def test_odometry_errors_name_the_source() -> None:
    one = odometry_message(0, "odom", "base_link", (0, 0, 0), (0, 0, 0, 1))
    two = odometry_message(S, "map", "base_link", (0, 0, 0), (0, 0, 0, 1))
    with pytest.raises(InputError, match=r"run\.bag:/odom: odometry messages name different"):
        odometry_track([0, S], [one, two], source="run.bag:/odom")
    with pytest.raises(InputError, match="no odometry messages"):
        odometry_track([], [])
    with pytest.raises(InputError, match="2 bag times for 1"):
        odometry_track([0, 1], [one])
    zero = odometry_message(0, "odom", "", (0, 0, 0), (0, 0, 0, 0))
    with pytest.raises(InputError, match="quaternion"):
        odometry_track([0], [zero])


# ------------------------------------------------------------------------------------- TUM


def test_read_tum(tmp_path: Path) -> None:
    path = tmp_path / "traj.txt"
    path.write_text(
        "# timestamp tx ty tz qx qy qz qw\n"
        "\n"
        "1700000001.5 1 2 3 0 0 0 1\n"
        "1700000000.25\t0 0 0 0 0 0 2   # not normalised, tab separated\n"
        "1700000003.0 4 5 6 0 0 0.7071067811865476 0.7071067811865476\n"
    )
    track = read_tum(path)
    np.testing.assert_array_equal(
        track.times_ns, [1_700_000_000_250_000_000, 1_700_000_001_500_000_000, 1_700_000_003 * S]
    )
    np.testing.assert_array_equal(track.translations[1], [1, 2, 3])
    np.testing.assert_allclose(track.quaternions_xyzw[0], [0, 0, 0, 1])
    assert track.max_gap_ns is None
    got = track.at(1_700_000_003 * S)
    assert_same(got, Transform.from_quaternion((4, 5, 6), (0, 0, 1, 1)))


def test_read_tum_times_are_exact_nanoseconds(tmp_path: Path) -> None:
    path = tmp_path / "traj.txt"
    path.write_text(
        "1700000000.123456789 0 0 0 0 0 0 1\n"
        "1700000000.9876543219 0 0 0 0 0 0 1\n"  # beyond 9 decimals: truncated
        "+1700000001 0 0 0 0 0 0 1\n"
        "1.700000002e9 0 0 0 0 0 0 1\n"  # exponent notation goes through the float
        "-0.5 0 0 0 0 0 0 1\n"
        ".25 0 0 0 0 0 0 1\n"
    )
    np.testing.assert_array_equal(
        read_tum(path).times_ns,
        [
            -S // 2,
            S // 4,
            1_700_000_000_123_456_789,
            1_700_000_000_987_654_321,
            1_700_000_001 * S,
            1_700_000_002 * S,
        ],
    )


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("", "no poses"),
        ("# only a comment\n\n", "no poses"),
        ("0 0 0 0 0 0 0 1\n1 0 0 0 0 0 1\n", "line 2 has 7 columns, expected 8"),
        ("# c\n0 0 0 0 0 0 0 1 9\n", "line 2 has 9 columns"),
        ("0 0 0 0 0 0 0 1\n1 0 0 x 0 0 0 1\n", "line 2: 'x' is not a number"),
        ("0 0 0 0 0 0 0 1\n1 0 0 nan 0 0 0 1\n", "line 2 holds a NaN or infinity"),
        ("0 0 0 0 0 0 0 1\n\n1 0 0 0 0 0 0 0\n", "line 3 has a zero quaternion"),
        ("5 0 0 0 0 0 0 1\n", "one time only"),
        ("5 0 0 0 0 0 0 1\n5 1 0 0 0 0 0 1\n", "2 pose\\(s\\) at one time only"),
        ("1e12 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n", "line 1: time out of range"),
    ],
)
def test_read_tum_bad_files(tmp_path: Path, text: str, problem: str) -> None:
    path = tmp_path / "bad.txt"
    path.write_text(text)
    with pytest.raises(InputError, match=problem) as info:
        read_tum(path)
    assert info.value.path == path
    assert "\n" not in str(info.value)


def test_read_tum_unreadable(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no such file"):
        read_tum(tmp_path / "missing.txt")
    with pytest.raises(InputError, match="is a folder"):
        read_tum(tmp_path)
    binary = tmp_path / "b.txt"
    binary.write_bytes(b"\xff\xfe\x00\x01")
    with pytest.raises(InputError, match="not a text file"):
        read_tum(binary)


# ----------------------------------------------------------------------------- fixed poses


def test_rpy_is_ros_fixed_axes() -> None:
    roll, pitch, yaw = 0.3, -0.7, 2.1
    ref = Rotation.from_euler("xyz", [roll, pitch, yaw]).as_matrix()  # extrinsic x, y, z
    np.testing.assert_allclose(rpy_matrix(roll, pitch, yaw), ref, atol=1e-15)
    rx = Rotation.from_euler("x", roll).as_matrix()
    ry = Rotation.from_euler("y", pitch).as_matrix()
    rz = Rotation.from_euler("z", yaw).as_matrix()
    np.testing.assert_allclose(rpy_matrix(roll, pitch, yaw), rz @ ry @ rx, atol=1e-15)


def test_fixed_pose_and_mount() -> None:
    sensor = fixed_pose(1, 2, 3, yaw=math.pi / 2)
    np.testing.assert_allclose(sensor.apply(np.array([[1.0, 0, 0]])), [[1, 3, 3]], atol=1e-15)
    base = Transform.from_quaternion((10, 0, 0), yaw_quaternion(math.pi))
    lidar = base.compose(mount(0.5, 0, 1))
    np.testing.assert_allclose(lidar.translation, [9.5, 0, 1], atol=1e-12)
    with pytest.raises(ValueError, match="pitch"):
        mount(0, 0, 0, pitch=math.inf)
    with pytest.raises(ValueError, match="z"):
        fixed_pose(0, 0, math.nan)


# ------------------------------------------------------------------------------ properties

FRAMES = ["f0", "f1", "f2", "f3", "f4", "f5"]


@st.composite
def random_trees(draw: st.DrawFn) -> tuple[TfBuffer, list[int]]:
    """A random tree over FRAMES, each edge static or dynamic with random samples in 0..10 s."""
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    buf = TfBuffer(max_gap_ns=None)
    for i in range(1, len(FRAMES)):
        parent = FRAMES[draw(st.integers(0, i - 1))]
        if draw(st.booleans()):
            q = random_quaternions(rng, 1)[0]
            buf.add(parent, FRAMES[i], 0, rng.normal(size=3), q, static=True)
        else:
            n = draw(st.integers(2, 6))
            samples = np.concatenate([[0, 10 * S], rng.integers(0, 10 * S, n)])
            buf.add_many(
                parent,
                FRAMES[i],
                samples,
                rng.normal(size=(n + 2, 3)) * 5,
                random_quaternions(rng, n + 2),
            )
    times = draw(st.lists(st.integers(0, 10 * S), min_size=1, max_size=5))
    return buf, times


@settings(max_examples=60, deadline=None)
@given(random_trees(), st.sampled_from(FRAMES), st.sampled_from(FRAMES), st.sampled_from(FRAMES))
def test_lookups_invert_and_chain(tree: tuple[TfBuffer, list[int]], a: str, b: str, c: str) -> None:
    buf, times = tree
    for t in times:
        ab, ba = buf.lookup(a, b, t), buf.lookup(b, a, t)
        bc, ac = buf.lookup(b, c, t), buf.lookup(a, c, t)
        assert ab is not None
        assert ba is not None
        assert bc is not None
        assert ac is not None
        assert_same(ab.compose(ba), Transform.identity(), atol=1e-9)
        assert_same(ab.compose(bc), ac, atol=1e-9)
        r = ab.rotation
        np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)


# --- rotation matrices back to quaternions; the sample times between two frames ------------------


def test_matrices_to_quaternions_inverts_scipy() -> None:
    from scan2terrain.readers.poses import matrices_to_quaternions

    rot = Rotation.random(2000, random_state=5)
    q = rot.as_quat()  # xyzw
    q[:4] = np.eye(4)  # 180-degree turns about x, y, z, and the identity: each branch
    q = np.where(q[:, 3:4] < 0, -q, q)
    got = matrices_to_quaternions(Rotation.from_quat(q).as_matrix())
    assert (got[:, 3] >= 0).all()
    # the same rotation (q and -q are one when w = 0)
    dots = np.abs(np.einsum("ij,ij->i", got, q))
    np.testing.assert_allclose(dots, 1.0, rtol=0, atol=1e-15)


def test_sample_times_are_the_dynamic_edges_between_two_frames() -> None:
    buf = TfBuffer()
    buf.add("map", "odom", 10, (0, 0, 0), (0, 0, 0, 1))
    buf.add("map", "odom", 30, (0, 0, 0), (0, 0, 0, 1))
    for t in (5, 10, 20, 40):
        buf.add("odom", "base_link", t, (t, 0, 0), (0, 0, 0, 1))
    buf.add("base_link", "laser", 0, (0.2, 0, 0), (0, 0, 0, 1), static=True)
    buf.add("map", "gps", 7, (0, 0, 0), (0, 0, 0, 1))
    assert buf.sample_times("map", "laser").tolist() == [5, 10, 20, 30, 40]
    assert buf.sample_times("laser", "base_link").tolist() == []  # a static edge only
    assert buf.sample_times("gps", "odom").tolist() == [7, 10, 30]
    assert buf.sample_times("map", "nowhere").tolist() == []


def test_tf_samples_beyond_the_earth_are_counted_not_used() -> None:
    """A flipped byte made a tf translation 3.5e76 m: the sample is refused like a NaN (one of
    many in a recording), the others are used."""
    buf = TfBuffer()
    buf.add("odom", "base_link", 0, (0, 0, 0), (0, 0, 0, 1))
    buf.add("odom", "base_link", S // 2, (3.5e76, 0, 0), (0, 0, 0, 1))
    buf.add("odom", "base_link", S, (2, 0, 0), (0, 0, 0, 1))
    buf.add_many("base_link", "laser", [0, S, 2 * S], [[0.0, 0, 1e9], [0.0, 0, -2e9], [0.0, 0, 1]],
                 [[0, 0, 0, 1]] * 3)  # fmt: skip
    assert buf.rejected == {"translation beyond 1e+09 m": 2}
    assert "tf: 2 sample(s) ignored: translation beyond 1e+09 m" in buf.problems()
    got = buf.lookup("odom", "base_link", S // 2)
    assert got is not None
    np.testing.assert_allclose(got.translation, [1, 0, 0])


def test_a_track_beyond_the_earth_is_refused() -> None:
    with pytest.raises(ValueError, match=r"within 1e\+09 m, not -2e\+09 \(row 2, z\)"):
        PoseTrack([0, 1], [[0.0, 0, 0], [0.0, 0, -2e9]], [[0, 0, 0, 1]] * 2)
