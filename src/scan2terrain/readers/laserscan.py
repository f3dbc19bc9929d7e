"""sensor_msgs/LaserScan messages -> points in the laser frame, ready for the octree.

Reading i lies along the angle ``angle_min + i * angle_increment`` (radians, CCW about the laser's
z axis), in the laser's xy plane (z = 0). The readings mean (REP 117):

* finite, ``range_min <= r < range_max``: an obstacle at ``r`` (a hit);
* ``+inf`` or finite ``>= range_max``: nothing within range (the beam only clears);
* ``NaN``, ``-inf`` (too close) or ``r < range_min``: no information (dropped).

The octree (``VoxelOctree.insert_scan(points, origin, max_range=...)``, OctoMap's model) cuts
beams longer than ``max_range`` at ``max_range`` and lets them only clear, so a clear-only beam is
returned as a point far beyond the returned max range, and hits all lie inside it. Computed with
numpy over all readings at once.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError

#: The returned max range exceeds the cut-off by this fraction, so a hit just below ``range_max``
#: stays a hit after the octree computes its distance from float32 coordinates (relative error
#: ~1e-7 per coordinate; 1e-5 leaves room for sensor poses tens of range lengths from the origin).
RANGE_SLACK = 1e-5
#: Clear-only beams end this many max ranges from the sensor (anything > 1 works).
CLEAR_FACTOR = 2.0


def laserscan_points(msg: Any, max_range: float | None = None) -> tuple[NDArray[np.float64], float]:
    """Points of a LaserScan in the laser frame, and the max range to insert them with.

    Parameters
    ----------
    msg : sensor_msgs/msg/LaserScan
        As rosbags deserialises it, or any object with ``angle_min``, ``angle_increment``
        (radians), ``range_min``, ``range_max`` (metres) and ``ranges`` (metres, float32 array).
        ``intensities`` are ignored.
    max_range : float, optional
        A shorter cut-off than the scanner's ``range_max`` (metres, > 0): readings at or beyond it
        become clear-only too. Ignored when not below ``range_max``.

    Returns
    -------
    points : float64 array, shape (N, 3)
        Metres, laser frame, z = 0, in reading order (dropped readings left out): hits at their
        range, clear-only beams at ``2 * max_range`` along their direction.
    max_range : float
        The cut-off for ``insert_scan``: ``min(range_max, max_range)`` plus a relative
        ``RANGE_SLACK``; every hit lies within it and every clear-only point beyond it.

    Raises
    ------
    InputError
        For a non-finite angle, ``angle_increment`` 0 with more than one reading, a
        ``range_max`` that is not a positive number, or a ``range_min`` that is not in
        ``[0, range_max)``.
    ValueError
        For a ``max_range`` argument that is not a positive number.
    """
    ranges = np.asarray(msg.ranges, dtype=np.float64).reshape(-1)
    angle_min, increment = float(msg.angle_min), float(msg.angle_increment)
    range_min, range_max = float(msg.range_min), float(msg.range_max)
    if not (math.isfinite(angle_min) and math.isfinite(increment)):
        raise InputError(
            None, f"LaserScan angles must be finite (angle_min {angle_min}, increment {increment})"
        )
    if increment == 0.0 and ranges.size > 1:
        raise InputError(None, f"LaserScan angle_increment is 0 with {ranges.size} readings")
    if not (range_max > 0.0 and math.isfinite(range_max)):
        raise InputError(None, f"LaserScan range_max must be a positive number, got {range_max}")
    if not 0.0 <= range_min < range_max:
        raise InputError(
            None, f"LaserScan range_min {range_min} must be in [0, range_max {range_max})"
        )
    limit = range_max
    if max_range is not None:
        if not (max_range > 0.0 and math.isfinite(max_range)):
            raise ValueError(f"max_range must be a positive number of metres, got {max_range}")
        limit = min(limit, float(max_range))
    cutoff = limit * (1.0 + RANGE_SLACK)

    with np.errstate(invalid="ignore"):  # NaN comparisons are False, as wanted
        usable = ranges >= range_min  # False for NaN; True for +inf
        hit = usable & (ranges < limit)
        clear = usable & (ranges >= limit)  # also +inf
    keep = np.flatnonzero(hit | clear)
    distance = np.where(hit[keep], ranges[keep], CLEAR_FACTOR * cutoff)
    angles = angle_min + increment * keep.astype(np.float64)
    points = np.zeros((keep.size, 3))
    points[:, 0] = distance * np.cos(angles)
    points[:, 1] = distance * np.sin(angles)
    return points, cutoff
