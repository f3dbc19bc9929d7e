"""CARMEN logs read as recordings (issue 27 item 7): :mod:`scan2terrain.readers.carmen` through
``open_bag``, record type by record type, on logs written here as text; the bundled MIT CSAIL log
against the test helper's own geometry. The command-level tests are in
tests/test_bag2world_carmen.py."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from scan2terrain.config import ScansConfig
from scan2terrain.errors import InputError
from scan2terrain.readers import _carmen_records
from scan2terrain.readers.bag import open_bag
from scan2terrain.readers.carmen import RANGE_MIN, LaserScan, Odometry
from scan2terrain.readers.points import hits_of
from scan2terrain.readers.scans import plan_bag, posed_scans, read_tf
from scan2terrain.types import ScanCounts
from tests.carmen import (
    DAMAGED,
    DEFAULT_LOG,
    GOOD,
    ODOM,
    RANGES,
    T0,
    Pose,
    carmen_scans,
    compose,
    damaged_log,
    flaser,
    ns,
    odom_line,
    read_carmen,
    robotlaser,
    write,
)


def raw_log(tmp: Path, mount: Pose = (0.2, 0.0, 0.0), *, param: bool = True) -> Path:
    lines = ["# CARMEN Logfile", "# file format is one message per line"]
    if param:
        lines.append(f"PARAM robot_frontlaser_offset {mount[0]} nohost 0")
    lines += [
        flaser(RANGES, compose(p, mount), p, T0 + 0.2 * k) for k, p in enumerate(ODOM)
    ]  # fmt: skip
    return write(tmp / "raw.clf", lines)


def messages(path: Path, topic: str) -> list[tuple[int, Any]]:
    with open_bag(path) as bag:
        return [(t, m) for _, t, m in bag.messages(topic)]


def scans(path: Path, cfg: ScansConfig | None = None) -> list[Any]:
    cfg = cfg or ScansConfig()
    with open_bag(path) as bag:
        plan = plan_bag(bag, cfg)
        return list(posed_scans(bag, cfg, plan, ScanCounts()))


# --- record types -------------------------------------------------------------------------------


def test_flaser_records_are_laserscans_odometry_and_a_mount(tmp_path: Path) -> None:
    path = raw_log(tmp_path)
    with open_bag(path) as bag:
        assert {n: (t.msgtype, t.count) for n, t in bag.topics.items()} == {
            "/odom": ("nav_msgs/msg/Odometry", 6),
            "/scan": ("sensor_msgs/msg/LaserScan", 6),
            "/tf_static": ("tf2_msgs/msg/TFMessage", 1),
        }
        assert bag.container.kind == "CARMEN log"
        assert bag.start_ns == 1_134_864_629_500_000_000
        assert bag.frame_ids("/scan") == {"laser"}
        plan = plan_bag(bag, ScansConfig())
        tf = read_tf(bag, ScansConfig())
    scan = messages(path, "/scan")
    assert [t for t, _ in scan] == [1_134_864_629_500_000_000 + 200_000_000 * k for k in range(6)]
    msg = scan[2][1]
    assert isinstance(msg, LaserScan)
    assert msg.header.frame_id == "laser"
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1_134_864_629, 900_000_000)
    assert msg.ranges.dtype == np.float32
    np.testing.assert_array_equal(msg.ranges, np.array(RANGES, np.float32))
    # 5 readings: CARMEN's spacing for a count it does not know, 180 degrees over n - 1 steps
    assert (msg.angle_min, msg.angle_increment) == (-math.pi / 2, math.pi / 4)
    assert msg.angle_max == pytest.approx(math.pi / 2)
    assert (msg.range_min, msg.range_max) == (RANGE_MIN, 80.0)
    odom = messages(path, "/odom")[3][1]
    assert isinstance(odom, Odometry)
    assert (odom.header.frame_id, odom.child_frame_id) == ("odom", "base_link")
    p = odom.pose.pose
    assert (p.position.x, p.position.y) == pytest.approx(ODOM[3][:2])
    assert 2 * math.atan2(p.orientation.z, p.orientation.w) == pytest.approx(ODOM[3][2])
    mount = tf.lookup("base_link", "laser", bag.start_ns)
    assert mount is not None
    np.testing.assert_allclose(mount.translation, [0.2, 0.0, 0.0])
    assert plan.poses == "odom" and plan.odom_topic == "/odom" and plan.fixed_frame == "odom"
    reasons = "\n".join(plan.reasons)
    assert "mount of laser on base_link (/tf_static): PARAM robot_frontlaser_offset 0.2" in reasons
    assert "raw CARMEN log" in reasons and "no map frame" in reasons


def test_raw_log_scans_land_at_the_logged_laser_poses(tmp_path: Path) -> None:
    mount = (0.2, -0.05, 0.1)
    lines = [
        "PARAM robot_frontlaser_offset 0.2",
        "PARAM robot_frontlaser_side_offset -0.05 nohost 0",
        "PARAM robot_frontlaser_angular_offset 0.1 nohost 0",
    ]
    lines += [flaser(RANGES, compose(p, mount), p, T0 + 0.2 * k) for k, p in enumerate(ODOM)]
    got = scans(write(tmp_path / "x.log", lines))
    assert len(got) == 6
    for k, s in enumerate(got):
        laser = compose(ODOM[k], mount)
        np.testing.assert_allclose(s.origin, [laser[0], laser[1], 0.0], atol=1e-12)
        assert s.heading == pytest.approx(laser[2])
        # reading 0 at -90 degrees from the laser's heading, 1 m away
        a = laser[2] - math.pi / 2
        np.testing.assert_allclose(s.points[0], [laser[0] + math.cos(a), laser[1] + math.sin(a), 0])


def test_mount_from_the_records_when_no_param(tmp_path: Path) -> None:
    path = raw_log(tmp_path, (0.22, 0.01, 0.0), param=False)
    with open_bag(path) as bag:
        tf = read_tf(bag, ScansConfig())
        mount = tf.lookup("base_link", "laser", bag.start_ns)
        notes = bag.container.notes
    assert mount is not None
    np.testing.assert_allclose(mount.translation, [0.22, 0.01, 0.0], atol=2e-6)
    assert any("the records' laser pose less their odometry pose" in n for n in notes)


def test_a_param_mount_the_records_disagree_with_is_used_and_reported(tmp_path: Path) -> None:
    lines = ["PARAM robot_frontlaser_offset 0.3 nohost 0"]  # the records say 0.2
    lines += [flaser(RANGES, compose(p, (0.2, 0, 0)), p, T0 + 0.2 * k) for k, p in enumerate(ODOM)]
    path = write(tmp_path / "x.clf", lines)
    with open_bag(path) as bag:
        notes = bag.container.notes
    assert notes[0] == (
        "mount of laser on base_link (/tf_static): PARAM robot_frontlaser_offset 0.3 (x 0.3 m, "
        "y 0 m, yaw 0 rad) (the records put the laser 0.100 m, 0.000 rad from there, the same on "
        "every record: the PARAM is used)"
    )
    assert notes[1].startswith("raw CARMEN log")
    for s, p in zip(scans(path), ODOM, strict=True):
        np.testing.assert_allclose(s.origin[:2], compose(p, (0.3, 0, 0))[:2], atol=1e-6)


def test_params_give_fov_resolution_and_max_range(tmp_path: Path) -> None:
    lines = [
        "PARAM laser_front_laser_fov 100 nohost 0",
        "PARAM laser_front_laser_resolution 0.25 nohost 0",
        "PARAM robot_front_laser_max 3.5 nohost 0",
        flaser(RANGES, ODOM[0], ODOM[0], T0),
    ]
    ((_, msg),) = messages(write(tmp_path / "p.clf", lines), "/scan")
    assert msg.angle_min == pytest.approx(math.radians(-50))
    assert msg.angle_increment == pytest.approx(math.radians(0.25))
    assert msg.range_max == 3.5


def test_rlaser_is_the_rear_scan_with_its_own_mount(tmp_path: Path) -> None:
    rear = (-0.3, 0.0, math.pi)
    lines = [
        "PARAM robot_rearlaser_offset -0.3 nohost 0",
        f"PARAM robot_rearlaser_angular_offset {math.pi} nohost 0",
    ]
    for k, p in enumerate(ODOM):
        lines.append(flaser(RANGES, p, p, T0 + 0.2 * k))
        lines.append(flaser(RANGES[:4], compose(p, rear), p, T0 + 0.2 * k + 0.1, "RLASER"))
    path = write(tmp_path / "two.clf", lines)
    with open_bag(path) as bag:
        assert bag.topics["/rear_scan"].count == 6
        assert bag.frame_ids("/rear_scan") == {"rear_laser"}
        tf = read_tf(bag, ScansConfig())
        with pytest.raises(InputError, match="several scan topics"):
            plan_bag(bag, ScansConfig())
    mount = tf.lookup("base_link", "rear_laser", tf.edges()[0].first_ns)
    assert mount is not None
    np.testing.assert_allclose(mount.translation, [-0.3, 0.0, 0.0])
    assert math.atan2(mount.rotation[1, 0], mount.rotation[0, 0]) == pytest.approx(math.pi)
    # /odom from both lasers' records, in time order
    assert len(messages(path, "/odom")) == 12
    got = scans(path, ScansConfig(topics=["/scan", "/rear_scan"]))
    assert [s.topic for s in got] == ["/scan", "/rear_scan"] * 6
    rear_scan = got[3]
    laser = compose(ODOM[1], rear)
    np.testing.assert_allclose(rear_scan.origin[:2], laser[:2], atol=1e-12)
    assert len(rear_scan.points) == 4


def test_robotlaser1_carries_its_geometry_and_gives_the_mount(tmp_path: Path) -> None:
    mount = (0.22, 0.0, 0.0)
    lines = [
        robotlaser(RANGES, compose(p, mount), p, T0 + 0.2 * k, remissions=[7, 8, 9, 1, 2])
        for k, p in enumerate(ODOM)
    ]
    lines[3] = robotlaser(
        [*RANGES, 6.0], compose(ODOM[3], mount), ODOM[3], T0 + 0.6, start=-1.0, res=0.3
    )
    path = write(tmp_path / "rl.clf", lines)
    with open_bag(path) as bag:
        assert set(bag.topics) == {"/odom", "/scan", "/tf_static"}
        tf = read_tf(bag, ScansConfig())
    msgs = [m for _, m in messages(path, "/scan")]
    assert (msgs[0].angle_min, msgs[0].angle_increment) == pytest.approx(
        (-math.pi / 2, math.radians(45))
    )
    assert (msgs[3].angle_min, msgs[3].angle_increment, len(msgs[3].ranges)) == (-1.0, 0.3, 6)
    assert msgs[0].range_max == 30.0
    m = tf.lookup("base_link", "laser", msgs[0].header.stamp.sec * 10**9)
    assert m is not None
    np.testing.assert_allclose(m.translation, [0.22, 0.0, 0.0], atol=2e-6)


def test_robotlaser2_is_the_rear_scan_and_flaser_beside_robotlaser1_gets_its_own_topic(
    tmp_path: Path,
) -> None:
    lines = []
    for k, p in enumerate(ODOM):
        lines.append(flaser(RANGES, p, p, T0 + 0.2 * k))
        lines.append(robotlaser(RANGES, p, p, T0 + 0.2 * k + 0.05))
        lines.append(robotlaser(RANGES, p, p, T0 + 0.2 * k + 0.1, kind="ROBOTLASER2"))
    with open_bag(write(tmp_path / "all.clf", lines)) as bag:
        assert {n: bag.frame_ids(n) for n in bag.topics if "scan" in n or "laser" in n} == {
            "/scan": {"laser"},
            "/robotlaser1": {"robotlaser1"},
            "/rear_scan": {"rear_laser"},
        }


def test_odom_records_give_the_odometry(tmp_path: Path) -> None:
    lines = [odom_line((0.05 * k, 0.0, 0.0), T0 + 0.1 * k) for k in range(12)]
    lines += [flaser(RANGES, (0.1 * k, 0, 0), (0.1 * k, 0, 0), T0 + 0.2 * k) for k in range(6)]
    path = write(tmp_path / "o.clf", lines)
    odom = messages(path, "/odom")
    assert len(odom) == 12
    assert odom[5][1].pose.pose.position.x == pytest.approx(0.25)
    with open_bag(path) as bag:
        assert "the ODOM records" in bag.container.encodings["/odom"]
    got = scans(path)
    np.testing.assert_allclose([s.origin[0] for s in got], [0.1 * k for k in range(6)])


def test_unknown_records_are_skipped_and_counted(tmp_path: Path) -> None:
    lines = [
        "SYNC tag 1.0 host 1.0",
        "TRUEPOS 1 2 3 1 2 3 1.0 host 1.0",
        "NMEAGGA 1 2 3 N 4 E 1 2 3 4 5 6 7 8 1.0 host 1.0",
        "PARAM robot_use_laser on nohost 0",
        flaser(RANGES, ODOM[0], ODOM[0], T0),
    ]
    with open_bag(write(tmp_path / "u.clf", lines)) as bag:
        assert set(bag.topics) == {"/odom", "/scan", "/tf_static"}
        assert bag.container.describe() == (
            "CARMEN log (5 lines; not used: NMEAGGA 1, PARAM 1, SYNC 1, TRUEPOS 1), read with "
            "scan2terrain (text, line by line)"
        )


# --- no return ----------------------------------------------------------------------------------


def no_return_scan(tmp: Path, lines: list[str]) -> Any:
    ((s,),) = [scans(write(tmp / "nr.clf", lines))]
    return s


def test_readings_at_or_beyond_range_max_clear_and_are_not_hits(tmp_path: Path) -> None:
    ranges = [1.0, 81.91, 80.0, 79.99, 2.0]  # default range_max 80 (CARMEN's)
    s = no_return_scan(tmp_path, [flaser(ranges, ODOM[0], ODOM[0], T0)])
    hits = hits_of(s)
    np.testing.assert_allclose(np.linalg.norm(hits[:, :2], axis=1), [1.0, 79.99, 2.0], rtol=1e-6)
    assert len(s.points) == 5  # the two no-return beams clear, up to range_max
    assert s.max_range == pytest.approx(80.0, rel=1e-4)
    with open_bag(tmp_path / "nr.clf") as bag:
        assert "range_max 80 m (CARMEN's default" in bag.container.encodings["/scan"]


def test_param_max_range_is_the_no_return_limit(tmp_path: Path) -> None:
    lines = ["PARAM robot_front_laser_max 10.0 nohost 0"]
    s = no_return_scan(tmp_path, [*lines, flaser([1.0, 10.0, 9.99, 12.0], ODOM[0], ODOM[0], T0)])
    np.testing.assert_allclose(np.linalg.norm(hits_of(s)[:, :2], axis=1), [1.0, 9.99], rtol=1e-6)


def test_sick_error_codes_are_no_return_below_a_robotlaser_max_range(tmp_path: Path) -> None:
    ranges = [1.0, 81.83, 81.91, 81.5, 2.0]
    line = robotlaser(ranges, ODOM[0], ODOM[0], T0, max_range=81.9, laser_type=0)
    s = no_return_scan(tmp_path, [line])
    np.testing.assert_allclose(
        np.linalg.norm(hits_of(s)[:, :2], axis=1), [1.0, 81.5, 2.0], rtol=1e-6
    )
    hokuyo = robotlaser(ranges, ODOM[0], ODOM[0], T0, max_range=81.9, laser_type=2)
    s = no_return_scan(tmp_path, [hokuyo])  # not a SICK: its own maximum range holds
    assert len(hits_of(s)) == 4


def test_a_logs_saturated_largest_reading_is_its_no_return_value(tmp_path: Path) -> None:
    """The ACES log holds no robot_front_laser_max, and 50.0 m on one reading in 120."""
    ranges = [1.0, 50.0, 3.0, 49.9, 2.0]
    lines = [flaser(ranges, p, p, T0 + 0.2 * k) for k, p in enumerate(ODOM * 20)]
    path = write(tmp_path / "aces.clf", lines)
    s = scans(path)[0]
    np.testing.assert_allclose(
        np.linalg.norm(hits_of(s)[:, :2] - s.origin[:2], axis=1), [1.0, 3.0, 49.9, 2.0], rtol=1e-6
    )
    with open_bag(path) as bag:
        assert (
            "the log's largest reading, 120 times (20.0% of the readings): its no-return "
            in (bag.container.encodings["/scan"])
        )
    few = write(tmp_path / "few.clf", lines[:99])  # 99 readings of 50 m: no sign of a code
    assert scans(few)[0].max_range == pytest.approx(80.0, rel=1e-4)


# --- time ---------------------------------------------------------------------------------------


def test_backward_timestamps_read_in_time_order_with_their_stamps(tmp_path: Path) -> None:
    """Like the Intel log: a record stamped late, the next ones before it."""
    stamps = [0.0, 0.2, 0.75, 0.4, 0.6, 0.8]
    lines = [flaser(RANGES, p, p, T0 + dt) for p, dt in zip(ODOM, stamps, strict=True)]
    path = write(tmp_path / "back.clf", lines)
    got = messages(path, "/scan")
    want = sorted(ns(T0 + dt) for dt in stamps)
    assert [t for t, _ in got] == want
    assert [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for _, m in got] == want
    with open_bag(path) as bag:
        plan = plan_bag(bag, ScansConfig())
    assert (
        "timestamps step back: 2 FLASER (up to 0.350 s back) records stamped before one of "
        "their kind above them: read in time order, stamps as logged"
    ) in plan.reasons
    # each scan keeps its own record's pose
    posed = scans(path)
    by_stamp = {ns(T0 + dt): p for p, dt in zip(ODOM, stamps, strict=True)}
    for s in posed:
        np.testing.assert_allclose(s.origin[:2], by_stamp[s.stamp_ns][:2], atol=1e-12)


def test_a_clock_step_back_is_refused(tmp_path: Path) -> None:
    lines = [
        flaser(RANGES, p, p, T0 + dt) for p, dt in zip(ODOM, [0, 1, 2, -30, 4, 5], strict=True)
    ]
    with pytest.raises(InputError, match=r"line 4: the FLASER timestamp goes 32\.000 s back"):
        open_bag(write(tmp_path / "step.clf", lines))


def test_stamps_keep_every_digit(tmp_path: Path) -> None:
    line = flaser(RANGES, ODOM[0], ODOM[0], 0).replace(" 0.000000 host", " 1134864629.895182 host")
    ((t, msg),) = messages(write(tmp_path / "d.clf", [line]), "/scan")
    assert t == 1_134_864_629_895_182_000
    assert msg.header.stamp.nanosec == 895_182_000


# --- corrected logs -----------------------------------------------------------------------------


def test_corrected_laser_poses_give_map_to_odom_and_tf_poses(tmp_path: Path) -> None:
    """A SLAM result: the laser poses are the odometry's, corrected by a growing drift."""
    mount = (0.2, 0.0, 0.0)
    corrected = [
        compose((0.03 * k, -0.02 * k, 0.01 * k), compose(p, mount)) for k, p in enumerate(ODOM)
    ]
    lines = ["PARAM robot_frontlaser_offset 0.2 nohost 0"]
    lines += [
        flaser(RANGES, c, p, T0 + 0.2 * k)
        for k, (c, p) in enumerate(zip(corrected, ODOM, strict=True))
    ]
    path = write(tmp_path / "gfs.log", lines)
    with open_bag(path) as bag:
        assert bag.topics["/tf"].count == 6
        plan = plan_bag(bag, ScansConfig())
        tf = read_tf(bag, ScansConfig())
    assert (plan.poses, plan.fixed_frame) == ("tf", "map")
    assert {(e.parent, e.child) for e in tf.edges()} == {
        ("map", "odom"), ("odom", "base_link"), ("base_link", "laser"),
    }  # fmt: skip
    assert any(r.startswith("CARMEN log with corrected laser poses") for r in plan.reasons)
    got = scans(path)  # at the logged laser poses (6 decimals)
    for s, c in zip(got, corrected, strict=True):
        np.testing.assert_allclose(s.origin[:2], c[:2], atol=1e-6)
        assert math.remainder(s.heading - c[2], 2 * math.pi) == pytest.approx(0, abs=1e-6)
    # --poses odom: the raw odometry plus the mount instead
    raw = scans(path, ScansConfig(poses="odom"))
    for s, p in zip(raw, ODOM, strict=True):
        np.testing.assert_allclose(s.origin[:2], compose(p, mount)[:2], atol=1e-6)


def test_corrected_log_without_a_mount_uses_the_identity_and_says_so(tmp_path: Path) -> None:
    corrected = [compose((0.03 * k, 0.0, 0.02 * k), p) for k, p in enumerate(ODOM)]
    lines = [
        flaser(RANGES, c, p, T0 + 0.2 * k)
        for k, (c, p) in enumerate(zip(corrected, ODOM, strict=True))
    ]
    path = write(tmp_path / "c.clf", lines)
    with open_bag(path) as bag:
        notes = "\n".join(bag.container.notes)
    assert "not known (no PARAM robot_frontlaser_offset" in notes and "the identity" in notes
    for s, c in zip(scans(path), corrected, strict=True):
        np.testing.assert_allclose(s.origin[:2], c[:2], atol=1e-6)


# --- containers ---------------------------------------------------------------------------------


@pytest.mark.parametrize("compression", ["gz", "bz2"])
def test_gzip_and_bzip2_logs_read_as_the_plain_one(tmp_path: Path, compression: str) -> None:
    plain = raw_log(tmp_path)
    text = plain.read_text().splitlines()
    packed = write(tmp_path / f"raw.clf.{compression}", text, compression)
    unnamed = write(tmp_path / "intel_gfs", text, compression)  # recognised by its content
    want = messages(plain, "/scan")
    for path in (packed, unnamed):
        got = messages(path, "/scan")
        assert [t for t, _ in got] == [t for t, _ in want]
        for (_, g), (_, w) in zip(got, want, strict=True):
            np.testing.assert_array_equal(g.ranges, w.ranges)


def test_text_that_is_not_a_log_is_not_read_as_one(tmp_path: Path) -> None:
    path = tmp_path / "notes"
    path.write_text("hello\nworld\n")
    with pytest.raises(InputError, match="this is a text file, not a ROS bag"):
        open_bag(path)


def test_a_log_is_read_alone(tmp_path: Path) -> None:
    path = raw_log(tmp_path)
    with pytest.raises(InputError, match="a CARMEN log is read alone"):
        open_bag([path, path])


def test_a_missing_log_is_named_as_a_log(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="CARMEN log not found"):
        open_bag(tmp_path / "gone.clf.bz2")


# --- damaged input ------------------------------------------------------------------------------


@pytest.mark.parametrize("case", sorted(DAMAGED))
def test_damaged_log_is_one_error_naming_the_file_and_line(tmp_path: Path, case: str) -> None:
    path, message = damaged_log(tmp_path, case)
    with pytest.raises(InputError) as exc:
        open_bag(path)
    assert str(exc.value).startswith(f"{path}: "), exc.value
    assert message in str(exc.value)
    assert "\n" not in str(exc.value)


@pytest.mark.parametrize("compression", ["gz", "bz2"])
def test_truncated_compressed_log(tmp_path: Path, compression: str) -> None:
    lines = [flaser(RANGES * 40, p, p, T0 + 0.2 * k) for k, p in enumerate(ODOM * 20)]
    full = write(tmp_path / f"full.clf.{compression}", lines, compression)
    cut = tmp_path / f"cut.clf.{compression}"
    cut.write_bytes(full.read_bytes()[: full.stat().st_size * 2 // 3])
    name = {"gz": "gzip", "bz2": "bzip2"}[compression]
    with pytest.raises(
        InputError, match=rf"cut\.clf\.{compression}: the {name} stream is cut short"
    ):
        open_bag(cut)
    junk = tmp_path / f"junk.clf.{compression}"
    junk.write_bytes(full.read_bytes()[:20] + b"\x00" * 200)
    with pytest.raises(InputError, match=rf"the {name} stream is (damaged|cut short)"):
        open_bag(junk)


def test_a_decompression_bomb_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(_carmen_records, "MIN_ZSTD_BUDGET", 1000)
    monkeypatch.setattr(_carmen_records, "MAX_ZSTD_RATIO", 2)
    lines = [flaser(RANGES, p, p, T0 + 0.2 * k) for k, p in enumerate(ODOM * 400)]
    path = write(tmp_path / "bomb.clf.gz", lines, "gz")
    with pytest.raises(InputError, match="decompresses to more than"):
        open_bag(path)


def test_an_endless_line_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(_carmen_records, "MAX_LINE_BYTES", 1000)
    monkeypatch.setattr(_carmen_records, "BLOCK_BYTES", 256)
    path = write(tmp_path / "long.clf", [GOOD, "FLASER " + "1.0 " * 600])
    with pytest.raises(InputError, match="line 2 is longer than 1,000 bytes"):
        open_bag(path)


# --- the bundled log ----------------------------------------------------------------------------


def test_mit_csail_log_as_the_test_helper_reads_it() -> None:
    start = time.perf_counter()
    with open_bag(DEFAULT_LOG) as bag:
        opened = time.perf_counter() - start
        assert bag.topics["/scan"].count == 1988
        assert bag.duration_s == pytest.approx(424.0, abs=0.01)
        cfg = ScansConfig()
        plan = plan_bag(bag, cfg)
        got = list(posed_scans(bag, cfg, plan, ScanCounts()))
    print(f"\nmit-csail.clf.bz2 opened (decompressed, parsed, checked) in {opened:.2f} s")
    assert plan.poses == "odom"
    log = read_carmen()
    want = carmen_scans(log, mount_z=0.0)
    assert len(got) == len(want) == 1988
    for k in (0, 700, 1987):
        hits = hits_of(got[k])
        np.testing.assert_allclose(got[k].origin, want[k][1], atol=1e-9)
        w = want[k][0]
        # the helper keeps [0.05, 80]; the reader every reading below range_max 80
        assert len(hits) == len(w)
        np.testing.assert_allclose(hits, w, atol=1e-6)
