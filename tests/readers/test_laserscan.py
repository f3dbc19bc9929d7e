"""sensor_msgs/LaserScan -> laser-frame points + max range, and what the octree makes of them."""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from scan2terrain.errors import InputError
from scan2terrain.octree.tree import VoxelOctree
from scan2terrain.readers.laserscan import CLEAR_FACTOR, RANGE_SLACK, laserscan_points

INF, NAN = math.inf, math.nan


def scan(ranges: Any, **kw: float) -> SimpleNamespace:
    msg = SimpleNamespace(
        angle_min=-math.pi / 2,
        angle_max=math.pi / 2,
        angle_increment=math.pi / 4,
        range_min=0.1,
        range_max=30.0,
        ranges=np.asarray(ranges, dtype=np.float32),
        intensities=np.zeros(0, dtype=np.float32),
    )
    for k, v in kw.items():
        setattr(msg, k, v)
    return msg


def test_readings_by_kind() -> None:
    # angles: -90, -45, 0, 45, 90, 135, 180, 225, 270 degrees
    ranges = [1.0, 2.0, INF, NAN, -INF, 0.05, 40.0, 30.0, 0.1]
    points, max_range = laserscan_points(scan(ranges))
    assert max_range == pytest.approx(30.0 * (1 + RANGE_SLACK), rel=1e-12) and max_range > 30.0
    far = CLEAR_FACTOR * max_range
    kept = [0, 1, 2, 6, 7, 8]  # NaN, -inf and 0.05 < range_min dropped
    dist = np.array([1.0, 2.0, far, far, far, np.float32(0.1)])
    angles = -math.pi / 2 + math.pi / 4 * np.array(kept, dtype=float)
    expected = np.stack([dist * np.cos(angles), dist * np.sin(angles), np.zeros(6)], axis=1)
    assert points.dtype == np.float64 and points.shape == (6, 3)
    np.testing.assert_allclose(points, expected, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(points[:, 2], 0.0)
    norms = np.linalg.norm(points, axis=1)
    assert (norms[:2] < 30).all() and (norms[2:5] > max_range).all()


def test_user_max_range_turns_far_hits_into_clear_only() -> None:
    points, max_range = laserscan_points(scan([1.0, 5.0, 9.0, INF]), max_range=5.0)
    assert 5.0 < max_range < 5.0001
    norms = np.linalg.norm(points, axis=1)
    np.testing.assert_allclose(norms, [1.0, 2 * max_range, 2 * max_range, 2 * max_range])
    # a max_range beyond the scanner's range_max changes nothing
    same, same_max = laserscan_points(scan([1.0, 5.0, 9.0, INF]), max_range=100.0)
    np.testing.assert_array_equal(same, laserscan_points(scan([1.0, 5.0, 9.0, INF]))[0])
    assert same_max == laserscan_points(scan([1.0]))[1]


def test_empty_and_single_reading() -> None:
    points, max_range = laserscan_points(scan([]))
    assert points.shape == (0, 3) and max_range > 30
    one, _ = laserscan_points(scan([2.0], angle_increment=0.0, angle_min=math.pi))
    np.testing.assert_allclose(one, [[-2.0, 0.0, 0.0]], atol=1e-12)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"angle_increment": 0.0}, "angle_increment is 0 with 3 readings"),
        ({"angle_increment": NAN}, "angles must be finite"),
        ({"angle_min": INF}, "angles must be finite"),
        ({"range_max": 0.0}, "range_max must be a positive number"),
        ({"range_max": -1.0}, "range_max must be a positive number"),
        ({"range_max": INF}, "range_max must be a positive number"),
        ({"range_max": NAN}, "range_max must be a positive number"),
        ({"range_min": 30.0}, r"range_min 30.0 must be in \[0, range_max"),
        ({"range_min": -0.5}, "range_min -0.5"),
        ({"range_min": NAN}, "range_min nan"),
    ],
)
def test_bad_messages(change: dict[str, float], message: str) -> None:
    with pytest.raises(InputError, match=message):
        laserscan_points(scan([1.0, 2.0, 3.0], **change))


@pytest.mark.parametrize("bad", [0.0, -1.0, NAN, INF])
def test_bad_max_range_argument(bad: float) -> None:
    with pytest.raises(ValueError, match="max_range"):
        laserscan_points(scan([1.0]), max_range=bad)


def test_rosbags_message() -> None:
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    t = ts.types
    msg = t["sensor_msgs/msg/LaserScan"](
        header=t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id="laser"
        ),
        angle_min=-1.0,
        angle_max=1.0,
        angle_increment=0.5,
        time_increment=0.0,
        scan_time=0.1,
        range_min=0.2,
        range_max=10.0,
        ranges=np.array([1.0, INF, 3.0, NAN, 12.0], dtype=np.float32),
        intensities=np.zeros(5, dtype=np.float32),
    )
    back = ts.deserialize_cdr(ts.serialize_cdr(msg, msg.__msgtype__), msg.__msgtype__)
    points, max_range = laserscan_points(back)
    norms = np.linalg.norm(points, axis=1)
    np.testing.assert_allclose(norms, [1.0, 2 * max_range, 3.0, 2 * max_range])
    np.testing.assert_allclose(np.arctan2(points[:, 1], points[:, 0]), [-1.0, -0.5, 0.0, 1.0])


@pytest.mark.parametrize("origin", [(0.0, 0.0, 0.0), (12.3, -4.5, 0.7), (800.3, -700.1, 3.0)])
def test_readings_just_below_range_max_stay_hits_in_the_octree(
    origin: tuple[float, float, float],
) -> None:
    """The octree measures distances from float32 coordinates: without the slack, some of these
    hits (one float32 step below range_max) would be cut and only clear."""
    n = 720
    range_max = np.float32(8.0)
    ranges = np.full(n, np.nextafter(range_max, np.float32(0)), dtype=np.float32)
    ranges[::10] = np.inf  # 72 clear-only beams
    msg = scan(ranges, angle_min=-math.pi, angle_increment=2 * math.pi / n, range_max=8.0)
    points, max_range = laserscan_points(msg)
    world = points + origin
    stats = VoxelOctree(0.1).insert_scan(world, origin, max_range=max_range)
    assert stats.beams_cut == 72
    assert stats.out_of_range == 0
    if origin != (0.0, 0.0, 0.0):  # the point of the slack: at range_max itself, hits are lost
        unslacked = VoxelOctree(0.1).insert_scan(world, origin, max_range=8.0)
        assert unslacked.beams_cut > 72


def test_clear_only_beam_clears_up_to_max_range_and_no_further() -> None:
    msg = scan([INF, 3.05], angle_min=0.0, angle_increment=math.pi / 2, range_max=5.0)
    points, max_range = laserscan_points(msg)
    tree = VoxelOctree(0.1)
    stats = tree.insert_scan(points, (0.0, 0.0, 0.0), max_range=max_range)
    assert stats.beams_cut == 1
    along_x = tree.logodds_at(
        np.array([[1.05, 0.05, 0.05], [4.85, 0.05, 0.05], [5.35, 0.05, 0.05]])
    )
    assert along_x[0] < 0 and along_x[1] < 0  # free up to max range
    assert np.isnan(along_x[2])  # unknown beyond it
    along_y = tree.logodds_at(np.array([[0.05, 3.05, 0.05], [0.05, 1.55, 0.05]]))
    assert along_y[0] > 0 and along_y[1] < 0  # the hit at 3 m, free before it
