"""What a recording's topics carry (the message type names the pipeline reads, ROS's and
Foxglove's), and times a user gives against a recording. Light: no rosbags, so the modules
that plan and pose scans can name them without loading the bag readers (readers/bag.py)."""

from __future__ import annotations

from decimal import Decimal, InvalidOperation
from typing import Protocol

from scan2terrain.errors import InputError
from scan2terrain.readers import foxglove

#: Message types the pipeline consumes (ROS 2 names; ROS1 bags report the same names).
LASER_SCAN = "sensor_msgs/msg/LaserScan"
POINT_CLOUD2 = "sensor_msgs/msg/PointCloud2"
OCCUPANCY_GRID = "nav_msgs/msg/OccupancyGrid"
ODOMETRY = "nav_msgs/msg/Odometry"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
#: ROS1's pre-tf2 ``tf/tfMessage``: the same layout (``geometry_msgs/TransformStamped[]``).
TF_MESSAGE_ROS1_OLD = "tf/msg/tfMessage"
TF_TYPES = frozenset({TF_MESSAGE, TF_MESSAGE_ROS1_OLD, *foxglove.TF_TYPES})
#: Scans: ROS's, and Foxglove's ``foxglove.LaserScan`` / ``foxglove.PointCloud`` in MCAP.
SCAN_TYPES = frozenset({LASER_SCAN, POINT_CLOUD2, *foxglove.SCAN_TYPES})
#: Occupancy grids: ``nav_msgs/OccupancyGrid``, and ``foxglove.Grid`` in MCAP.
MAP_TYPES = frozenset({OCCUPANCY_GRID, foxglove.GRID})
#: Poses of the robot base over time: odometry, and ``foxglove.PoseInFrame`` in MCAP.
ODOMETRY_TYPES = frozenset({ODOMETRY, foxglove.POSE_IN_FRAME})

#: Values at or above this many seconds are absolute UNIX times in :func:`resolve_time`.
ABSOLUTE_TIME_S = 1e9


class _Span(Protocol):
    start_ns: int
    end_ns: int


def resolve_time(value: str | float | None, bag: _Span) -> int | None:
    """A user-given time as bag time in nanoseconds (None stays None: no bound).

    Parameters
    ----------
    value : str, float or None
        Seconds. ``>= 1e9`` is an absolute UNIX time; smaller values count from the bag's first
        message (``"12.5"`` is 12.5 s into the bag).
    bag : Bag
        The bag the time refers to.

    Returns
    -------
    int or None
        Nanoseconds, clamped to ``[start_ns - 1, end_ns + 1]``: a bound before the bag admits
        every message from its start, one after it every message to its end, and a range that
        lies outside the bag is empty (see :meth:`Bag.require_messages`).

    Raises
    ------
    InputError
        Not a number.
    """
    if value is None:
        return None
    try:  # Decimal keeps "1663929585.503548227" exact, float would round it to ~200 ns
        seconds = Decimal(value if isinstance(value, str) else repr(float(value)))
    except (InvalidOperation, TypeError, ValueError):
        raise InputError(None, f"time {value!r} is not a number of seconds") from None
    if not seconds.is_finite():
        raise InputError(None, f"time {value!r} is not a finite number of seconds")
    ns = int((seconds * 1_000_000_000).to_integral_value())
    if seconds < ABSOLUTE_TIME_S:
        ns += bag.start_ns
    return min(max(ns, bag.start_ns - 1), bag.end_ns + 1)
