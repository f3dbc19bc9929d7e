"""Load time and real-time factor of our worlds in gz-sim's physics (by hand, not a test).

    python benchmarks/bench_physics.py [--quick] [--repeat N] [--keep DIR] [--only voxels]

Worlds: an empty ground plane (the reference), and the four fixture maps (Willow Garage,
warehouse, Levine, TurtleBot3 world; fixtures/maps/) written by the
scan2terrain CLI (``map2world MAP -o OUT --simulator gz --geometry G``) for each geometry G:
heightmap, mesh, boxes, polylines, into a temporary folder (or --keep DIR).

Each world runs in tests/gazebo/physics_probe.cpp (tests/physics_harness.py), which builds it
in ign-physics 5's dartsim plugin the way ign-gazebo 6's Physics system does, with the
world's collision detector (bullet in every world here), twice: the Husky-sized robot alone,
and the robot plus two free 0.5 x 0.5 x 0.1 m boxes (2 kg) resting on the floor. The robot
stands at the world's spawn pose (spawn.yaml, else the open floor nearest the map origin)
and turns in place (wheel rims at +-0.3 m/s after 0.2 s); the boxes rest on open floor
1.5-4 m from it, off the heightmap's vertex grid (a box whose edges lie on grid lines sinks
through a bullet height field, see the physics findings, and a falling box costs nothing).

Reported per run (the median of --repeat runs, each a fresh process):

* load = SDF parse + building the world in physics + the first step (wall seconds), as a
  user waits for it before the world runs; the plugin's own load (a constant ~20-60 ms) is
  not in it;
* RTF = simulated time / wall time of the step loop after the first step (unthrottled,
  1 ms steps, contacts read only until every body has touched);

each also as a ratio to the empty plane's (same scenario). --quick: 1,000 steps, 1 run;
otherwise 5,000 steps, 3 runs. The machine may be shared: the load average is printed.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from PIL import Image
from scipy import ndimage

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the repository: tests

from tests.fixtures import FR079, GEB079, LEVINE, TB3_MAP, WAREHOUSE, WILLOW
from tests.physics_harness import (
    Body,
    Box,
    Robot,
    Scenario,
    SimResult,
    physics_binary,
    simulate,
)

MAPS = {
    "willow": WILLOW,
    "warehouse": WAREHOUSE,
    "levine": LEVINE,
    "tb3": TB3_MAP,
}
GEOMETRIES = ("heightmap", "mesh", "boxes", "polylines")
#: Voxel worlds (--geometry voxels, issue 15): OctoMap's building and corridor scans.
VOXEL_WORLDS = {
    "geb079 voxels": ["octree2world", str(GEB079)],
    "fr079 voxels": ["octree2world", str(FR079),
                     "--resolution", "0.1"],
}  # fmt: skip
PLANE_WORLD = """<?xml version="1.0"?>
<sdf version="1.9">
  <world name="plane">
    <physics name="dart_bullet" type="dart">
      <max_step_size>0.001</max_step_size>
      <real_time_factor>1</real_time_factor>
      <dart><collision_detector>bullet</collision_detector></dart>
    </physics>
    <model name="ground">
      <static>true</static>
      <link name="link">
        <collision name="plane">
          <geometry><plane><normal>0 0 1</normal><size>100 100</size></plane></geometry>
        </collision>
      </link>
    </model>
  </world>
</sdf>
"""


@dataclass
class World:
    label: str
    sdf: Path
    model_dirs: list[Path]
    robot: tuple[float, float, float]  # x, y, yaw
    boxes: list[tuple[float, float]]
    z: float = 0.0  # the floor under the robot and the boxes


def _cli() -> list[str]:
    script = Path(sys.executable).parent / "scan2terrain"
    if script.is_file():
        return [str(script)]
    return [sys.executable, "-c", "import sys; from scan2terrain.cli import main; sys.exit(main())"]


def _open_spots(
    out: Path, near: tuple[float, float], clearance: float
) -> list[tuple[float, float]]:
    """Cell centres at least ``clearance`` m from any wall cell, nearest ``near`` first."""
    meta = yaml.safe_load((out / "map" / "map_gz.yaml").read_text())
    grid = np.flipud(np.asarray(Image.open(out / "map" / meta["image"])))
    res = float(meta["resolution"])
    ox, oy = float(meta["origin"][0]), float(meta["origin"][1])
    dist = ndimage.distance_transform_edt(grid != 0) * res
    rows, cols = np.nonzero(dist >= clearance)
    xs = ox + (cols + 0.5) * res
    ys = oy + (rows + 0.5) * res
    order = np.argsort(np.hypot(xs - near[0], ys - near[1]))
    return [(float(xs[i]), float(ys[i])) for i in order]


def _place(out: Path) -> tuple[tuple[float, float, float], list[tuple[float, float]]]:
    spawn_file = out / "spawn.yaml"
    if spawn_file.is_file():
        pose = yaml.safe_load(spawn_file.read_text())["gz"]["pose"]
        robot = (float(pose[0]), float(pose[1]), float(pose[5]))
    else:
        x, y = _open_spots(out, (0.0, 0.0), 1.0)[0]
        robot = (x, y, 0.0)
    boxes: list[tuple[float, float]] = []
    for x, y in _open_spots(out, robot[:2], 0.6):
        d = math.hypot(x - robot[0], y - robot[1])
        if 1.5 <= d <= 4.0 and all(math.hypot(x - bx, y - by) > 1.0 for bx, by in boxes):
            boxes.append((x + 0.013, y + 0.007))  # off the vertex grid (cell centres)
            if len(boxes) == 2:
                break
    if len(boxes) < 2:
        raise RuntimeError(f"{out}: no open floor for two boxes near the robot")
    return robot, boxes


def build_worlds(root: Path, only: str | None = None) -> list[World]:
    """The empty plane and every world whose label contains ``only`` (None: all)."""
    plane = root / "plane.sdf"
    plane.write_text(PLANE_WORLD)
    worlds = [World("empty plane", plane, [], (0.0, 0.0, 0.0), [(2.0, 0.3), (-1.7, 1.1)])]
    for name, map_yaml in MAPS.items():
        for geometry in GEOMETRIES:
            if only is not None and only not in f"{name} {geometry}":
                continue
            out = root / f"{name}_{geometry}"
            if not (out / "world_gz.sdf").is_file():
                cmd = [*_cli(), "map2world", str(map_yaml), "-o", str(out), "--overwrite",
                       "--simulator", "gz", "--geometry", geometry, "-q"]  # fmt: skip
                t0 = time.perf_counter()
                subprocess.run(cmd, check=True)
                print(f"  wrote {out.name} in {time.perf_counter() - t0:.1f} s", flush=True)
            robot, boxes = _place(out)
            worlds.append(
                World(f"{name} {geometry}", out / "world_gz.sdf", [out / "models"], robot, boxes)
            )
    for label, args in VOXEL_WORLDS.items():
        if only is not None and only not in label:
            continue
        out = root / label.replace(" ", "_")
        if not (out / "world_gz.sdf").is_file():
            cmd = [*_cli(), *args, "-o", str(out), "--overwrite", "--simulator", "gz",
                   "--geometry", "voxels", "-q"]  # fmt: skip
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True)
            print(f"  wrote {out.name} in {time.perf_counter() - t0:.1f} s", flush=True)
        robot, boxes = _place(out)
        z = float(yaml.safe_load((out / "spawn.yaml").read_text())["gz"]["pose"][2])
        worlds.append(World(label, out / "world_gz.sdf", [out / "models"], robot, boxes, z))
    return worlds


def scenario(world: World, with_boxes: bool, steps: int) -> Scenario:
    x, y, yaw = world.robot
    z = world.z
    bodies: list[Body] = [Robot("robot", x, y, z, yaw, 0.3, -0.3, 0.2)]
    if with_boxes:
        for i, (bx, by) in enumerate(world.boxes):
            pose = (bx, by, z + 0.0505, 0.0, 0.0, 0.0)
            bodies.append(Box(f"box{i}", (0.5, 0.5, 0.1), 2.0, pose))
    return Scenario(bodies=bodies, steps=steps, dt=0.001)


@dataclass
class Row:
    label: str
    bodies: str
    shapes: str
    parse: float
    build: float
    first: float
    load: float
    rtf: float
    note: str


def measure(world: World, with_boxes: bool, steps: int, repeat: int, tmp: Path) -> Row:
    runs: list[SimResult] = []
    for _ in range(repeat):
        result = simulate(world.sdf, world.model_dirs, scenario(world, with_boxes, steps), tmp)
        if result.crashed:
            bodies = "robot + 2 boxes" if with_boxes else "robot"
            nan = math.nan
            return Row(world.label, bodies, "-", nan, nan, nan, nan, nan, result.crash_summary())
        runs.append(result)
    last = runs[-1]
    assert all(r.times is not None for r in runs)
    times = [r.times for r in runs if r.times is not None]
    notes = []
    if last.shapes_failed:
        notes.append(f"{last.shapes_failed} shapes failed")
    for b in last.bodies.values():
        if b.min_z < world.z - 0.05:
            notes.append(f"{b.name} fell (min z {b.min_z:.2f})")
    return Row(
        label=world.label,
        bodies="robot + 2 boxes" if with_boxes else "robot",
        shapes=f"{last.shapes_built}",
        parse=statistics.median(t.sdf_parse_s for t in times),
        build=statistics.median(t.build_s for t in times),
        first=statistics.median(t.first_step_s for t in times),
        load=statistics.median(t.load_s for t in times),
        rtf=statistics.median(r.rtf for r in runs),
        note="; ".join(notes),
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="1,000 steps, one run each")
    parser.add_argument("--repeat", type=int, default=None, help="runs per case (default 3)")
    parser.add_argument("--keep", type=Path, default=None, help="write (and reuse) worlds here")
    parser.add_argument(
        "--only", default=None, help="only the worlds whose label holds this (e.g. voxels)"
    )
    args = parser.parse_args()
    steps = 1000 if args.quick else 5000
    repeat = args.repeat or (1 if args.quick else 3)

    print(f"load average {os.getloadavg()}, {os.cpu_count()} cpus; {steps} steps, {repeat} run(s)")
    t0 = time.perf_counter()
    physics_binary()
    print(f"physics_probe ready in {time.perf_counter() - t0:.1f} s", flush=True)
    with tempfile.TemporaryDirectory(prefix="bench_physics_") as tmpdir:
        root = args.keep if args.keep is not None else Path(tmpdir)
        root.mkdir(parents=True, exist_ok=True)
        worlds = build_worlds(root, args.only)
        rows: list[Row] = []
        for world in worlds:
            for with_boxes in (False, True):
                row = measure(world, with_boxes, steps, repeat, Path(tmpdir) / "runs")
                rows.append(row)
                print(f"  {row.label} / {row.bodies}: load {row.load:.3f} s, RTF {row.rtf:.2f}",
                      flush=True)  # fmt: skip

    ref = {r.bodies: r for r in rows if r.label == "empty plane"}
    head = (
        f"{'world':<22} {'bodies':<16} {'shapes':>6} {'parse s':>8} {'build s':>8} "
        f"{'step1 s':>8} {'load s':>8} {'load x':>7} {'RTF':>7} {'RTF x':>7}  note"
    )
    print()
    print(head)
    print("-" * len(head))
    for r in rows:
        base = ref[r.bodies]
        print(
            f"{r.label:<22} {r.bodies:<16} {r.shapes:>6} {r.parse:>8.3f} {r.build:>8.3f} "
            f"{r.first:>8.3f} {r.load:>8.3f} {r.load / base.load:>7.1f} {r.rtf:>7.2f} "
            f"{r.rtf / base.rtf:>7.3f}  {r.note}"
        )
    print(f"\nload average {os.getloadavg()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
