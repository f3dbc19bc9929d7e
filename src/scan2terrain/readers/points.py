"""What scans and clouds contribute in the map frame, shared by the octree path
(commands/scans.py) and the streamed path (commands/stream.py): a posed scan's hits, where the
recording started, and the local origin subtracted from clouds far from theirs (UTM)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from scan2terrain.types import Pose2D, Scan, StartPose

#: Beyond this distance from the origin (metres) cloud files get a local origin (auto).
FAR = 1000.0


def hits_of(scan: Scan) -> NDArray[np.float64]:
    """A scan's hits: its points, less a LaserScan's clear-only beams (beyond max range)."""
    return within_reach(scan.points, scan.origin, scan.max_range)


def within_reach(
    points: NDArray[np.float64], sensor: NDArray[np.float64], reach: float
) -> NDArray[np.float64]:
    """The points within ``reach`` metres of the sensor (all of them when ``reach`` <= 0)."""
    if reach <= 0:
        return points
    rel = points - sensor
    near: NDArray[np.float64] = points[np.einsum("ij,ij->i", rel, rel) <= reach**2]
    return near


def start_of(scan: Scan) -> StartPose:
    """Where the robot was at its first posed scan: the sensor's position and heading."""
    x, y = float(scan.origin[0]), float(scan.origin[1])
    why = f"from the recorded start ({scan.topic} at {scan.stamp_ns / 1e9:.3f} s)"
    return StartPose(Pose2D(x, y, scan.heading), why)


def local_origin(
    lo: NDArray[np.float64], hi: NDArray[np.float64], mode: str | list[float], notes: list[str]
) -> NDArray[np.float64]:
    """The origin to subtract from clouds spanning ``lo``..``hi`` (x, y, z): the one given
    (``scans.local_origin: [x, y, z]``), or their rounded centre when they lie beyond FAR of
    the origin and the mode is auto, else zero; a note says which was subtracted."""
    if isinstance(mode, list):
        shown = ", ".join(f"{v:.6f}".rstrip("0").rstrip(".") for v in mode)
        notes.append(
            f"local origin ({shown}) subtracted (scans.local_origin): world = cloud - origin"
        )
        return np.asarray(mode, dtype=np.float64)
    if mode != "auto" or max(np.abs(lo).max(), np.abs(hi).max()) <= FAR:
        return np.zeros(3)
    origin: NDArray[np.float64] = np.round((np.asarray(lo) + np.asarray(hi)) / 2)
    notes.append(
        "local origin ({:.0f}, {:.0f}, {:.0f}) subtracted: world = cloud - origin".format(*origin)
    )
    return origin
