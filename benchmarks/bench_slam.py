"""Pose correction (``--correct``) by hand, not a test.

    python benchmarks/bench_slam.py [--quick]

1. The correction alone (``slam.planar.correct``) on the MIT CSAIL CARMEN log (1,988 scans,
   424 s of recording, raw odometry) and on synthetic recordings with known truth
   (tests/slamworld.py: the corridor loop, the rooms and the look-alike corridors at their
   default size, and the corridor loop at full size, 30 x 20 m, 2,167 scans): wall time against
   the recording's duration, time per scan of local matching, the loop search and the graph,
   closures kept, and the trajectory error against the truth where it is known (after the best
   rigid alignment), and Kuemmerle et al.'s relations metric with relations taken from the
   truth (every 5th scan against every scan within 5 m of it, before and after each loop:
   the mean absolute translational error of the relative poses, +- its standard deviation).
   Targets (issue 27): correction at least 30x faster than the recording; the metric at or
   below Cartographer's 0.0375 m (on real logs with hand-made relations, which we do not have).
2. bag2world with the default ``--correct auto`` beside ``--correct off``, each in a fresh
   process (the CLI as a user runs it), on the mit-csail log, the bundled TurtleBot3 bag and
   the synthetic corridor loop: wall time and the replay's share of beams within 10 cm.
   Targets: the whole run at most 3x the uncorrected one; the replay at 85% within 10 cm.

Times are wall clock, the best of the repetitions (2; --quick: 1). The machine may be shared:
the load average is printed.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the repository: tests.fixtures

from tests import slamworld as sw
from tests.fixtures import FUSE_DIR, MIT
from tests.slamworld import aligned_errors, flat_scans

from scan2terrain.slam import planar, pose2


def _mit() -> tuple[np.ndarray, list[np.ndarray], float]:
    from tests.carmen import read_carmen

    log = read_carmen(MIT)
    a = log.angle_min + log.angle_increment * np.arange(log.ranges.shape[1])
    scans = []
    for r in log.ranges.astype(np.float64):
        ok = (r > 0.05) & (r < 80.0)
        scans.append(np.c_[r[ok] * np.cos(a[ok]), r[ok] * np.sin(a[ok])])
    span = (log.stamps_ns[-1] - log.stamps_ns[0]) / 1e9
    return log.laser_poses, scans, span


def relations_error(est: np.ndarray, truth: np.ndarray, reach: float = 5.0) -> tuple[float, float]:
    """Kuemmerle et al. (2009): the mean (and standard deviation) of the translational error
    of relative poses, est_i^-1 est_j against truth_i^-1 truth_j, over the relations: every 5th
    scan with every scan within ``reach`` metres of it in the truth (neighbours in time and
    revisits)."""
    errors = []
    for i in range(0, len(truth), 5):
        near = np.flatnonzero(np.hypot(*(truth[:, :2] - truth[i, :2]).T) <= reach)
        near = near[near != i]
        true = pose2.between(truth[i], truth[near])
        got = pose2.between(est[i], est[near])
        errors.append(np.hypot(*(pose2.between(true, got)[:, :2]).T))
    e = np.concatenate(errors)
    return float(e.mean()), float(e.std())


def correction_alone(repeat: int) -> None:
    print("1. the correction alone (slam.planar.correct)")
    #: label -> (prior poses, scans, duration in seconds, the simulated recording or None)
    cases: dict[str, tuple[np.ndarray, list[np.ndarray], float, sw.Recording | None]] = {
        "mit-csail (CARMEN, 1988 scans)": (*_mit(), None)
    }
    for name, scale in (
        ("corridor_loop", None),
        ("rooms", None),
        ("parallel_corridors", None),
        ("corridor_loop", 1.0),
    ):
        sim = sw.simulate(name, scale=scale)
        label = f"{name}{'' if scale is None else f' x{scale:g}'} ({len(sim.stamps_ns)} scans)"
        cases[label] = (sim.odom_laser_poses, flat_scans(sim), sim.duration, sim)
    head = (
        f"   {'recording':<38} {'duration':>9} {'wall':>7} {'speed':>7} {'local/scan':>11} "
        f"{'loops':>7} {'graph':>6} {'refine':>7} {'closures':>9}  error vs truth"
    )
    print(head)
    for label, (prior, scans, span, rec) in cases.items():
        best, result = float("inf"), None
        for _ in range(repeat):
            t = time.perf_counter()
            result = planar.correct(prior, scans)
            best = min(best, time.perf_counter() - t)
        assert result is not None
        sec = result.seconds
        truth = ""
        if rec is not None:
            err, yaw = aligned_errors(result.poses, rec.laser_poses)
            raw, _ = aligned_errors(prior, rec.laser_poses)
            rel, rel_sd = relations_error(result.poses, rec.laser_poses)
            odo, odo_sd = relations_error(prior, rec.laser_poses)
            truth = (
                f"relations {rel:.4f} +- {rel_sd:.4f} m (odometry {odo:.3f} +- {odo_sd:.3f}); "
                f"mean {100 * err.mean():.1f} cm, p95 {100 * np.percentile(err, 95):.1f} cm, "
                f"max {100 * err.max():.1f} cm, yaw max {yaw.max():.2f} deg "
                f"(odometry max {raw.max():.2f} m)"
            )
        print(
            f"   {label:<38} {span:>8.1f}s {best:>6.2f}s {span / best:>6.0f}x "
            f"{1000 * sec['local'] / len(scans):>9.2f}ms {sec['loops']:>6.2f}s "
            f"{sec['graph']:>5.2f}s {sec['refine']:>6.2f}s "
            f"{result.accepted:>3}/{result.candidates:<5}  {truth}"
        )


def _run(args: list[str]) -> tuple[float, str]:
    with tempfile.TemporaryDirectory() as tmp:
        t = time.perf_counter()
        done = subprocess.run(
            [sys.executable, "-m", "scan2terrain", *args, "-o", str(Path(tmp) / "out")],
            capture_output=True, text=True, check=False,
        )  # fmt: skip
        took = time.perf_counter() - t
    if done.returncode:
        raise SystemExit(done.stderr)
    return took, done.stdout + done.stderr


def _within(report: str) -> str:
    m = re.search(r"fidelity \(world_gz.sdf\): [\d,]+ recorded beams replayed: ([\d.]+)%", report)
    return f"{m.group(1)}%" if m else "?"


def whole_runs(repeat: int) -> None:
    print("2. bag2world, --correct auto beside --correct off (fresh processes)")
    with tempfile.TemporaryDirectory() as tmp:
        rec = sw.simulate("corridor_loop")
        loop = rec.write_bag(Path(tmp) / "loop.bag")
        inputs = {
            "mit-csail (CARMEN log)": MIT,
            "tb3 (bundled bag)": FUSE_DIR,
            "corridor_loop": loop,
        }
        print(f"   {'recording':<26} {'off':>8} {'auto':>8} {'ratio':>6}  within 10 cm off -> auto")
        for label, path in inputs.items():
            times, reports = {}, {}
            for mode in ("off", "auto"):
                runs = [_run(["bag2world", str(path), "--correct", mode]) for _ in range(repeat)]
                times[mode] = min(t for t, _ in runs)
                reports[mode] = runs[0][1]
            print(
                f"   {label:<26} {times['off']:>7.1f}s {times['auto']:>7.1f}s "
                f"{times['auto'] / times['off']:>5.1f}x  {_within(reports['off'])} -> "
                f"{_within(reports['auto'])}"
            )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="one repetition")
    args = p.parse_args()
    repeat = 1 if args.quick else 2
    print(f"load average {os.getloadavg()[0]:.2f}, {os.cpu_count()} cores")
    correction_alone(repeat)
    whole_runs(repeat)


if __name__ == "__main__":
    main()
