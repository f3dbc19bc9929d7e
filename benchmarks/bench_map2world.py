"""map2world end to end and ``--help``, process start to exit (run by hand, not a test).

    python benchmarks/bench_map2world.py [--runs 7]

Targets (issue 2): map2world on the Willow Garage map <= 1.0 s; ``scan2terrain --help`` <= 0.3 s.
Runs the console script of the current environment (e.g. .venv/bin/scan2terrain) in a fresh
process each time and reports the best and median wall-clock time.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the repository: tests.fixtures

from tests.fixtures import WILLOW


def timed(cmd: list[str], runs: int) -> list[float]:
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
        times.append(time.perf_counter() - t0)
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--runs", type=int, default=7)
    args = parser.parse_args()
    exe = Path(sys.executable).parent / "scan2terrain"
    if not exe.exists():
        sys.exit(f"{exe} not found: install the package into this environment first")
    tmp = Path(tempfile.mkdtemp())
    try:
        rows = [
            ("scan2terrain --help", timed([str(exe), "--help"], args.runs), 0.3),
            (
                "map2world willow (1165x945)",
                timed(
                    [str(exe), "map2world", str(WILLOW), "-o", str(tmp / "w"), "--overwrite"],
                    args.runs,
                ),
                1.0,
            ),
        ]
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"{'command':32s} {'best [s]':>9s} {'median [s]':>11s} {'target [s]':>11s}")
    for name, times, target in rows:
        print(f"{name:32s} {min(times):9.3f} {statistics.median(times):11.3f} {target:11.2f}")


if __name__ == "__main__":
    main()
