"""The real MIT CSAIL CARMEN laser log as a ROS bag, and as posed scans for OctoMap.

CARMEN logs are text, one record per line, read by :mod:`scan2terrain.readers.carmen` (which
also makes bag2world read them directly). This log (``fixtures/logs/raw_carmen_mit_csail``)
holds 1988 ``FLASER`` lines::

    FLASER n r_1 .. r_n  x y theta  odom_x odom_y odom_theta  ipc_timestamp host logger_timestamp

``n`` = 361 beams over 180 degrees (-90 .. +90, 0.5 degree steps), ranges in metres, 81.91 = no
return (the SICK's overflow code). ``x y theta`` is the laser's pose; in *this* log it equals the
odometry pose on every line (checked by the tests), so the trajectory is raw odometry, not a
corrected one. ``ipc_timestamp`` is UNIX time; ``logger_timestamp`` counts from the start of the
log. ``ROBOTLASER1`` lines (other logs of the same collection) are read too. ``ODOM`` and other
records are ignored here: the laser records carry the poses.

The bag (:func:`carmen_to_bag`) has ``/scan`` LaserScan (frame ``laser``), ``/tf`` odom ->
base_link at every scan's stamp, and ``/tf_static`` base_link -> laser (``mount``): base_link is
placed so that base_link * mount is the logged laser pose, so the laser ends where CARMEN says it
was. :func:`carmen_scans` gives the same scans directly as world-frame points and sensor origins
(for inserting into octomap-python), computed from the float32 ranges the bag holds.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from tests.bagmaker import (
    LASER_SCAN,
    TF_MESSAGE,
    Fmt,
    MsgSpec,
    laserscan_msg,
    tf_msg,
    write_bag,
    yaw_quaternion,
)

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_LOG = ROOT / "fixtures/logs/raw_carmen_mit_csail/mit-csail.clf.bz2"
#: Readings at or above this are the SICK's "no return" code (81.91 m).
NO_RETURN = 81.9
#: LaserScan limits written to the bag: no-return readings lie above ``RANGE_MAX``.
RANGE_MIN = 0.05
RANGE_MAX = 80.0


@dataclass(frozen=True)
class CarmenLog:
    """The laser records of a CARMEN log.

    Attributes
    ----------
    stamps_ns : int64 (K,)
        ``ipc_timestamp`` of each scan, UNIX nanoseconds.
    ranges : float32 (K, B)
        Metres; >= ``NO_RETURN`` means no return.
    laser_poses : float64 (K, 3)
        Laser x, y (metres), theta (radians) in the log's world frame.
    odom_poses : float64 (K, 3)
        Odometry (FLASER) or robot (ROBOTLASER1) pose, same frame.
    angle_min, angle_increment : float
        Beam angles in the laser frame, radians (beam i at ``angle_min + i * angle_increment``).
    """

    stamps_ns: NDArray[np.int64]
    ranges: NDArray[np.float32]
    laser_poses: NDArray[np.float64]
    odom_poses: NDArray[np.float64]
    angle_min: float
    angle_increment: float

    def __len__(self) -> int:
        return len(self.stamps_ns)


def read_carmen(
    path: Path = DEFAULT_LOG, *, every: int = 1, max_scans: int | None = None
) -> CarmenLog:
    """The front laser records of a CARMEN log (``.clf``, ``.bz2``, ``.gz``), parsed by
    :mod:`scan2terrain.readers.carmen` (FLASER or ROBOTLASER1; their beam geometry as it says).

    Parameters
    ----------
    path : Path
        The log.
    every : int
        Keep every ``every``-th scan (1 = all).
    max_scans : int, optional
        Stop after this many kept scans.

    Raises
    ------
    ValueError
        A damaged log (:class:`~scan2terrain.errors.InputError` naming the file and line), or
        scans of different geometry in one log.
    """
    from scan2terrain.readers.carmen import CarmenFile

    reader = CarmenFile(Path(path))
    front = next(las for las in reader.lasers if las.topic == "/scan")
    rec, beams = front.records, front.beams
    keep = np.arange(0, len(rec), every)[:max_scans]
    counts = rec.counts
    same = (counts == counts[0]).all() and (beams.angle_min == beams.angle_min[0]).all()
    if not same or not (beams.angle_increment == beams.angle_increment[0]).all():
        raise ValueError(f"{path}: scan geometry differs from the first scan")
    ranges = rec.ranges.reshape(len(rec), int(counts[0]))
    return CarmenLog(
        stamps_ns=rec.stamps_ns[keep],
        ranges=ranges[keep],
        laser_poses=rec.laser_poses[keep],
        odom_poses=rec.odom_poses[keep],
        angle_min=float(beams.angle_min[0]),
        angle_increment=float(beams.angle_increment[0]),
    )


def _poses(log: CarmenLog, pose: Literal["laser", "odom"]) -> NDArray[np.float64]:
    return log.laser_poses if pose == "laser" else log.odom_poses


def carmen_messages(
    log: CarmenLog,
    *,
    mount: tuple[float, float, float] = (0.2, 0.0, 0.3),
    pose: Literal["laser", "odom"] = "laser",
) -> list[MsgSpec]:
    """Bag messages for a CARMEN log: /scan, /tf odom->base_link, /tf_static base_link->laser.

    ``mount`` is the laser's x, y, z in base_link (no rotation); base_link's pose is the logged
    laser pose minus the mount, so the laser lands exactly on the logged pose.
    """
    p = _poses(log, pose)
    c, s = np.cos(p[:, 2]), np.sin(p[:, 2])
    bx = p[:, 0] - (c * mount[0] - s * mount[1])
    by = p[:, 1] - (s * mount[0] + c * mount[1])
    t0 = int(log.stamps_ns[0])
    messages: list[MsgSpec] = [
        (
            "/tf_static",
            TF_MESSAGE,
            t0,
            tf_msg([("base_link", "laser", t0, mount, (0.0, 0.0, 0.0, 1.0))]),
        )
    ]
    for k in range(len(log)):
        t = int(log.stamps_ns[k])
        scan = laserscan_msg(
            t, "laser", log.angle_min, log.angle_increment, log.ranges[k], RANGE_MIN, RANGE_MAX
        )
        messages.append(("/scan", LASER_SCAN, t, scan))
        edge = ("odom", "base_link", t, (bx[k], by[k], 0.0), yaw_quaternion(float(p[k, 2])))
        messages.append(("/tf", TF_MESSAGE, t, tf_msg([edge])))
    return messages


def carmen_to_bag(
    path: Path,
    log: CarmenLog | None = None,
    *,
    fmt: Fmt = "ros1",
    mount: tuple[float, float, float] = (0.2, 0.0, 0.3),
    pose: Literal["laser", "odom"] = "laser",
) -> Path:
    """Write a CARMEN log (default: the MIT CSAIL one, all scans) as a bag; see the module doc."""
    log = read_carmen() if log is None else log
    return write_bag(path, fmt, carmen_messages(log, mount=mount, pose=pose))


def carmen_scans(
    log: CarmenLog,
    *,
    mount_z: float = 0.3,
    pose: Literal["laser", "odom"] = "laser",
) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """Each scan's returns as world-frame points (N, 3) and the sensor origin (3,).

    Beams outside ``[RANGE_MIN, RANGE_MAX]`` (no return) are left out; points lie at height
    ``mount_z``, as the bag's laser frame does.
    """
    p = _poses(log, pose)
    angles = log.angle_min + log.angle_increment * np.arange(log.ranges.shape[1])
    out = []
    for k in range(len(log)):
        r = log.ranges[k].astype(np.float64)
        ok = (r >= RANGE_MIN) & (r <= RANGE_MAX)
        a = p[k, 2] + angles[ok]
        pts = np.column_stack(
            [p[k, 0] + r[ok] * np.cos(a), p[k, 1] + r[ok] * np.sin(a), np.full(ok.sum(), mount_z)]
        )
        out.append((pts, np.array([p[k, 0], p[k, 1], mount_z])))
    return out
