"""cloud2world --grid height, timed end to end (by hand, not a test).

    python benchmarks/bench_heights.py [--points 1e7] [--runs 5] [--cache DIR] [--src DIR]

Times the whole command, each run in a fresh process (imports and numba's cached kernels
included), best of ``--runs``, for:

1. ``autzen-2m``: the README's example, ``fixtures/clouds/pc_laz_autzen_trim/autzen_trim.laz
   --las-classes 2 --grid height --resolution 2``;
2. ``autzen-auto``: the same LAZ, every class, at the automatic resolution;
3. ``hills-auto`` / ``hills-0.5m``: ``--points`` points of smooth hills with noise (30 m of
   relief, 2 x 2 km, one LAS 1.2 file, cached in ``--cache``), at the automatic resolution and
   at 0.5 m (a finer grid: the column statistics' share grows).

Each line shows the best and median wall time, the best CPU time (user + sys of the process
and its threads: steadier than wall time on a shared machine), the grid's height levels
(distinct heights in the gz-sim heightmap PNG) and the resolution used. ``--src DIR`` (may be
repeated) runs every case with each ``DIR`` first on ``PYTHONPATH`` instead of the installed
code, e.g. unpacked ``git archive`` trees of two commits: each run of a case takes every
variant in turn, so a busy machine slows them alike.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the repository: tests.fixtures

from tests.fixtures import AUTZEN

SIDE_M = 2000.0


def hills(folder: Path, points: int) -> Path:
    """One LAS file of ``points`` ground points on smooth hills (cached)."""
    import laspy  # type: ignore[import-untyped]

    path = folder / f"hills_{points}.las"
    if path.exists():
        return path
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(7)
    xy = rng.uniform(0, SIDE_M, (points, 2))
    z = (
        15 * np.sin(xy[:, 0] / 170) * np.cos(xy[:, 1] / 230)
        + 0.004 * xy[:, 0]
        + rng.normal(0, 0.03, points)
    )
    header = laspy.LasHeader(point_format=0, version="1.2")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([500_000.0, 4_100_000.0, 0.0])
    las = laspy.LasData(header)
    las.x, las.y, las.z = xy[:, 0] + 500_000.0, xy[:, 1] + 4_100_000.0, z + 100.0
    las.classification = np.full(points, 2, dtype=np.uint8)
    tmp = path.with_suffix(".part")
    las.write(tmp)
    tmp.rename(path)
    return path


def levels(out: Path) -> int:
    from PIL import Image

    pngs = [
        p
        for p in out.glob("models/*/materials/textures/heightmap.png")
        if not p.parent.parent.parent.name.endswith("_classic")
    ]
    return len(np.unique(np.asarray(Image.open(pngs[0])))) if pngs else 0


def resolution(out: Path) -> str:
    import yaml

    cfg = yaml.safe_load((out / "scan2terrain.yaml").read_text())
    return str(cfg["octree"]["resolution"])


def run_once(args: list[str], out: Path, env: dict[str, str]) -> tuple[float, float]:
    """(wall, CPU) seconds of one run in a fresh process."""
    cmd = [sys.executable, "-m", "scan2terrain.cli", "cloud2world", *args, "-o", str(out)]
    cmd += ["--grid", "height", "--no-preview", "--overwrite", "-q"]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{proc.stderr[-3000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=float, default=1e7)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "s2t_bench")
    ap.add_argument(
        "--src", type=Path, action="append", default=[], help="source folder to run too"
    )
    ap.add_argument("--only", help="run only the cases whose name holds this")
    opts = ap.parse_args()
    variants = {} if opts.src else {"installed": dict(os.environ)}
    for src in opts.src:
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([str(src), env.get("PYTHONPATH", "")])
        variants[str(src)] = env
    big = hills(opts.cache, int(opts.points))
    cases = {
        "autzen-2m": [str(AUTZEN), "--las-classes", "2", "--resolution", "2", "--no-filter"],
        "autzen-auto": [str(AUTZEN), "--no-filter"],
        "hills-auto": [str(big), "--no-filter"],
        "hills-0.5m": [str(big), "--resolution", "0.5", "--no-filter"],
    }
    if opts.only:
        cases = {k: v for k, v in cases.items() if opts.only in k}
    runs = [(c, v) for c in cases for v in variants]
    times: dict[tuple[str, str], list[tuple[float, float]]] = {r: [] for r in runs}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)

        def folder(case: str, variant: str) -> Path:
            return work / f"{case}_{list(variants).index(variant)}"

        for case, variant in runs:  # warm: numba's cache, the page cache
            run_once(cases[case], folder(case, variant), variants[variant])
        for _ in range(opts.runs):
            for case, variant in runs:
                times[case, variant].append(
                    run_once(cases[case], folder(case, variant), variants[variant])
                )
        print(
            f"{'case':<12} {'best s':>7} {'median s':>9} {'CPU s':>6} {'levels':>7}"
            f" {'res':>5}  code"
        )
        for case, variant in runs:
            walls = [w for w, _ in times[case, variant]]
            cpu = min(c for _, c in times[case, variant])
            out = folder(case, variant)
            print(
                f"{case:<12} {min(walls):7.2f} {statistics.median(walls):9.2f} {cpu:6.2f}"
                f" {levels(out):7d} {resolution(out):>5}  {variant}"
            )


if __name__ == "__main__":
    main()
