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

import bz2
import gzip
import math
from collections.abc import Sequence
from dataclasses import dataclass
from decimal import Decimal
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
from tests.fixtures import MIT

DEFAULT_LOG = MIT
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


# --- writing logs (the CARMEN reader's tests) --------------------------------------------------

T0 = 1_134_864_629.5  # seconds, as the logs' ipc_timestamps
Pose = tuple[float, float, float]


def fmt(values: Sequence[float]) -> str:
    return " ".join(f"{v:.6f}" for v in values)


def flaser(ranges: Sequence[float], laser: Pose, odom: Pose, t: float, kind: str = "FLASER") -> str:
    return f"{kind} {len(ranges)} {fmt(ranges)} {fmt(laser)} {fmt(odom)} {t:.6f} host {t - T0:.6f}"


def robotlaser(
    ranges: Sequence[float],
    laser: Pose,
    robot: Pose,
    t: float,
    *,
    start: float = -math.pi / 2,
    res: float = math.radians(45),
    fov: float = math.pi,
    max_range: float = 30.0,
    laser_type: int = 0,
    remissions: Sequence[float] = (),
    kind: str = "ROBOTLASER1",
) -> str:
    config = f"{laser_type} {start:.6f} {fov:.6f} {res:.6f} {max_range:.6f} 0.010000 0"
    rem = f"{len(remissions)} {fmt(remissions)}".strip()
    return (
        f"{kind} {config} {len(ranges)} {fmt(ranges)} {rem} {fmt(laser)} {fmt(robot)} "
        f"0.1 0.0 0.5 0.3 1000000.0 {t:.6f} host {t - T0:.6f}"
    )


def odom_line(pose: Pose, t: float) -> str:
    return f"ODOM {fmt(pose)} 0.100000 0.000000 0.000000 {t:.6f} host {t - T0:.6f}"


def ns(t: float) -> int:
    """A stamp as the log writes it (6 decimals), in nanoseconds."""
    return int(Decimal(f"{t:.6f}") * 10**9)


def compose(a: Pose, b: Pose) -> Pose:
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2])


def write(path: Path, lines: Sequence[str], compression: str | None = None) -> Path:
    text = ("\n".join(lines) + "\n").encode()
    if compression == "gz":
        text = gzip.compress(text, mtime=0)
    elif compression == "bz2":
        text = bz2.compress(text)
    path.write_bytes(text)
    return path


#: Odometry of a robot driving along x and turning a little.
ODOM: list[Pose] = [(0.1 * k, 0.02 * k, 0.05 * k) for k in range(6)]
RANGES = [1.0, 2.0, 3.0, 4.0, 5.0]


# --- damaged logs: the line each holds and the refusal it must give ---------------------------

GOOD = flaser(RANGES, ODOM[0], ODOM[0], T0)
GOOD_RL = robotlaser(RANGES, ODOM[0], ODOM[0], T0)

#: case -> (the log's lines, or bytes; what the one line says)
DAMAGED: dict[str, tuple[list[str] | bytes, str]] = {
    "cut short": ([GOOD, GOOD[:60]], "line 2: FLASER is cut short: has 8 fields, expected 16"),
    "not a number": (
        [GOOD.replace(" 3.000000 ", " 3.0x0 ")],
        "line 1: FLASER field 5 '3.0x0' is not a number",
    ),
    "count that does not match": (
        [GOOD.replace("FLASER 5 ", "FLASER 6 ")],
        "line 1: FLASER is cut short: has 16 fields, expected 17 (the count, 6 readings",
    ),
    "count that is not a count": (
        [GOOD.replace("FLASER 5 ", "FLASER 5.0 ")],
        "line 1: FLASER count of readings '5.0' is not a count",
    ),
    "non-finite range": (
        [GOOD.replace(" 3.000000 ", " nan ")],
        "line 1: FLASER reading 3 is nan: not a range (finite, >= 0)",
    ),
    "infinite range": (
        [GOOD.replace(" 3.000000 ", " inf ")],
        "line 1: FLASER reading 3 is inf: not a range",
    ),
    "negative range": (
        [GOOD.replace(" 3.000000 ", " -3.000000 ")],
        "line 1: FLASER reading 3 is -3.0: not a range",
    ),
    "no beams": (["FLASER 0 0 0 0 0 0 0 1.0 host 0"], "line 1: FLASER has no readings (count 0)"),
    "millions of beams": (
        ["FLASER 5000000 1 2 3"],
        "line 1: FLASER says 5,000,000 readings: more than 100,000, not a 2D laser scan",
    ),
    "fov over a turn": (
        [robotlaser(RANGES, ODOM[0], ODOM[0], T0, fov=7.0)],
        "line 1: ROBOTLASER1 field of view 7.0 rad is not in (0, 2 pi]",
    ),
    "absurd max range": (
        [robotlaser(RANGES, ODOM[0], ODOM[0], T0, max_range=1e6)],
        "line 1: ROBOTLASER1 maximum range 1000000.0 m is not in (0, 1000]",
    ),
    "no resolution": (
        [robotlaser(RANGES, ODOM[0], ODOM[0], T0, res=0.0)],
        "line 1: ROBOTLASER1 angular resolution 0.0 rad over 5 readings is not a 2D scan",
    ),
    "remissions cut short": (
        [GOOD_RL.replace(" 0 0.000000 0.000000 0.000000 0.000000", " 9 0.000000 0.000000", 1)],
        "line 1: ROBOTLASER1 ",
    ),
    "non-finite pose": (
        [
            GOOD.replace(
                " 0.000000 0.000000 0.000000 0.000000 0.000000 0.000000 ", " inf 0 0 0 0 0 "
            )
        ],
        "line 1: FLASER has a pose value that is not finite",
    ),
    "bad timestamp": (
        [GOOD.replace(f"{T0:.6f} host", "yesterday host")],
        "line 1: FLASER ipc_timestamp 'yesterday' is not a time in seconds",
    ),
    "resolution PARAM not a number": (
        ["PARAM laser_front_laser_resolution fine nohost 0", GOOD],
        "line 1: PARAM laser_front_laser_resolution 'fine' is not a finite number",
    ),
    "absurd fov PARAM": (
        ["PARAM laser_front_laser_fov 720 nohost 0", GOOD],
        "line 1: PARAM laser_front_laser_fov 720 is not in (0, 360] deg",
    ),
    "absurd offset PARAM": (
        ["PARAM robot_frontlaser_offset 1e9 nohost 0", GOOD],
        "line 1: PARAM robot_frontlaser_offset 1e+09 is not a laser's offset",
    ),
    "empty log": ([], "the log is empty"),
    "comments only": (["# CARMEN Logfile"], "no laser records (FLASER, RLASER, ROBOTLASER1"),
    "no laser lines": (
        [odom_line(ODOM[0], T0), "PARAM robot_use_laser on nohost 0"],
        "no laser records (FLASER, RLASER, ROBOTLASER1, ROBOTLASER2): nothing to map; the log "
        "holds ODOM 1, PARAM 1",
    ),
    "binary junk": (
        b"# CARMEN Logfile\nFLASER \x00\x01\x02\xff\xfe\n",
        "line 2 holds binary data (byte 0x00): not a CARMEN log",
    ),
    "junk record": (["$%& 1 2 3", GOOD], "line 1: '$%&' is not a CARMEN record type"),
    "odom cut short": (["ODOM 1 2 3 0 0 0 1.0", GOOD], "line 1: ODOM is cut short: has 8 fields"),
}


def damaged_log(tmp: Path, case: str) -> tuple[Path, str]:
    content, message = DAMAGED[case]
    path = tmp / "damaged.clf"
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text("".join(f"{line}\n" for line in content))
    return path, message
