"""Scan matching in the plane: ICP against a local map (small_gicp), and the correlative search
with branch and bound that finds loop closures far from the current estimate.

Two matchers because they answer two questions. ICP (small_gicp's point-to-point, on scans
lifted to z = 0; its point-to-plane and GICP need surfaces and degenerate on a flat scan) refines
a pose it is already close to, in a millisecond. The correlative matcher (Olson 2009; Cartographer's
``FastCorrelativeScanMatcher2D``) finds the best placement of a scan anywhere in a window of
metres and tens of degrees on a likelihood grid of a submap, exactly, by branch and bound
(:mod:`._bnb_kernels`); no well-kept Python library does it, so it is written here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import small_gicp
from numpy.typing import NDArray
from scipy import ndimage

from scan2terrain.slam import pose2
from scan2terrain.slam._bnb_kernels import branch_and_bound

Points = NDArray[np.float64]


def lift(points: NDArray[np.floating]) -> NDArray[np.float64]:
    """(N, 2) planar points as (N, 3) at z = 0, as small_gicp takes them."""
    out = np.zeros((len(points), 3))
    out[:, :2] = points[:, :2]
    return out


def thin(points: NDArray[np.floating], cell: float) -> NDArray[np.float64]:
    """One point per ``cell`` x ``cell`` square (their mean), in a fixed order: a scan's points
    spread evenly, so that near walls do not outweigh far ones."""
    p = np.asarray(points, np.float64)[:, :2]
    if len(p) == 0:
        return p
    cells = np.floor(p / cell).astype(np.int64)
    cells -= cells.min(axis=0)
    # One integer per cell, ordered as the rows (x, then y) would sort: a 1D unique is many
    # times faster than numpy's row-wise one.
    keys = cells[:, 0] * (int(cells[:, 1].max()) + 1) + cells[:, 1]
    _, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
    sums = np.stack(
        [np.bincount(inverse, p[:, 0], len(counts)), np.bincount(inverse, p[:, 1], len(counts))],
        axis=1,
    )
    means: NDArray[np.float64] = sums / counts[:, None]
    return means


class LocalMap:
    """Points in the map frame, ready for ICP (small_gicp's cloud and k-d tree)."""

    def __init__(self, points: Points) -> None:
        self.points = points
        self.cloud = small_gicp.PointCloud(lift(points))
        self.tree = small_gicp.KdTree(self.cloud)

    def __len__(self) -> int:
        return len(self.points)

    def icp(
        self, scan: Points, guess: NDArray[np.float64], max_distance: float, iterations: int = 30
    ) -> tuple[NDArray[np.float64], float]:
        """The scan's pose (x, y, yaw) in the map frame, from ``guess``; and the fraction of
        its points within ``max_distance`` of the map afterwards."""
        result = small_gicp.align(
            self.cloud,
            small_gicp.PointCloud(lift(scan)),
            self.tree,
            init_T_target_source=pose2.matrix(guess),
            registration_type="ICP",
            max_correspondence_distance=max_distance,
            num_threads=1,
            max_iterations=iterations,
        )
        return pose2.from_matrix(result.T_target_source), result.num_inliers / max(len(scan), 1)

    def inliers(self, scan: Points, pose: NDArray[np.float64], distance: float) -> float:
        """The fraction of the scan's points (placed at ``pose``) within ``distance`` of the
        map."""
        placed = small_gicp.PointCloud(lift(pose2.apply(pose, scan)))
        _, d2 = self.tree.batch_nearest_neighbor_search(placed.points(), num_threads=1)
        return float(np.mean(np.asarray(d2) <= distance * distance)) if len(scan) else 0.0


@dataclass(frozen=True)
class Match:
    pose: NDArray[np.float64]  #: x, y, yaw of the scan's frame in the grid's frame
    score: float  #: mean likelihood of its points, 0 .. 1


class LikelihoodGrid:
    """A submap as a likelihood field: 1 on a cell holding a point, falling off as a Gaussian
    of the distance to the nearest one (``sigma`` metres); with its branch-and-bound bounds."""

    DEPTH = 7
    REACH = 15.0  #: metres

    def __init__(self, points: Points, resolution: float, sigma: float, margin: float) -> None:
        self.resolution = resolution
        lo = points.min(axis=0) - margin
        hi = points.max(axis=0) + margin
        self.origin = lo
        shape = np.ceil((hi - lo) / resolution).astype(np.int64) + 1
        cells = np.floor((points - lo) / resolution).astype(np.int64)
        empty = np.ones((int(shape[1]), int(shape[0])), bool)
        empty[cells[:, 1], cells[:, 0]] = False
        dist = ndimage.distance_transform_edt(empty) * resolution
        field = np.exp(-0.5 * (dist / sigma) ** 2).astype(np.float32)
        levels = [field]
        for d in range(1, self.DEPTH + 1):
            half = 1 << (d - 1)
            prev = levels[-1]
            b = prev.copy()
            b[:, :-half] = np.maximum(prev[:, :-half], prev[:, half:])
            c = b.copy()
            c[:-half, :] = np.maximum(b[:-half, :], b[half:, :])
            levels.append(c)
        self.bounds = np.stack(levels)

    def match(
        self,
        scan: Points,
        guess: NDArray[np.float64],
        linear: float,
        angular: float,
        min_score: float,
    ) -> Match | None:
        """The best placement of the scan (points in its own frame) within ``linear`` metres and
        ``angular`` radians of ``guess``, if it scores above ``min_score``."""
        if len(scan) == 0:
            return None
        res = self.resolution
        # Cartographer's angular step: the farthest point moves by about one cell. Points
        # farther than REACH count, but do not make the step finer.
        reach = min(self.REACH, float(np.max(np.hypot(scan[:, 0], scan[:, 1]))))
        step = math.acos(max(-1.0, 1 - res * res / (2 * max(reach, res) ** 2)))
        n_rot = math.ceil(angular / step)
        angles = guess[2] + step * np.arange(-n_rot, n_rot + 1)
        c, s = np.cos(angles)[:, None], np.sin(angles)[:, None]
        wx = c * scan[:, 0] - s * scan[:, 1] + guess[0]
        wy = s * scan[:, 0] + c * scan[:, 1] + guess[1]
        half = math.ceil(linear / res)
        cx = np.floor((wx - self.origin[0]) / res).astype(np.int32) - half
        cy = np.floor((wy - self.origin[1]) / res).astype(np.int32) - half
        depth = min(self.DEPTH, max(0, math.ceil(math.log2(2 * half + 1))))
        score, r, ox, oy = branch_and_bound(
            self.bounds[: depth + 1], cx, cy, 2 * half + 1, float(min_score)
        )
        if r < 0:
            return None
        # The placement's cells, back to a pose: the offset moves the scan's frame.
        pose = np.array([guess[0] + (ox - half) * res, guess[1] + (oy - half) * res, angles[r]])
        return Match(pose, float(score))
