"""The pose graph: one node per scan, the scan matcher's steps between consecutive nodes, loop
closures between far ones; optimised by GTSAM.

GTSAM because it is the well-kept library made for this: ``Pose2`` factors, robust kernels and
ISAM2, the incremental solver that keeps the estimate current while closures arrive (each one
costs the loop's length, not the trajectory's). A closure's noise model is wrapped in a Cauchy
kernel, so a wrong closure that got through the matcher's checks pulls with a bounded force and
cannot fold the map; :meth:`PoseGraph.final` then drops the closures the optimised graph does
not agree with and solves again.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam
import numpy as np
from numpy.typing import NDArray

from scan2terrain.slam import pose2

#: The first node is held where the prior put it (metres, radians).
ANCHOR_SIGMAS = (1e-4, 1e-4, 1e-5)


def _pose(p: NDArray[np.float64]) -> gtsam.Pose2:
    return gtsam.Pose2(float(p[0]), float(p[1]), float(p[2]))


@dataclass
class Closure:
    """A loop closure: node ``later`` seen from node ``earlier``."""

    earlier: int
    later: int
    relative: NDArray[np.float64]
    score: float
    kept: bool = True


@dataclass
class PoseGraph:
    """Nodes 0 .. K-1 with initial poses; steps between neighbours; closures."""

    initial: NDArray[np.float64]  #: (K, 3)
    step_sigmas: NDArray[np.float64]  #: (K - 1, 3) of each step's noise
    closure_sigmas: tuple[float, float, float] = (0.05, 0.05, 0.01)
    cauchy: float = 1.0
    closures: list[Closure] = field(default_factory=list)

    def __post_init__(self) -> None:
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(0.01)
        params.relinearizeSkip = 1
        self._isam = gtsam.ISAM2(params)
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        for k, p in enumerate(self.initial):
            values.insert(k, _pose(p))
        for f in self._chain():
            graph.add(f)
        self._isam.update(graph, values)
        self._estimate = np.array(self.initial, dtype=np.float64)

    def _chain(self) -> list[gtsam.NonlinearFactor]:
        p = self.initial
        steps = pose2.between(p[:-1], p[1:])
        factors: list[gtsam.NonlinearFactor] = [
            gtsam.PriorFactorPose2(0, _pose(p[0]), gtsam.noiseModel.Diagonal.Sigmas(ANCHOR_SIGMAS))
        ]
        for k, (step, sig) in enumerate(zip(steps, self.step_sigmas, strict=True)):
            noise = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sig, np.float64))
            factors.append(gtsam.BetweenFactorPose2(k, k + 1, _pose(step), noise))
        return factors

    def _closure_factor(self, c: Closure) -> gtsam.NonlinearFactor:
        noise = gtsam.noiseModel.Robust.Create(
            gtsam.noiseModel.mEstimator.Cauchy.Create(self.cauchy),
            gtsam.noiseModel.Diagonal.Sigmas(np.asarray(self.closure_sigmas, np.float64)),
        )
        return gtsam.BetweenFactorPose2(c.earlier, c.later, _pose(c.relative), noise)

    def add(self, closure: Closure) -> None:
        """Add a closure and bring the estimate up to date (incrementally)."""
        self.closures.append(closure)
        graph = gtsam.NonlinearFactorGraph()
        graph.add(self._closure_factor(closure))
        self._isam.update(graph, gtsam.Values())
        self._isam.update()
        self._read(self._isam.calculateEstimate())

    def _read(self, values: gtsam.Values) -> None:
        self._estimate = np.asarray(gtsam.utilities.extractPose2(values), dtype=np.float64)

    @property
    def estimate(self) -> NDArray[np.float64]:
        return self._estimate

    def final(self, gate: float = 3.0) -> NDArray[np.float64]:
        """Batch-optimise the whole graph; drop the closures whose error there exceeds
        ``gate`` sigmas in any axis (worst first, one at a time, solving again after each), and
        return the poses."""
        while True:
            values = self._solve()
            worst, worst_err = None, gate
            for c in self.closures:
                if not c.kept:
                    continue
                rel = values.atPose2(c.earlier).between(values.atPose2(c.later))
                got = np.array([rel.x(), rel.y(), rel.theta()])
                err = np.abs(pose2.between(got, c.relative)) / self.closure_sigmas
                if err.max() > worst_err:
                    worst, worst_err = c, float(err.max())
            if worst is None:
                return self._estimate
            worst.kept = False

    def _solve(self) -> gtsam.Values:
        graph = gtsam.NonlinearFactorGraph()
        for f in self._chain():
            graph.add(f)
        for c in self.closures:
            if c.kept:
                graph.add(self._closure_factor(c))
        values = gtsam.Values()
        for k, p in enumerate(self._estimate):
            values.insert(k, _pose(p))
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(100)
        result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
        self._read(result)
        return result
