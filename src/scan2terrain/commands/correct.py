"""Pose correction of a recording (``scans.correct``): which case applies, the scans read once
with their recorded poses, slam/ run on them, and the result judged and kept or not.

    plan (poses, tf) -> case (auto: odometry only?) -> posed scans of one topic, levelled to
    the plane -> slam.planar.correct -> agreement before/after (replay/agreement.py) ->
    plan.correction (a PoseCorrection every later pose lookup applies)

The correction is computed on the scan topic with the most messages (LaserScan before
PointCloud2); other topics move with it (:class:`PoseCorrection` interpolates). A 3D cloud is
matched by its slice within :data:`SLICE` of the sensor's height: the correction is planar (x,
y, yaw), as a ground robot's drift is.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from scan2terrain.config import Config
from scan2terrain.readers.messages import POINT_CLOUD2
from scan2terrain.readers.points import hits_of
from scan2terrain.readers.poses import matrices_to_quaternions
from scan2terrain.readers.scans import odometry_only, posed_scans
from scan2terrain.replay.agreement import agreement
from scan2terrain.types import PoseCorrection, ScanCounts

if TYPE_CHECKING:
    from scan2terrain.readers.bag import Bag
    from scan2terrain.readers.scans import BagPlan

#: Metres above and below the sensor: a 3D cloud's points matched in the plane.
SLICE = 0.25
#: The grid the agreement is measured on (metres).
AGREEMENT_CELL = 0.05


def decide(cfg: Config, plan: BagPlan) -> tuple[bool, str]:
    """Whether the plan's poses are to be corrected, and why (or why not): ``inspect``'s line
    and the report's."""

    mode = cfg.scans.correct
    if mode == "off":
        return False, "correction: none (--correct off)"
    if plan.poses == "fixed":
        return False, "correction: none (one fixed pose: a stationary sensor)"
    if mode == "on":
        return True, "--correct on"
    odometry, why = odometry_only(plan)
    if not odometry:
        return False, f"correction: none ({why}; --correct on corrects them too)"
    return True, why


def correct_plan(bag: Bag, cfg: Config, plan: BagPlan) -> list[str]:
    """Decide, compute and judge the correction of the plan's poses; sets ``plan.correction``
    when corrected poses are kept. Returns the report's lines."""
    if not plan.scan_topics:
        return []
    correct, why = decide(cfg, plan)
    if not correct:
        return [] if cfg.scans.correct == "off" else [why]
    return _correct(bag, cfg, plan, why)


def _topic(bag: Bag, plan: BagPlan) -> str:

    counts = bag.count(plan.scan_topics, plan.start_ns, plan.end_ns)
    return max(
        plan.scan_topics,
        key=lambda t: (bag.topics[t].msgtype != POINT_CLOUD2, counts.get(t, 0), t),
    )


def _correct(bag: Bag, cfg: Config, plan: BagPlan, why: str) -> list[str]:

    from scan2terrain.slam import planar

    topic = _topic(bag, plan)
    stamps: list[int] = []
    prior: list[tuple[float, float, float]] = []
    xyz: list[NDArray[np.float64]] = []
    rotations: list[NDArray[np.float64]] = []
    flat: list[NDArray[np.float64]] = []
    recorded = replace(plan, scan_topics=[topic], correction=None)
    for scan in posed_scans(bag, cfg.scans, recorded, ScanCounts(), max_range=cfg.octree.max_range):
        rel = hits_of(scan) - scan.origin
        rel = rel[np.abs(rel[:, 2]) <= SLICE]
        c, s = math.cos(scan.heading), math.sin(scan.heading)
        flat.append(np.stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]], 1))
        stamps.append(scan.stamp_ns)
        prior.append((float(scan.origin[0]), float(scan.origin[1]), scan.heading))
        xyz.append(scan.origin)
        rotations.append(np.eye(3) if scan.rotation is None else scan.rotation)
    head = f"correction ({why}): {topic}"
    if len(stamps) < 2:
        return [f"{head}: {len(stamps)} scan(s), nothing to match"]
    order = np.argsort(np.asarray(stamps, np.int64), kind="stable")
    times = np.asarray(stamps, np.int64)[order]
    keep = np.r_[True, np.diff(times) > 0]  # one scan per stamp
    order = order[keep]
    before = np.asarray(prior)[order]
    scans = [flat[i] for i in order]
    result = planar.correct(before, scans)
    moved = np.hypot(*(result.poses[:, :2] - before[:, :2]).T)
    was, n_was = agreement(before, scans, AGREEMENT_CELL)
    now, n_now = agreement(result.poses, scans, AGREEMENT_CELL)
    lines = [
        f"{head}: {len(scans)} scans, {result.matched} placed by scan matching, "
        f"{result.candidates} loop closure searches: {result.accepted} closures kept, "
        f"{len(result.closures) - result.accepted} dropped by the pose graph",
        f"correction: poses moved {moved.mean():.3f} m on average, {moved.max():.3f} m at most",
        f"correction: beams agreeing within 10 cm with the other spans' hits: "
        f"{100 * was:.1f}% recorded -> {100 * now:.1f}% corrected "
        f"({n_was:,} and {n_now:,} beams compared)",
    ]
    if cfg.scans.correct == "auto" and now <= was:
        lines.append("correction: not kept (the recorded poses agree as well or better)")
        return lines
    plan.correction = PoseCorrection(
        stamps_ns=times[keep],
        prior=before,
        corrected=result.poses,
        prior_xyz=np.asarray(xyz)[order],
        prior_xyzw=matrices_to_quaternions(np.asarray(rotations)[order]),
        notes=tuple(lines),
    )
    return lines
