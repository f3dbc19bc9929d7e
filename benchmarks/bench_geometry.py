"""Worlds of walls (--geometry mesh | boxes | polylines) on the Willow Garage map (run by hand).

    python benchmarks/bench_geometry.py [--runs 5]

Targets (issue 5): map2world --geometry mesh, boxes and polylines on the Willow Garage map,
process start to exit, each <= 1.0 s (the heightmap row is for comparison). Then the steps, in
process, on the filtered grid: the box partition, the outlines, the mesh and its files, and each
SDF model (both simulators write one). Best and median wall-clock times.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the repository: tests.fixtures

from tests.fixtures import WILLOW


def timed(run: Callable[[], object], runs: int) -> list[float]:
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        run()
        times.append(time.perf_counter() - t0)
    return times


def end_to_end(exe: Path, out: Path, runs: int) -> list[tuple[str, list[float], float | None]]:
    rows: list[tuple[str, list[float], float | None]] = []
    for geometry in ("heightmap", "mesh", "boxes", "polylines"):
        cmd = [str(exe), "map2world", str(WILLOW), "-o", str(out), "--overwrite"]
        cmd += ["--geometry", geometry]

        def run(cmd: list[str] = cmd) -> None:
            subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)

        rows.append((f"map2world --geometry {geometry}", timed(run, runs), 1.0))
    return rows


def steps(runs: int) -> list[tuple[str, list[float], float | None]]:
    from scan2terrain import steps
    from scan2terrain.config import Config
    from scan2terrain.exporters import meshfile, sdf
    from scan2terrain.geometry import mesh, outlines
    from scan2terrain.geometry.boxes import merge_boxes
    from scan2terrain.readers import read_map_yaml
    from scan2terrain.world import walls as world

    meta, grid = read_map_yaml(WILLOW)
    trinary = steps.classify(grid, meta.mode, meta.occupied_thresh, meta.free_thresh)
    walls = steps.filter_occupancy(trinary, Config()) == 100
    r, origin = grid.resolution, grid.origin
    ground = sdf.Ground((0.0, 0.0), (1.0, 1.0))
    p = sdf.walls_placement("gz", "bench", "boxes", ground, 2.0)
    cells = merge_boxes(walls)
    poses = world._box_poses(cells, r, origin)
    polygons = outlines.trace(walls, r, origin)
    rings = [poly.rings() for poly in polygons]
    m = mesh.extrude(polygons, 2.0)
    print(
        f"Willow Garage, filtered: {int(walls.sum())} wall cells -> {len(cells)} boxes, "
        f"{len(polygons)} polygons ({sum(len(x) for x in rings)} rings, "
        f"{sum(len(ring) for x in rings for ring in x)} vertices), {len(m.faces)} triangles"
    )
    rows: list[tuple[str, list[float], float | None]] = [
        ("merge_boxes", timed(lambda: merge_boxes(walls), runs), None),
        (
            "boxes_model_sdf",
            timed(lambda: sdf.boxes_model_sdf(p, ground, poses, comment=""), runs),
            None,
        ),
        ("outlines.trace", timed(lambda: outlines.trace(walls, r, origin), runs), None),
        (
            "polylines_model_sdf",
            timed(lambda: sdf.polylines_model_sdf(p, ground, rings, comment=""), runs),
            None,
        ),
        ("mesh.extrude", timed(lambda: mesh.extrude(polygons, 2.0), runs), None),
        (
            "stl + dae + obj bytes",
            timed(
                lambda: (
                    meshfile.stl_bytes(m),
                    meshfile.dae_bytes(m, "walls"),
                    meshfile.obj_bytes(m),
                ),
                runs,
            ),
            None,
        ),
    ]
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    exe = Path(sys.executable).parent / "scan2terrain"
    if not exe.exists():
        sys.exit(f"{exe} not found: install the package into this environment first")
    tmp = Path(tempfile.mkdtemp())
    try:
        rows = end_to_end(exe, tmp / "w", args.runs)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    rows += steps(args.runs)
    print(f"{'what':34s} {'best [s]':>9s} {'median [s]':>11s} {'target [s]':>11s}")
    for name, times, target in rows:
        goal = f"{target:11.2f}" if target is not None else f"{'':11s}"
        print(f"{name:34s} {min(times):9.3f} {statistics.median(times):11.3f} {goal}")


if __name__ == "__main__":
    main()
