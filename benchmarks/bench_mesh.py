"""Time the wall geometry steps (outlines, simplification, mesh, writers) on three real maps.

Run by hand from the project root::

    python benchmarks/bench_mesh.py [--runs 5]

For the Willow Garage, Levine and warehouse maps, after classification and the default filter
(as map2world does; not timed): one row per step with the best of ``--runs`` wall-clock times
(time.perf_counter), in seconds, one column per map, then the triangle counts. The target is the
``mesh total`` row (trace + extrude + STL + DAE) for Willow Garage: <= 1 s. ``simplify`` runs
once before timing, so numba's compilation (or cache load) is not counted.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the repository: tests.fixtures

from tests.fixtures import LEVINE, WAREHOUSE, WILLOW

MAPS = {
    "willow": WILLOW,
    "levine": LEVINE,
    "warehouse": WAREHOUSE,
}
HEIGHT = 2.0


def best_time(function: Callable[[], Any], runs: int) -> float:
    """Best wall-clock time of ``runs`` calls, in seconds."""
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return min(times)


def time_map(path: Path, runs: int) -> tuple[dict[str, float], dict[str, int]]:
    """Best time of each step on one map, and its counts."""
    from scan2terrain import steps
    from scan2terrain.config import Config
    from scan2terrain.exporters import meshfile
    from scan2terrain.geometry import mesh, outlines
    from scan2terrain.geometry.simplify import simplify
    from scan2terrain.readers import read_map_yaml

    meta, grid = read_map_yaml(path)
    trinary = steps.classify(grid, meta.mode, meta.occupied_thresh, meta.free_thresh)
    occ = steps.filter_occupancy(trinary, Config()) == 100
    r, origin = grid.resolution, grid.origin
    exact = outlines.trace(occ, r, origin)
    simple = simplify(exact, r, resolution=r, origin=origin)  # also warms numba up
    m = mesh.extrude(exact, HEIGHT)
    s = mesh.extrude(simple, HEIGHT)

    def total() -> None:
        walls = mesh.extrude(outlines.trace(occ, r, origin), HEIGHT)
        meshfile.stl_bytes(walls)
        meshfile.dae_bytes(walls, "walls")

    stages: dict[str, Callable[[], Any]] = {
        "trace": lambda: outlines.trace(occ, r, origin),
        "simplify (1 cell)": lambda: simplify(exact, r, resolution=r, origin=origin),
        "extrude (exact)": lambda: mesh.extrude(exact, HEIGHT),
        "extrude (simplified)": lambda: mesh.extrude(simple, HEIGHT),
        "stl_bytes (exact)": lambda: meshfile.stl_bytes(m),
        "dae_bytes (exact)": lambda: meshfile.dae_bytes(m, "walls"),
        "obj_bytes (exact)": lambda: meshfile.obj_bytes(m),
        "mesh total (trace+extrude+stl+dae)": total,
    }
    times = {step: best_time(function, runs) for step, function in stages.items()}
    counts = {
        "occupied cells": int(occ.sum()),
        "cube triangles (12 per cell)": 12 * int(occ.sum()),
        "exact mesh triangles": len(m.faces),
        "simplified mesh triangles": len(s.faces),
    }
    return times, counts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5, help="timed runs per step (default 5)")
    args = parser.parse_args()

    results = {name: time_map(path, args.runs) for name, path in MAPS.items()}
    names = list(MAPS)
    print(f"best of {args.runs} runs, seconds; target: mesh total on willow <= 1.0")
    print(f"{'step':<36}" + "".join(f"{n:>11}" for n in names))
    for step in results[names[0]][0]:
        print(f"{step:<36}" + "".join(f"{results[n][0][step]:>11.3f}" for n in names))
    print()
    for key in results[names[0]][1]:
        print(f"{key:<36}" + "".join(f"{results[n][1][key]:>11d}" for n in names))


if __name__ == "__main__":
    main()
