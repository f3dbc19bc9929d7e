"""convert and inspect (issue 4), through the command line.

* convert: cloud formats round-trip the points (float32 where the format holds float32), a
  bag's scans merge into one file holding exactly their finite hits, LAS -> LAZ keeps
  georeferenced coordinates.
* inspect: what a bag holds and what bag2world would do with it, or why it would stop.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import laspy  # type: ignore[import-untyped]
import numpy as np
import pytest

from scan2terrain.cli import main
from scan2terrain.readers.bag import BagWarning
from scan2terrain.readers.cloudfile import read_cloud
from tests.bagmaker import (
    LASER_SCAN,
    POINT_CLOUD2,
    laserscan_msg,
    pointcloud2_msg,
    synthetic_room,
    write_bag,
)
from tests.fixtures import GRIDMAP, HDL_PCD, SICK_ROS1, SIMPLE_LAS

T0 = 1_700_000_000_000_000_000


def run(capsys: pytest.CaptureFixture[str], *args: object) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


# --- convert -----------------------------------------------------------------------------------


def test_pcd_ply_pcd_round_trip_keeps_the_points(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The HDL-32 frame (float32 in the PCD) through PLY (float64) back to PCD (float32): the
    same 69,088 points in the same order, bit for bit at float32."""
    ply, pcd = tmp_path / "a.ply", tmp_path / "b.pcd"
    code, stdout, err = run(capsys, "convert", HDL_PCD, ply)
    assert code == 0, err
    assert stdout.startswith(f"Wrote {ply} (69,088 points)")
    code, _, err = run(capsys, "convert", ply, pcd)
    assert code == 0, err
    original = read_cloud(HDL_PCD).points
    assert original.shape == (69088, 3)
    via_ply = read_cloud(ply).points
    back = read_cloud(pcd).points
    np.testing.assert_array_equal(via_ply, original)  # float32 values are exact in float64
    np.testing.assert_array_equal(back, original)
    assert np.array_equal(back.astype(np.float32).astype(np.float64), back)
    # the target exists: refused without --overwrite, replaced with it
    code, _, err = run(capsys, "convert", ply, pcd)
    assert code == 2 and "exists (use --overwrite" in err and err.count("\n") == 1
    assert run(capsys, "convert", ply, pcd, "--overwrite")[0] == 0


def test_bag_clouds_merge_into_one_file_of_their_finite_hits(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The synthetic room's PointCloud2 scans (posed by tf) become one PLY holding every
    return, in the map frame, in scan order (float32 sensor-frame values, posed in float64)."""
    room = synthetic_room("cloud", n_scans=11)  # odd: map->odom has a sample at the last scan
    bag = room.write(tmp_path / "room.bag", "ros1")
    target = tmp_path / "merged.ply"
    code, stdout, err = run(capsys, "convert", bag, target)
    assert code == 0, err
    want = np.concatenate(room.hits)
    assert f"({len(want):,} points)" in stdout and "scans: 11" in stdout
    got = read_cloud(target).points
    assert got.shape == want.shape
    np.testing.assert_allclose(got, want, atol=1e-9)


def test_bag_merge_keeps_finite_hits_only(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """NaN cloud points, and LaserScan readings that are no hit (inf, >= range_max, NaN,
    < range_min), are not in the merged file; the stationary pose moves the rest."""
    rng = np.random.default_rng(4)
    clouds = []
    for k in range(3):
        pts = rng.uniform(-5, 5, (100, 3))
        pts[rng.choice(100, 7 + k, replace=False), rng.integers(0, 3)] = np.nan
        clouds.append(pts)
    ranges = np.array([1.0, np.inf, 2.0, 30.0, np.nan, 0.01, 3.0], dtype=np.float32)
    msgs = [
        ("/points", POINT_CLOUD2, T0 + k * 10**8, pointcloud2_msg(T0 + k * 10**8, "lidar", c))
        for k, c in enumerate(clouds)
    ]
    finite = sum(int(np.isfinite(c).all(axis=1).sum()) for c in clouds)
    assert finite < 300
    cloud_bag = write_bag(tmp_path / "c.bag", "ros1", msgs)
    pose = ["--pose", "10", "0", "1", "0", "0", "0"]
    code, stdout, err = run(capsys, "convert", cloud_bag, tmp_path / "c.xyz", *pose)
    assert code == 0, err
    assert f"({finite} points)" in stdout
    got = read_cloud(tmp_path / "c.xyz").points
    assert len(got) == finite
    want = np.concatenate([c[np.isfinite(c).all(axis=1)] for c in clouds])
    np.testing.assert_allclose(got, want.astype(np.float32) + np.array([10, 0, 1]), atol=1e-9)

    scan = laserscan_msg(T0, "laser", 0.0, math.pi / 2, ranges, 0.05, 25.0)
    scan_bag = write_bag(tmp_path / "s_mcap", "mcap", [("/scan", LASER_SCAN, T0, scan)])
    code, stdout, err = run(capsys, "convert", scan_bag, tmp_path / "s.csv", *pose)
    assert code == 0, err
    assert "(3 points)" in stdout
    got = read_cloud(tmp_path / "s.csv").points
    # hits at 1 m (0 rad), 2 m (pi), 3 m (3 pi): the rest are clear-only or no information
    np.testing.assert_allclose(got, [[11, 0, 1], [8, 0, 1], [7, 0, 1]], atol=1e-6)


def test_las_to_laz_keeps_georeferenced_coordinates(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    target = tmp_path / "simple.laz"
    code, stdout, err = run(capsys, "convert", SIMPLE_LAS, target)
    assert code == 0, err
    assert "local origin" not in stdout  # a format conversion moves nothing
    a, b = laspy.read(SIMPLE_LAS), laspy.read(target)
    assert b.header.point_count == a.header.point_count == 1065
    assert b.header.are_points_compressed and not a.header.are_points_compressed
    np.testing.assert_allclose(
        np.column_stack([b.x, b.y, b.z]), np.column_stack([a.x, a.y, a.z]), rtol=0, atol=1e-6
    )
    assert read_cloud(target).format.startswith("laz")


# --- inspect -----------------------------------------------------------------------------------


def test_inspect_synthetic_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Topics with counts and types, duration, the tf tree's edges, and the plan's reasons."""
    room = synthetic_room("slashes", n_scans=40)
    bag = room.write(tmp_path / "room_mcap", "mcap")
    times = [m[2] for m in room.messages]
    code, stdout, err = run(capsys, "inspect", bag)
    assert code == 0 and err == ""
    lines = stdout.splitlines()
    assert lines[0] == str(bag)
    assert lines[1].startswith("  ") and "read with rosbags" in lines[1]  # what read the bag
    lines = [lines[0], *lines[2:]]
    assert lines[1] == (
        f"  duration {(max(times) - min(times)) / 1e9:.3f} s, {len(times)} messages, "
        f"start {min(times) / 1e9:.3f} (UNIX s)"
    )
    topics = {tuple(line.split()) for line in lines[3:6]}
    assert topics == {
        ("/scan", "40", "sensor_msgs/msg/LaserScan"),
        ("/tf", "80", "tf2_msgs/msg/TFMessage"),
        ("/tf_static", "1", "tf2_msgs/msg/TFMessage"),
    }
    tree = lines[lines.index("  tf tree:") + 1 : lines.index("  bag2world would use:")]
    # ROS1-style '/map' names are normalised
    assert tree == [
        "    base_link -> laser (static)",
        "    map -> odom (20 samples)",
        "    odom -> base_link (80 samples)",
    ]
    assert lines[lines.index("  bag2world would use:") + 1 :] == [
        "    topic /scan: the bag's only LaserScan/PointCloud2 topic",
        "    poses: tf, sensor frame(s) laser in fixed frame 'map'",
        "    correction: none (tf has the map frame 'map' (poses a SLAM system made); "
        "--correct on corrects them too)",
    ]


def test_inspect_odometry_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag = synthetic_room("odom", n_scans=20).write(tmp_path / "odom.bag", "ros1")
    code, stdout, err = run(capsys, "inspect", bag, "--mount", "0.2", "0", "0.3", "0", "0", "0")
    assert code == 0 and err == ""
    assert "  tf tree: none (no /tf or /tf_static)" in stdout
    assert "    poses: odometry on /odom plus the sensor mount" in stdout


def test_inspect_says_why_bag2world_would_stop(capsys: pytest.CaptureFixture[str]) -> None:
    """The SICK bag has four scan topics: inspect lists them and the option that picks one;
    with --topic and --fixed-frame it shows the plan instead."""
    code, stdout, err = run(capsys, "inspect", SICK_ROS1)
    assert code == 0 and err == ""
    assert "    /sick_lms_1xx/scan                          89  sensor_msgs/msg/LaserScan" in stdout
    assert "    /radar                                      34  sick_scan/msg/RadarScan" in stdout
    assert "    cloud -> radar (17 samples)" in stdout  # '/cloud' -> '/radar' in the bag
    assert stdout.splitlines()[-1] == (
        "  bag2world would stop: several scan topics, choose with --topic (repeatable): "
        "/cloud (PointCloud2); /cloud_radar_rawtarget (PointCloud2); "
        "/cloud_radar_track (PointCloud2); /sick_lms_1xx/scan (LaserScan)"
    )
    for topic in ("/sick_lms_1xx/scan", "sick_lms_1xx/scan"):  # the same topic (issue 25)
        code, stdout, err = run(
            capsys, "inspect", SICK_ROS1, "--topic", topic, "--fixed-frame", "cloud"
        )
        assert code == 0 and err == ""
        assert stdout.splitlines()[-3:] == [
            "    topics /sick_lms_1xx/scan: chosen (--topic)",
            "    poses: tf, sensor frame(s) cloud in fixed frame 'cloud'",
            "    correction: none (the sensor does not move in the fixed frame 'cloud' (static "
            "tf); --correct on corrects them too)",
        ]


def test_inspect_lists_skipped_topics(capsys: pytest.CaptureFixture[str]) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("always", BagWarning)  # pytest makes warnings errors
        code, stdout, err = run(capsys, "inspect", GRIDMAP)
    assert code == 0
    assert err.startswith("scan2terrain: warning: ") and err.count("\n") == 1
    assert "  skipped: /grid_map: message type grid_map_msgs/msg/GridMap has no definition" in (
        stdout
    )
    assert "  bag2world would stop: nothing to map and no trajectory" in stdout


def test_inspect_missing_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, stdout, err = run(capsys, "inspect", tmp_path / "nope.bag")
    assert code == 2 and stdout == ""
    assert err == f"scan2terrain: error: {tmp_path / 'nope.bag'}: bag not found\n"
