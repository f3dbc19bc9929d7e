"""3D clean-up: small voxel components and statistical outliers (run by hand, not a test).

    python benchmarks/bench_voxel_cleanup.py [--voxels 10000000] [--points 1000000]

The inputs are made here and saved; each case loads its input in a fresh process, so that
the peak RSS it prints (resource.getrusage) is the call's (with the interpreter, the libraries
and the input: the RSS just before the call is printed beside it). Targets (issue 15):
remove_small_components on 10 M voxels in a few seconds and < 2 GB.
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from numpy.typing import NDArray


def rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def noisy_surfaces(n: int, seed: int = 0) -> NDArray[np.int64]:
    """About ``n`` voxels: a rough two-voxel-thick terrain, two walls and 1% specks (singles
    and pairs scattered above the terrain), shuffled."""
    rng = np.random.default_rng(seed)
    side = int(np.sqrt(0.96 * n / 2.2))
    x, y = np.meshgrid(np.arange(side), np.arange(side), indexing="ij")
    z = 8 * np.sin(x / 40) + 8 * np.cos(y / 55) + rng.normal(0, 0.7, x.shape)
    ground = np.stack([x, y, np.round(z)], -1).reshape(-1, 3).astype(np.int64)
    parts = [ground, ground - [0, 0, 1]]
    for wall in range(2):
        u, h = np.meshgrid(np.arange(side), np.arange(20, 20 + side // 10), indexing="ij")
        at = side // 3 * (wall + 1) + rng.integers(-1, 2, u.shape)
        xyz = (at, u, h) if wall else (u, at, h)
        parts.append(np.stack(xyz, -1).reshape(-1, 3))
    specks = rng.integers([0, 0, 40], [side, side, 400], (n // 100, 3))
    parts += [specks, specks + rng.integers(0, 2, specks.shape)]
    keys = np.concatenate(parts).astype(np.int64)
    code = (keys[:, 0] * side + keys[:, 1]) * 512 + keys[:, 2] + 64  # z in -64..447
    _, first = np.unique(code, return_index=True)
    return keys[rng.permutation(first)]


def plane_and_noise(n: int, seed: int = 0) -> NDArray[np.float64]:
    """``n`` points on a 50 m x 50 m plane (1 cm of noise) and 1% scattered in 10 m above/below."""
    rng = np.random.default_rng(seed)
    plane = np.column_stack([rng.uniform(0, 50, (n, 2)), rng.normal(0, 0.01, n)])
    return np.concatenate([plane, rng.uniform([0, 0, -5], [50, 50, 5], (n // 100, 3))])


def run(case: str, path: Path) -> None:
    from scipy.sparse.csgraph import connected_components  # noqa: F401 (imports not timed)

    from scan2terrain.filters.outliers import statistical_outliers
    from scan2terrain.filters.voxels3d import remove_small_components

    data = np.load(path)
    before = rss_mib()
    for option in (26, 6) if case == "voxels" else (20,):
        t0 = time.perf_counter()
        if case == "voxels":
            keep = remove_small_components(data, 10, connectivity=option)
            what = f"remove_small_components, {option:>2}-connected, min 10"
        else:
            keep = statistical_outliers(data, neighbours=option)
            what = f"statistical_outliers, {option} neighbours, 2 std"
        dt = time.perf_counter() - t0
        print(
            f"  {what:46s} {len(data):>11,} {case}: {dt:6.2f} s, dropped"
            f" {len(data) - int(keep.sum()):>9,}; RSS {before:5.0f} MiB before, peak"
            f" {rss_mib():5.0f} MiB"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--voxels", type=int, default=10_000_000)
    parser.add_argument("--points", type=int, default=1_000_000)
    parser.add_argument("--make", nargs=2, help=argparse.SUPPRESS)
    parser.add_argument("--run", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.make:
        case, path = args.make
        make = noisy_surfaces(args.voxels) if case == "voxels" else plane_and_noise(args.points)
        np.save(path, make)
    elif args.run:
        run(args.run[0], Path(args.run[1]))
    else:
        # Inputs are made in a process of their own too: a child's ru_maxrss starts at its
        # parent's RSS when it was forked.
        with tempfile.TemporaryDirectory() as tmp:
            for case in ("voxels", "points"):
                path = str(Path(tmp) / f"{case}.npy")
                for step in ("--make", "--run"):
                    cmd = [sys.executable, __file__, *sys.argv[1:], step, case, path]
                    subprocess.run(cmd, check=True)


if __name__ == "__main__":
    main()
