"""Pose correction for 2D laser scans: scan-to-map matching with the odometry as prior, loop
closures found by correlative search and checked, a pose graph with robust kernels.

The steps, as Cartographer and slam_toolbox split them:

1. **Local matching** (:func:`local_matching`): each scan is matched by ICP to a local map of
   the last key scans (a key scan every :attr:`Settings.key_step` metres or
   :attr:`Settings.key_turn` radians), starting from the previous pose moved by the odometry's
   step. A scan ICP cannot place (too few points near the map) keeps the odometry's step.
2. **Submaps** every :attr:`Settings.submap_every` metres of travel: the scans within
   :attr:`Settings.submap_reach` metres of travel around an anchor scan, placed by step 1 (which
   is exact over such spans), as a likelihood grid and an ICP map, in the anchor's frame.
3. **Loop closures** (:func:`correct`): every :attr:`Settings.query_every` metres, the scan (with
   its neighbours, for context) is searched for in the submaps that the current estimate puts
   near it and that were recorded at least :attr:`Settings.loop_min_travel` metres earlier.
   The search window grows with the travel between the two, as odometry error does, up to
   :attr:`Settings.max_window`. A candidate is kept when the correlative score, then ICP's
   inlier share within :attr:`Settings.inlier_distance`, pass their thresholds.
4. **The pose graph** (:mod:`.graph`), updated after each closure (so later searches start from
   the corrected poses) and solved once more at the end, without the closures it disagrees with.

Every step is deterministic: fixed orders, no randomness, one thread per library call.
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from scan2terrain.slam import pose2
from scan2terrain.slam.graph import Closure, PoseGraph
from scan2terrain.slam.matching import LikelihoodGrid, LocalMap, thin

Floats = NDArray[np.float64]
#: Submaps' grids held at once (each about 1 MB at 0.1 m).
SUBMAPS_HELD = 48


@dataclass(frozen=True)
class Settings:
    """Metres and radians."""

    cell: float = 0.05  #: scans thinned to one point per cell for ICP
    key_step: float = 0.25
    key_turn: float = math.radians(10)
    local_keys: int = 25  #: key scans in the local map
    icp_distance: float = 0.3  #: ICP's correspondence distance
    min_inliers: float = 0.3  #: below, a scan keeps the odometry's step
    submap_every: float = 2.0
    submap_reach: float = 5.0
    query_every: float = 1.0
    query_reach: float = 1.0  #: the query scan's neighbours within this travel join it
    loop_min_travel: float = 10.0
    grid_resolution: float = 0.1
    grid_sigma: float = 0.1
    min_window: float = 0.5
    window_per_metre: float = 0.1
    max_window: float = 8.0
    min_turn_window: float = math.radians(5)
    turn_window_per_metre: float = math.radians(1.0)
    max_turn_window: float = math.radians(45)
    min_score: float = 0.55
    inlier_distance: float = 0.1
    min_closure_inliers: float = 0.7
    candidates_per_query: int = 2
    refinements: int = 1  #: passes of scan-to-map ICP on the final poses
    refine_distance: float = 0.1


@dataclass
class Correction:
    """What :func:`correct` found."""

    poses: Floats  #: (K, 3) corrected sensor poses
    local: Floats  #: (K, 3) after local matching alone
    matched: int = 0  #: scans ICP placed (the others kept the odometry's step)
    closures: list[Closure] = field(default_factory=list)
    candidates: int = 0  #: loop closure searches made
    seconds: dict[str, float] = field(default_factory=dict)

    @property
    def accepted(self) -> int:
        return sum(c.kept for c in self.closures)


def _step_sigmas(steps: Floats) -> Floats:
    """Noise of a local matching step: a floor plus a share of the motion."""
    d = np.hypot(steps[:, 0], steps[:, 1])
    t = np.abs(steps[:, 2])
    lin = 0.01 + 0.05 * d
    ang = 0.002 + 0.05 * t + 0.01 * d
    return np.stack([lin, lin, ang], axis=1)


def local_matching(prior: Floats, scans: list[Floats], s: Settings) -> tuple[Floats, int]:
    """Each scan matched to the local map of the key scans before it (step 1)."""
    k = len(prior)
    est = np.empty_like(prior)
    est[0] = prior[0]
    steps = pose2.between(prior[:-1], prior[1:])
    keys: deque[Floats] = deque(maxlen=s.local_keys)
    keys.append(pose2.apply(est[0], scans[0]))
    local = LocalMap(thin(np.concatenate(list(keys)), s.cell)) if len(scans[0]) else None
    last_key = est[0]
    matched = 0
    for i in range(1, k):
        guess = pose2.compose(est[i - 1], steps[i - 1])
        est[i] = guess
        if local is not None and len(local) >= 10 and len(scans[i]) >= 10:
            pose, share = local.icp(scans[i], guess, s.icp_distance)
            if share >= s.min_inliers:
                est[i] = pose
                matched += 1
        moved = pose2.between(last_key, est[i])
        if len(scans[i]) and (
            math.hypot(moved[0], moved[1]) >= s.key_step or abs(moved[2]) >= s.key_turn
        ):
            keys.append(pose2.apply(est[i], scans[i]))
            local = LocalMap(thin(np.concatenate(list(keys)), s.cell))
            last_key = est[i]
    return est, matched


class _Submap:
    def __init__(self, anchor: int, members: NDArray[np.intp], local: Floats, scans: list[Floats],
                 s: Settings) -> None:  # fmt: skip
        self.anchor = anchor
        frame = local[anchor]
        parts = [pose2.apply(pose2.between(frame, local[m]), scans[m]) for m in members]
        pts = thin(np.concatenate(parts), s.cell)
        self.grid = LikelihoodGrid(pts, s.grid_resolution, s.grid_sigma, margin=1.0)
        self.map = LocalMap(pts)


def correct(prior: Floats, scans: list[Floats], s: Settings | None = None) -> Correction:
    """Corrected poses of the scans (points (N, 2) in each scan's own frame) whose prior poses
    are ``prior`` (K, 3), in time order."""
    s = s or Settings()
    t0 = time.perf_counter()
    thinned = [thin(p, s.cell) for p in scans]
    local, matched = local_matching(prior, thinned, s)
    t1 = time.perf_counter()
    steps = pose2.between(local[:-1], local[1:])
    graph = PoseGraph(local, _step_sigmas(steps))
    travel = pose2.path_lengths(local)
    out = Correction(poses=local, local=local, matched=matched)
    if len(prior) > 1 and travel[-1] > s.loop_min_travel:
        _close_loops(graph, out, travel=travel, scans=thinned, s=s)
    t2 = time.perf_counter()
    out.poses = graph.final() if graph.closures else local
    out.closures = graph.closures
    t3 = time.perf_counter()
    for _ in range(s.refinements):
        out.poses = refine(out.poses, thinned, s)
    t4 = time.perf_counter()
    out.seconds = {"local": t1 - t0, "loops": t2 - t1, "graph": t3 - t2, "refine": t4 - t3}
    return out


def refine(poses: Floats, scans: list[Floats], s: Settings) -> Floats:
    """Each scan matched once more, by ICP, to the map of all the scans at ``poses``: the
    consensus of every visit pulls each scan onto it (what remains of the graph's errors
    between closures is a few centimetres; ICP is started within them)."""
    parts = [pose2.apply(p, sc) for p, sc in zip(poses, scans, strict=True) if len(sc)]
    if not parts:
        return poses
    whole = LocalMap(thin(np.concatenate(parts), s.cell))
    out: Floats = poses.copy()
    for i, scan in enumerate(scans):
        if len(scan) >= 10:
            pose, share = whole.icp(scan, poses[i], s.refine_distance)
            if share >= s.min_inliers:
                out[i] = pose
    return out


def _marks(travel: Floats, every: float) -> NDArray[np.intp]:
    """The first scan past each multiple of ``every`` metres of travel."""
    bins = np.floor(travel / every).astype(np.int64)
    return np.flatnonzero(np.r_[True, bins[1:] != bins[:-1]])


def _close_loops(
    graph: PoseGraph, out: Correction, *, travel: Floats, scans: list[Floats], s: Settings
) -> None:
    anchors = _marks(travel, s.submap_every)
    submaps: dict[int, _Submap] = {}
    for q in _marks(travel, s.query_every):
        if travel[q] < s.loop_min_travel:
            continue
        est = graph.estimate
        old = anchors[travel[anchors] <= travel[q] - s.loop_min_travel]
        if len(old) == 0:
            continue
        gap = travel[q] - travel[old]
        window = np.minimum(s.max_window, s.min_window + s.window_per_metre * gap)
        dist = np.hypot(est[old, 0] - est[q, 0], est[old, 1] - est[q, 1])
        near = np.flatnonzero(dist <= window + s.submap_reach / 2)
        if len(near) == 0:
            continue
        query = _query_points(q, travel, out.local, scans, s)
        if len(query) < 20:
            continue
        coarse = thin(query, s.grid_resolution)  # the search needs one point per grid cell
        tried: list[float] = []
        for j in near[np.argsort(dist[near], kind="stable")]:
            a = int(old[j])
            if any(abs(travel[a] - t) < 2 * s.submap_reach for t in tried):
                continue  # one search per earlier visit of the place
            if len(tried) >= s.candidates_per_query:
                break
            tried.append(float(travel[a]))
            out.candidates += 1
            sub = submaps.get(a)
            if sub is None:
                members = np.flatnonzero(np.abs(travel - travel[a]) <= s.submap_reach)
                sub = submaps[a] = _Submap(a, members, out.local, scans, s)
                if len(submaps) > SUBMAPS_HELD:  # the oldest made goes first
                    del submaps[next(iter(submaps))]
            guess = pose2.between(est[a], est[q])
            turn = min(s.max_turn_window, s.min_turn_window + s.turn_window_per_metre * gap[j])
            found = sub.grid.match(coarse, guess, float(window[j]), turn, s.min_score)
            if found is None:
                continue
            pose, _ = sub.map.icp(query, found.pose, 2 * s.grid_resolution)
            if sub.map.inliers(query, pose, s.inlier_distance) < s.min_closure_inliers:
                continue
            graph.add(Closure(a, int(q), pose, found.score))


def _query_points(
    q: int, travel: Floats, local: Floats, scans: list[Floats], s: Settings
) -> Floats:
    """Scan ``q`` with its neighbours within ``query_reach`` of travel, in ``q``'s frame."""
    members = np.flatnonzero(np.abs(travel - travel[q]) <= s.query_reach)
    parts = [pose2.apply(pose2.between(local[q], local[m]), scans[m]) for m in members]
    return thin(np.concatenate(parts), s.cell)
