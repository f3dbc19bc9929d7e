"""readers/bag.py on every real fixture bag (copies under fixtures/bags) and on bad input.

The catalogue below restates each fixture's SOURCE.txt (topics, types, counts, span, sensor
geometry); the ROS 2 copies must list the same topics and give the same deserialised data as the
ROS1 originals they were converted from.
"""

from __future__ import annotations

import shutil
import sqlite3
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from scan2terrain.errors import InputError
from scan2terrain.readers.bag import (
    LASER_SCAN,
    ODOMETRY,
    POINT_CLOUD2,
    SCAN_TYPES,
    TF_MESSAGE,
    TF_TYPES,
    Bag,
    BagWarning,
    open_bag,
    resolve_time,
)
from tests.bagmaker import read_messages, synthetic_room, write_bag
from tests.fixtures import (
    BAGS,
    CCNY,
    EMBARK_MCAP,
    EMBARK_ROS1,
    FUSE,
    GRIDMAP,
    LEG_TRACKER,
    LEGACY,
    NAV2,
    SICK_DB3,
    SICK_ROS1,
)

PC2, LS, TF = POINT_CLOUD2, LASER_SCAN, TF_MESSAGE
SICK_SENSORS = {
    "/sick_lms_1xx/scan": (LS, 89),
    "/cloud": (PC2, 89),
    "/cloud_radar_track": (PC2, 108),
    "/cloud_radar_rawtarget": (PC2, 139),
    "/tf": (TF, 17),
}
EMBARK_TOPICS = {
    "/luminar_pointcloud": (PC2, 5),
    "/base_scan": (LS, 5),
    "/base_pose_ground_truth": (ODOMETRY, 5),
}
#: path -> (start s, duration s, topics {name: (type, count)}), from each SOURCE.txt.
CATALOGUE: dict[str, tuple[Path, float, float, dict[str, tuple[str, int]]]] = {
    "sick_ros1": (
        SICK_ROS1,
        1663929585.388,
        1.88,
        {
            **SICK_SENSORS,
            "/rosout": ("rosgraph_msgs/msg/Log", 35),
            "/sick_lms_1xx/parameter_descriptions": (
                "dynamic_reconfigure/msg/ConfigDescription",
                1,
            ),
            "/sick_lms_1xx/parameter_updates": ("dynamic_reconfigure/msg/Config", 1),
            "/sick_rms_1xxx/parameter_descriptions": (
                "dynamic_reconfigure/msg/ConfigDescription",
                1,
            ),
            "/sick_rms_1xxx/parameter_updates": ("dynamic_reconfigure/msg/Config", 1),
            "/diagnostics": ("diagnostic_msgs/msg/DiagnosticArray", 3),
            "/radar": ("sick_scan/msg/RadarScan", 34),
        },
    ),
    "sick_db3": (SICK_DB3, 1663929585.503, 1.76, SICK_SENSORS),
    "embark_ros1": (EMBARK_ROS1, 1604515190.231, 7.59, EMBARK_TOPICS),
    "embark_mcap": (EMBARK_MCAP, 1604515190.231, 7.59, EMBARK_TOPICS),
    "fuse": (
        FUSE,
        112.540,
        91.34,
        {
            "/cmd_vel": ("geometry_msgs/msg/Twist", 2335),
            "/joint_states": ("sensor_msgs/msg/JointState", 2741),
            "/odom": (ODOMETRY, 2741),
            "/scan": (LS, 457),
            "/imu": ("sensor_msgs/msg/Imu", 2253),
        },
    ),
    "leg_tracker": (LEG_TRACKER, 1403201183.688, 125.99, {"/scan": (LS, 1265)}),
    "ccny": (CCNY, 1282836371.070, 35.81, {"/scan": (LS, 360)}),
    "gridmap": (GRIDMAP, 1600035091.055, 9.60, {"/grid_map": ("grid_map_msgs/msg/GridMap", 4)}),
    "nav2_zstd": (
        NAV2,
        1760908698.049,
        11.50,
        {
            "/local_costmap/costmap": ("nav2_msgs/msg/Costmap", 231),
            "/cmd_vel_smoothed": ("geometry_msgs/msg/Twist", 231),
            "/clock": ("rosgraph_msgs/msg/Clock", 231),
        },
    ),
}
#: What open_bag warns about, per fixture.
WARNS = {"ccny": "index does not match its data", "gridmap": "grid_map_msgs/msg/GridMap"}


def opened(path: Path | list[Path], warns: str | None = None) -> Bag:
    if warns is None:
        return open_bag(path)
    with pytest.warns(BagWarning, match=warns):
        return open_bag(path)


def input_error(path: Any, match: str) -> InputError:
    """The InputError open_bag raises: one line, naming the file."""
    with pytest.raises(InputError, match=match) as info, open_bag(path):
        pass
    assert "\n" not in str(info.value)
    return info.value


def stamp(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def test_the_copies_are_the_shared_fixtures() -> None:
    names = sorted(p.name for p in BAGS.iterdir() if p.is_dir())
    assert len(names) == 10
    for name in names:
        assert (BAGS / name / "SOURCE.txt").is_file()


@pytest.mark.parametrize("name", sorted(CATALOGUE))
def test_catalogue(name: str) -> None:
    path, start_s, duration_s, topics = CATALOGUE[name]
    with opened(path, WARNS.get(name)) as bag:
        assert {t.name: (t.msgtype, t.count) for t in bag.topics.values()} == topics
        assert bag.start_ns / 1e9 == pytest.approx(start_s, abs=1e-3)
        assert bag.duration_s == pytest.approx(duration_s, abs=0.01)
        assert bag.message_count == sum(c for _, c in topics.values())
        readable = [t for t in bag.topics if t not in bag.skipped]
        if not readable:  # the gridmap bag: its one topic is skipped
            assert bag.skipped.keys() == bag.topics.keys()
            return
        times = []
        counts = dict.fromkeys(readable, 0)
        for topic, t_ns, _ in bag.messages(readable):
            times.append(t_ns)
            counts[topic] += 1
    assert counts == {t: topics[t][1] for t in readable}
    assert times[0] == bag.start_ns
    assert times[-1] == bag.end_ns
    assert np.all(np.diff(times) >= 0)


def first(bag: Bag, topic: str) -> Any:
    return next(m for _, _, m in bag.messages(topic))


def test_sick_scan_cloud_and_tf_with_slashes() -> None:
    with open_bag(SICK_ROS1) as bag:
        scan, cloud = first(bag, "/sick_lms_1xx/scan"), first(bag, "/cloud")
        tf = first(bag, "/tf").transforms[0]
        assert bag.topics_of_type(SCAN_TYPES) == [
            "/cloud",
            "/cloud_radar_rawtarget",
            "/cloud_radar_track",
            "/sick_lms_1xx/scan",
        ]
        assert bag.topics_of_type(TF_TYPES) == ["/tf"]
        assert bag.frame_ids("/tf") == {"cloud", "radar"}
        assert bag.frame_ids("/sick_lms_1xx/scan") == {"cloud"}
        assert bag.skipped == {}  # the custom RadarScan has its definition in the bag
        assert first(bag, "/radar").header.frame_id == "radar"
    assert scan.header.frame_id == "cloud"
    assert (len(scan.ranges), len(scan.intensities)) == (541, 541)
    assert scan.angle_min == pytest.approx(-2.356, abs=1e-3)
    assert (scan.range_min, scan.range_max) == (pytest.approx(0.05), pytest.approx(25.0))
    assert (cloud.width, cloud.height, cloud.point_step) == (541, 1, 16)
    assert [f.name for f in cloud.fields] == ["x", "y", "z", "intensity"]
    assert (tf.header.frame_id, tf.child_frame_id) == ("/cloud", "/radar")
    assert scan.header.seq >= 0  # ROS1 headers keep seq


def test_embark_cloud_layout_and_odometry() -> None:
    with open_bag(EMBARK_ROS1) as bag:
        clouds = [m for _, _, m in read_messages(bag, "/luminar_pointcloud")]
        odom = first(bag, "/base_pose_ground_truth")
        scan = first(bag, "/base_scan")
    assert clouds[0].width == 35707
    assert max(c.width for c in clouds) == 36457
    layout = [(f.name, f.datatype, f.offset) for f in clouds[0].fields]
    assert layout == [
        ("x", 7, 0),
        ("y", 7, 4),
        ("z", 7, 8),
        ("intensity", 7, 16),
        ("time_sec", 6, 20),
        ("time_nsec", 6, 24),
        ("laser_id", 4, 28),
    ]
    assert (clouds[0].point_step, clouds[0].is_bigendian) == (32, False)
    assert (odom.header.frame_id, odom.child_frame_id) == ("odom", "")
    assert (scan.header.frame_id, len(scan.ranges)) == ("base_laser_link", 90)
    assert scan.header.stamp.sec == 60  # simulator time in the header, 2020 record times


def test_fuse_leg_tracker_and_ccny_scans() -> None:
    with open_bag(FUSE) as bag:
        scan, odom = first(bag, "/scan"), first(bag, "/odom")
        assert not bag.topics_of_type(TF_TYPES)
    assert (scan.header.frame_id, len(scan.ranges)) == ("base_scan", 360)
    assert (odom.header.frame_id, odom.child_frame_id) == ("odom", "base_footprint")
    with open_bag(LEG_TRACKER) as bag:
        scan = first(bag, "/scan")
    assert (scan.header.frame_id, len(scan.ranges)) == ("laser", 512)
    assert scan.angle_min == pytest.approx(-np.pi / 2, abs=1e-3)


def test_ccny_broken_index_is_rebuilt_from_the_chunks() -> None:
    with opened(CCNY, "rebuilt it from 2 chunk") as bag:
        scans = [(t, m) for _, t, m in read_messages(bag, "/scan")]
        assert bag.frame_ids("/scan") == {"laser"}  # recorded as "/laser"
    assert len(scans) == 360
    t, scan = scans[0]
    assert scan.header.frame_id == "/laser"  # 2010's roslib/Header, read as std_msgs/Header
    assert len(scan.ranges) == 681
    assert scan.angle_min == pytest.approx(-2.086, abs=1e-3)
    assert (scan.range_min, scan.range_max) == (pytest.approx(0.02), pytest.approx(5.6))
    assert abs(stamp(scan) - t) < 1_000_000_000
    valid = (scan.ranges >= scan.range_min) & (scan.ranges <= scan.range_max)
    assert valid.sum() == 633


def fields(cloud: Any) -> list[tuple[str, int, int, int]]:
    """PointField values (message objects of two bags never compare equal: each bag has its own
    generated classes)."""
    return [(f.name, f.offset, f.datatype, f.count) for f in cloud.fields]


def pairs(bag: Bag, topic: str) -> list[tuple[int, Any]]:
    return [(t, m) for _, t, m in bag.messages(topic)]


def test_sick_db3_copy_gives_the_same_data() -> None:
    with open_bag(SICK_ROS1) as ros1, open_bag(SICK_DB3) as ros2:
        kept = {n: (t.msgtype, t.count) for n, t in ros1.topics.items() if n in ros2.topics}
        assert kept == {n: (t.msgtype, t.count) for n, t in ros2.topics.items()}
        assert ros2.end_ns == ros1.end_ns
        scans = zip(
            pairs(ros1, "/sick_lms_1xx/scan"), pairs(ros2, "/sick_lms_1xx/scan"), strict=True
        )
        for a, b in scans:
            assert a[0] == b[0]
            assert stamp(a[1]) == stamp(b[1])
            assert a[1].header.frame_id == b[1].header.frame_id
            np.testing.assert_array_equal(a[1].ranges, b[1].ranges)
            np.testing.assert_array_equal(a[1].intensities, b[1].intensities)
            assert a[1].angle_increment == b[1].angle_increment
        for topic in ("/cloud", "/cloud_radar_track", "/cloud_radar_rawtarget"):
            got = list(zip(pairs(ros1, topic), pairs(ros2, topic), strict=True))
            for (t1, c1), (t2, c2) in got:
                assert t1 == t2
                assert bytes(c1.data) == bytes(c2.data)
                assert (c1.width, c1.point_step) == (c2.width, c2.point_step)
                assert fields(c1) == fields(c2)
        tf1 = [m.transforms[0].child_frame_id for _, m in pairs(ros1, "/tf")]
        assert tf1 == [m.transforms[0].child_frame_id for _, m in pairs(ros2, "/tf")]


def test_embark_mcap_copy_gives_the_same_data() -> None:
    with open_bag(EMBARK_ROS1) as ros1, open_bag(EMBARK_MCAP) as ros2:
        assert (ros1.start_ns, ros1.end_ns) == (ros2.start_ns, ros2.end_ns)
        for topic in ("/luminar_pointcloud", "/base_scan", "/base_pose_ground_truth"):
            for (t1, m1), (t2, m2) in zip(pairs(ros1, topic), pairs(ros2, topic), strict=True):
                assert (t1, stamp(m1)) == (t2, stamp(m2))
                if topic == "/luminar_pointcloud":
                    assert bytes(m1.data) == bytes(m2.data)
                elif topic == "/base_scan":
                    np.testing.assert_array_equal(m1.ranges, m2.ranges)
                else:
                    p1, p2 = m1.pose.pose.position, m2.pose.pose.position
                    assert (p1.x, p1.y, p1.z) == (p2.x, p2.y, p2.z)


def test_unknown_type_is_skipped_with_a_warning() -> None:
    with opened(GRIDMAP, "skipping topics: /grid_map") as bag:
        assert bag.skipped.keys() == {"/grid_map"}
        assert "no definition" in bag.skipped["/grid_map"]
        assert bag.topics_of_type("grid_map_msgs/msg/GridMap") == []
        assert "cannot be decoded" in bag.describe_topics()
        with pytest.raises(InputError, match="'/grid_map' cannot be read"):
            bag.messages("/grid_map")
        with pytest.raises(InputError, match=r"no usable .*the bag has: /grid_map"):
            bag.pick_topic(SCAN_TYPES)


def test_bag_without_definitions_keeps_the_standard_types(tmp_path: Path) -> None:
    room = synthetic_room("tf", n_scans=5)
    custom = ("/custom", "my_msgs/msg/Thing", int(room.stamps_ns[0]), {"value": 7})
    path = write_bag(
        tmp_path / "b", "sqlite3", [*room.messages, custom], extra_types={custom[1]: "int32 value"}
    )
    with sqlite3.connect(next(path.glob("*.db3"))) as db:  # as old rosbag2 wrote it
        db.execute("DELETE FROM message_definitions")
    with opened(path, "my_msgs/msg/Thing has no definition") as bag:
        assert bag.skipped.keys() == {"/custom"}
        assert bag.count(["/scan", "/tf"]) == {"/scan": 5, "/tf": 10}
        assert len(list(bag.messages(["/scan", "/tf", "/tf_static"]))) == 16


def test_nav2_whole_file_zstd_has_no_usable_topic(tmp_path: Path) -> None:
    with open_bag(NAV2) as bag:
        with pytest.raises(InputError, match="no usable") as info:
            bag.pick_topic(SCAN_TYPES)
        costmap = first(bag, "/local_costmap/costmap")  # schema embedded in the mcap
    assert "/local_costmap/costmap (nav2_msgs/msg/Costmap, 231)" in str(info.value)
    assert costmap.header.frame_id == "base_footprint"
    # The .mcap.zstd alone, without metadata.yaml: decompressed into a temporary file.
    alone = tmp_path / "_tmp_cm_bag_0.mcap.zstd"
    shutil.copy(NAV2 / alone.name, alone)
    with open_bag(alone) as bag:
        assert {t: i.count for t, i in bag.topics.items()} == dict.fromkeys(
            ["/clock", "/cmd_vel_smoothed", "/local_costmap/costmap"], 231
        )
        assert isinstance(bag._reader, AnyReader)
        temp = bag._reader.paths[0]  # the decompressed copy
        assert isinstance(temp, Path) and temp.is_file()
    assert not temp.exists()


def test_standalone_storage_files_and_metadata_path(tmp_path: Path) -> None:
    db3 = tmp_path / "sick.db3"
    shutil.copy(next(SICK_DB3.glob("*.db3")), db3)
    mcap = tmp_path / "dir" / "embark.mcap"
    mcap.parent.mkdir()
    shutil.copy(next(EMBARK_MCAP.glob("*.mcap")), mcap)
    with open_bag(db3) as bag:
        assert bag.topics["/sick_lms_1xx/scan"].count == 89
    with open_bag(mcap.parent) as bag:  # a folder holding one storage file, no metadata.yaml
        assert bag.topics["/luminar_pointcloud"].count == 5
    with open_bag(str(EMBARK_MCAP / "metadata.yaml")) as bag:
        assert bag.paths == (EMBARK_MCAP,)


def test_wrong_suffixes_are_sniffed(tmp_path: Path) -> None:
    ros1 = tmp_path / "scans.data"
    shutil.copy(LEG_TRACKER, ros1)
    with open_bag(ros1) as bag:
        assert bag.topics["/scan"].count == 1265
        assert bag.paths == (ros1,)
    db3 = tmp_path / "sick.sqlite"
    shutil.copy(next(SICK_DB3.glob("*.db3")), db3)
    with open_bag(db3) as bag:
        assert bag.topics["/tf"].count == 17


def test_split_ros1_recording(tmp_path: Path) -> None:
    room = synthetic_room("tf", n_scans=40)
    t_mid = int(room.stamps_ns[20])
    (tmp_path / "split").mkdir()
    a = write_bag(tmp_path / "split/part_0.bag", "ros1", [m for m in room.messages if m[2] < t_mid])
    b = write_bag(
        tmp_path / "split/part_1.bag", "ros1", [m for m in room.messages if m[2] >= t_mid]
    )
    for given in ([a, b], tmp_path / "split"):
        with open_bag(given) as bag:
            assert bag.paths == (a, b)
            assert bag.topics["/scan"].count == 40
            assert bag.topics["/tf"].count == 80
            times = [t for _, t, _ in bag.messages(["/scan", "/tf"])]
            assert times == sorted(times)
            assert len(times) == 120
    b.write_bytes(b.read_bytes()[: b.stat().st_size // 2])
    err = input_error([a, b], "index is missing or damaged")
    assert err.path == b


def test_time_ranges() -> None:
    with open_bag(LEG_TRACKER) as bag:
        assert resolve_time(None, bag) is None
        assert resolve_time("12.5", bag) == bag.start_ns + 12_500_000_000
        assert resolve_time(0, bag) == bag.start_ns
        absolute = f"{bag.start_ns // 1_000_000_000}.{bag.start_ns % 1_000_000_000:09d}"
        assert resolve_time(absolute, bag) == bag.start_ns  # exact, no float rounding
        assert resolve_time(-5, bag) == bag.start_ns - 1
        assert resolve_time(1e12, bag) == bag.end_ns + 1
        with pytest.raises(InputError, match="not a number"):
            resolve_time("soon", bag)
        with pytest.raises(InputError, match="not a finite"):
            resolve_time("nan", bag)
        start, end = resolve_time("10", bag), resolve_time("20", bag)
        times = [t for _, t, _ in bag.messages("/scan", start, end)]
        assert times
        assert start is not None and end is not None
        assert start <= times[0] and times[-1] <= end
        assert bag.count("/scan", start, end) == {"/scan": len(times)}
        assert 90 < len(times) < 110  # ~10 Hz
        # Inclusive at both ends.
        assert bag.count("/scan", times[3], times[3]) == {"/scan": 1}
        bag.require_messages("/scan", start, end)
        with pytest.raises(InputError, match="starts after the bag's last message") as info:
            bag.require_messages("/scan", resolve_time("200", bag), resolve_time("300", bag))
        assert LEG_TRACKER.name in str(info.value)
        with pytest.raises(InputError, match=r"between 10\.000 s and 10\.001 s"):
            bag.require_messages("/scan", start, start + 1_000_000)
        with pytest.raises(InputError, match="ends before it starts"):
            bag.require_messages("/scan", end, start)


def test_missing_topic_lists_the_ones_there_are() -> None:
    with open_bag(FUSE) as bag:
        with pytest.raises(InputError, match=r"no topic '/points'.*/odom \(nav_msgs/msg/Odometry"):
            bag.messages("/points")
        with pytest.raises(InputError, match="is sensor_msgs/msg/LaserScan, expected"):
            bag.require("/scan", POINT_CLOUD2)
        assert bag.require("scan").name == "/scan"  # the leading slash may be left out
        assert bag.pick_topic(SCAN_TYPES).name == "/scan"
    with open_bag(SICK_ROS1) as bag, pytest.raises(InputError, match="several"):
        bag.pick_topic(SCAN_TYPES)


def _foxglove_scans(path: Path, topics: list[str]) -> Path:
    """An MCAP file of Foxglove schemas with one foxglove.LaserScan on each of ``topics`` (named
    as given: Foxglove channels often have no leading slash)."""
    from tests.bagmaker import write_foxglove_mcap

    scan = {"frame_id": "laser", "start_angle": 0.0, "end_angle": 1.0, "ranges": [1.0, 2.0]}
    stamp = {"sec": 1_700_000_000, "nsec": 0}
    messages = [
        (topic, "foxglove.LaserScan", 1_700_000_000 * 10**9 + i, scan | {"timestamp": stamp})
        for i, topic in enumerate(topics)
    ]
    return write_foxglove_mcap(path, messages, "json")


def test_a_topic_is_named_with_or_without_its_leading_slash(tmp_path: Path) -> None:
    """``--topic /scan`` and ``--topic scan`` name the same topic, as frame names do: ROS1 bags
    store ``/scan``, Foxglove MCAP channels may be ``scan``. --topic scan on a ROS1 bag was an
    internal error (KeyError: 'scan'), --topic /scan on a Foxglove channel 'scan' "no topic"."""
    from scan2terrain.config import ScansConfig
    from scan2terrain.readers.scans import plan_bag

    with open_bag(FUSE) as bag:
        for given in ("scan", "/scan", "//scan"):
            plan = plan_bag(
                bag, ScansConfig(topics=[given], odom_topic=given.replace("scan", "odom"))
            )
            assert plan.scan_topics == ["/scan"] and plan.odom_topic == "/odom"
            assert plan.reasons[0] == "topics /scan: chosen (--topic)"
        twice = plan_bag(bag, ScansConfig(topics=["scan", "/scan"]))
        assert twice.scan_topics == ["/scan"]  # one topic, read once
    with open_bag(_foxglove_scans(tmp_path / "fg.mcap", ["scan"])) as bag:
        assert list(bag.topics) == ["scan"]
        for given in ("scan", "/scan"):
            assert bag.require(given).name == "scan"
            fixed = ScansConfig(topics=[given], poses="fixed", pose=[0.0] * 6)
            plan = plan_bag(bag, fixed, max_range=10.0)
            assert plan.scan_topics == ["scan"]
        with pytest.raises(InputError, match="no topic '/points'"):
            bag.require("/points")
    # Both spellings recorded as two channels: each names its own; any other spelling neither.
    with open_bag(_foxglove_scans(tmp_path / "both.mcap", ["scan", "/scan"])) as bag:
        assert bag.require("scan").name == "scan"
        assert bag.require("/scan").name == "/scan"
        with pytest.raises(InputError, match=r"'//scan' could be '/scan' or 'scan'"):
            bag.require("//scan")


def test_legacy_rosrecord_is_refused() -> None:
    err = input_error(LEGACY, r"ROSRECORD V1\.2.*rosbag reindex old\.bag")
    assert err.path == LEGACY
    assert LEGACY.name in str(err)


@pytest.mark.parametrize("fraction", [0.5, 0.95])
def test_truncated_bags(tmp_path: Path, fraction: float) -> None:
    for src, name, match in [
        (SICK_ROS1, "cut.bag", "index is missing or damaged.*rosbag reindex"),
        (next(SICK_DB3.glob("*.db3")), "cut.db3", "sqlite3 file is truncated or damaged"),
        (next(EMBARK_MCAP.glob("*.mcap")), "cut.mcap", "MCAP file is truncated or damaged"),
    ]:
        cut = tmp_path / name
        data = src.read_bytes()
        cut.write_bytes(data[: int(len(data) * fraction)])
        assert input_error(cut, match).path == cut


def test_damaged_chunk_fails_while_reading(tmp_path: Path) -> None:
    data = bytearray(SICK_ROS1.read_bytes())
    middle = len(data) // 2
    data[middle : middle + 64] = b"\xff" * 64  # inside a bz2 chunk: the index is still fine
    bad = tmp_path / "bad.bag"
    bad.write_bytes(bytes(data))
    with open_bag(bad) as bag, pytest.raises(InputError, match=r"cannot read.*damaged") as info:
        for _ in bag.messages(list(bag.topics)):
            pass
    assert str(info.value).startswith(str(bad))
    # Not bz2's own words ("Invalid data stream, OSError"), which said nothing about the bag.
    assert info.value.problem == (
        "cannot read message data: the file is damaged or truncated "
        "(a compressed chunk does not decompress)"
    )


def test_not_bags(tmp_path: Path) -> None:
    input_error(tmp_path / "missing.bag", "bag not found")
    noise = tmp_path / "noise.bag"
    noise.write_bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    input_error(noise, "not a ROS bag")
    text = tmp_path / "notes.bag"
    text.write_text("just some notes\n" * 20)
    input_error(text, "text file, not a ROS bag")
    empty = tmp_path / "empty.bag"
    empty.touch()
    input_error(empty, "empty")
    yaml = tmp_path / "map.yaml"
    yaml.write_text("image: map.pgm\n")
    input_error(yaml, "metadata.yaml")
    folder = tmp_path / "nothing"
    folder.mkdir()
    input_error(folder, "no bag in this folder")
    input_error([SICK_ROS1, text], "split ROS1 recording")


def test_bag_without_messages(tmp_path: Path) -> None:
    path = write_bag(tmp_path / "none.bag", "ros1", [])
    input_error(path, "holds no messages")
