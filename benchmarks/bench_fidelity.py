"""The fidelity step's cost in bag2world, and the casting alone (by hand, not a test).

    python benchmarks/bench_fidelity.py [--quick]

1. bag2world with the replay (the default) beside ``--no-fidelity``, each run in a fresh
   process (the CLI, as a user runs it; ru_maxrss of the child), on the bundled scan bags
   and on a 2 M-beam recording: the synthetic hall of bench_bag2world.py, 100 clouds of 20,000
   points on /points (MCAP), inserted as end points at 0.1 m. Target (issue 26): the replay
   adds at most 25% to the wall time and at most 20% to the peak memory.
2. The casting alone (``replay.cast.simulated_ranges``: Embree through embreex, building
   the scene and casting) of those 2 M beams into the world bag2world wrote, read back with
   readers/world.py, on both cores. Target: above 5 M beams a second on 2 cores.

Times are wall clock, the best of the repetitions (3; --quick: 1). The machine may be shared:
the load average is printed.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the repository: tests.fixtures

from tests.fixtures import CCNY_DIR, EMBARK_ROS1_DIR, FUSE_DIR, LEG_TRACKER_DIR, ROOT, SICK_ROS1_DIR

sys.path.insert(0, str(ROOT / "benchmarks"))
#: The bundled bags with scans, and the options that pose them.
BAGS = {
    "tb3 (LaserScan, odometry)": (FUSE_DIR, []),
    "ccny (LaserScan, fixed)": (
        CCNY_DIR,
        ["--pose", "0", "0", "0.3", "0", "0", "0"],
    ),
    "sick lms1xx (LaserScan, fixed)": (
        SICK_ROS1_DIR,
        ["--topic", "/sick_lms_1xx/scan", "--pose", "0", "0", "0.3", "0", "0", "0"],
    ),
    "leg tracker (LaserScan, fixed)": (
        LEG_TRACKER_DIR,
        ["--pose", "0", "0", "0.3", "0", "0", "0"],
    ),
    "embark luminar (PointCloud2, fixed)": (
        EMBARK_ROS1_DIR,
        ["--topic", "/luminar_pointcloud", "--pose", "0", "0", "1.8", "0", "0", "0",
         "--insert", "endpoints", "--resolution", "0.2"],
    ),
}  # fmt: skip

LAUNCH = """
import resource, sys, time
from scan2terrain.cli import main
t = time.perf_counter()
code = main(sys.argv[1:])
took = time.perf_counter() - t
print(f"@@ {code} {took:.6f} {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss}", file=sys.stderr)
"""


def run_cli(args: list[str]) -> tuple[float, int]:
    """One bag2world in a fresh process: (seconds inside main, peak RSS in MB)."""
    done = subprocess.run(
        [sys.executable, "-c", LAUNCH, *args], capture_output=True, text=True, check=False
    )
    line = [x for x in done.stderr.splitlines() if x.startswith("@@ ")]
    if done.returncode != 0 or not line:
        raise SystemExit(f"failed: {' '.join(args)}\n{done.stderr}")
    _, code, took, rss = line[-1].split()
    assert code == "0", done.stderr
    return float(took), int(rss) // 1024


def compare(name: str, bag: Path, options: list[str], out: Path, repeats: int) -> None:
    rows = {}
    for label, extra in (("with replay", []), ("--no-fidelity", ["--no-fidelity"])):
        best, peak = float("inf"), 0
        for _ in range(repeats):
            took, rss = run_cli(
                ["bag2world", str(bag), "-o", str(out), "--overwrite", "-q", *options, *extra]
            )
            best, peak = min(best, took), max(peak, rss)
        rows[label] = (best, peak)
    (a, ma), (b, mb) = rows["with replay"], rows["--no-fidelity"]
    print(
        f"| {name} | {b:.2f} s | {a:.2f} s | {100 * (a / b - 1):+.0f}% | {mb} MB | {ma} MB "
        f"| {100 * (ma / mb - 1):+.0f}% |"
    )


def hall_bag(tmp: Path) -> Path:
    import bench_bag2world as hall

    lap = hall.lidar_lap(100)
    bag = tmp / "hall_2m"
    hall.write_bag(bag, "mcap", lap, 1)
    return bag


def casting(world: Path, bag: Path) -> None:
    from scan2terrain.cli.dispatch import COMMAND_DEFAULTS
    from scan2terrain.commands.replay import record
    from scan2terrain.config import load_config
    from scan2terrain.readers.world import read_world
    from scan2terrain.replay.cast import simulated_ranges

    cfg = load_config(None, {}, defaults=COMMAND_DEFAULTS.get("bag2world"))
    beams = record([bag], cfg).recorder.beams()
    geometry = read_world(world / "world_gz.sdf")
    best = float("inf")
    for _ in range(3):
        t = time.perf_counter()
        simulated_ranges(geometry.vertices, geometry.triangles, beams)
        best = min(best, time.perf_counter() - t)
    print(
        f"| {len(beams.scan):,} beams, {len(geometry.triangles):,} triangles | {best:.3f} s | "
        f"{len(beams.scan) / best / 1e6:.1f} M beams/s |"
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="one repetition")
    args = p.parse_args()
    repeats = 1 if args.quick else 3
    print(f"load average at start: {os.getloadavg()}")
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        hall = hall_bag(tmp)
        hall_options = ["--insert", "endpoints", "--resolution", "0.1"]
        print("\n| recording | --no-fidelity | replay | time | memory, none | replay | memory |")
        print("|---|---|---|---|---|---|---|")
        for name, (bag, options) in BAGS.items():
            compare(name, bag, options, tmp / "out", repeats)
        compare("hall, 2 M beams (PointCloud2, tf)", hall, hall_options, tmp / "out", repeats)
        run_cli(["bag2world", str(hall), "-o", str(tmp / "hall_world"), "-q", "--no-fidelity",
                 "--simulator", "gz", *hall_options])  # fmt: skip
        print("\n| casting (scene built + cast, 2 cores) | best | rate |")
        print("|---|---|---|")
        casting(tmp / "hall_world", hall)
    print(f"\nload average at end: {os.getloadavg()}")


if __name__ == "__main__":
    main()
