"""Streamed, tiled rasterisation of LAS tiles to a height grid, side by side (by hand, not a test).

    python benchmarks/bench_stream.py [--points 1e8] [--files 100] [--cache DIR] [--quick]

Generates ``--points`` terrain points as ``--files`` LAS 1.2 tiles (point format 0, a square
field of 100 m x 100 m tiles, UTM-like coordinates; kept in ``--cache`` and reused), then runs
each of these in a fresh process and prints points/s, wall time and peak memory (ru_maxrss):

1. ``stream``: scan2terrain's streamed path on one process (``stream_clouds`` -> column
   statistics at 0.5 m), the issue's single-process figure;
2. ``dask-2``: the same on a 2-worker Dask LocalCluster started by the run, with the cluster's
   start-up (including each worker's first imports and numba kernel loads) shown apart, and the
   workers' peak memory;
3. ``numpy``: a plain reference a user might write: each file read whole with laspy, cells by
   ``np.floor``, count with ``np.bincount`` and max/min with ``np.maximum.at`` into full-grid
   arrays (no tiles, no mean; same local origin, so the same grid);
4. ``octree`` (only up to ``--octree-points``, default 1e7): cloud2world's default path, every
   point read into memory and inserted into the voxel octree as end points, then projected.

Every row also gives its start-up (imports and, where compiled kernels run, their first load on
1,000 points; for ``dask-2`` the cluster's start, as before) and its rate past it: at 10^7 points
the start-up (numba's import and first load alone take ~0.4 s) is most of a run.

It then projects the time for 10^10 points on N workers from the measured per-worker throughput
(points / (wall - cluster start-up) / workers; the workers' summed task compute time is shown
too), and checks that ``stream``, ``dask-2`` and
``numpy`` give the same max and count grids. ``--quick``: 10^7 points in 10 files.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np

RES = 0.5
TILE_M = 100.0

RUNNER = textwrap.dedent(
    """
    import json, resource, sys, time
    import numpy as np
    mode, res, out = sys.argv[1], float(sys.argv[2]), sys.argv[3]
    files = sys.argv[4:]
    t0 = time.perf_counter()
    extra = {}
    if mode in ("stream", "dask-2"):
        from scan2terrain.commands import stream
        from scan2terrain.config import load_config
        over = {"octree.resolution": res, "octree.grid": "height", "stream.enabled": True}
        cfg = load_config(None, over)
        if mode == "stream":
            # The same one-off warm-up as each dask-2 worker's (imports, numba's cached kernels,
            # 1,000 points), timed as the start-up.
            probe = stream.plan_clouds(files[:1], cfg)
            stream.rasterize([stream.CloudChunk(probe[0][0].path, 0, 1000, 1000)], probe[1])
            extra["startup_s"] = time.perf_counter() - t0
        if mode == "dask-2":
            from dask.distributed import Client, LocalCluster
            ts = time.perf_counter()
            cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                   dashboard_address=None)
            client = Client(cluster)
            # Warm every worker (imports, numba's cached kernels) on 1,000 points: a one-off
            # cost per worker, counted in the start-up, not in the rate.
            probe = stream.plan_clouds(files[:1], cfg)
            warm = [stream.CloudChunk(probe[0][0].path, 0, 1000, 1000)]
            client.run(stream.rasterize, warm, probe[1])
            extra["cluster_start_s"] = time.perf_counter() - ts
            extra["startup_s"] = time.perf_counter() - t0
            cfg.stream.scheduler = cluster.scheduler_address
        if mode == "dask-2":
            from dask.distributed import get_task_stream
            with get_task_stream(client) as task_stream:
                streamed = stream.stream_clouds(files, cfg)
            extra["task_compute_s"] = sum(
                s["stop"] - s["start"] for t in task_stream.data for s in t["startstops"]
                if s["action"] == "compute")
        else:
            streamed = stream.stream_clouds(files, cfg)
        cs = streamed.tiles.column_stats()
        points = streamed.tiles.points
        maxz, count = cs.max_z, cs.count
        if mode == "dask-2":
            extra["worker_peak_kib"] = max(client.run(
                lambda: __import__("resource").getrusage(
                    __import__("resource").RUSAGE_SELF).ru_maxrss).values())
            client.close(); cluster.close()
    elif mode == "numpy":
        import laspy
        extra["startup_s"] = time.perf_counter() - t0
        lo = np.full(3, np.inf); hi = np.full(3, -np.inf)
        for f in files:
            with laspy.open(f) as r:
                lo = np.minimum(lo, r.header.mins); hi = np.maximum(hi, r.header.maxs)
        org = np.round((lo + hi) / 2)  # the local origin the streamed path subtracts
        c0, r0 = np.floor((lo[:2] - org[:2]) / res).astype(np.int64) - 1
        c1, r1 = np.floor((hi[:2] - org[:2]) / res).astype(np.int64) + 1
        h, w = r1 - r0 + 1, c1 - c0 + 1
        cnt = np.zeros(h * w, np.int64)
        mx = np.full(h * w, -np.inf, np.float32); mn = np.full(h * w, np.inf, np.float32)
        points = 0
        for f in files:
            xyz = laspy.read(f).xyz - org
            flat = ((np.floor(xyz[:, 1] * (1 / res)).astype(np.int64) - r0) * w
                    + np.floor(xyz[:, 0] * (1 / res)).astype(np.int64) - c0)
            cnt += np.bincount(flat, minlength=h * w)
            z32 = xyz[:, 2].astype(np.float32)
            np.maximum.at(mx, flat, z32); np.minimum.at(mn, flat, z32)
            points += len(xyz)
        known = cnt > 0
        rows, cols = np.nonzero(known.reshape(h, w))
        box = (slice(rows.min(), rows.max() + 1), slice(cols.min(), cols.max() + 1))
        maxz = np.where(known, mx, np.nan).reshape(h, w)[box]
        count = cnt.reshape(h, w)[box].astype(np.int32)
    else:
        from scan2terrain.commands.scans import read_clouds
        from scan2terrain.commands.voxels import new_tree
        from scan2terrain.config import load_config
        from scan2terrain.grids.projection import column_stats
        cfg = load_config(None, {"octree.resolution": res})
        warm = new_tree(cfg)
        warm.insert_endpoints(np.random.default_rng(0).uniform(-5, 5, (1000, 3)))
        column_stats(*warm.occupied_and_free(), res)
        extra["startup_s"] = time.perf_counter() - t0
        clouds = read_clouds([__import__("pathlib").Path(f) for f in files], cfg).points
        tree = new_tree(cfg)
        for c in clouds:
            tree.insert_endpoints(c)
        keys, occ = tree.occupied_and_free()
        cs = column_stats(keys, occ, res)
        points = sum(len(c) for c in clouds)
        maxz, count = cs.max_z, cs.count
    wall = time.perf_counter() - t0
    np.save(out + "_max.npy", maxz); np.save(out + "_count.npy", count)
    print(json.dumps({"wall_s": wall, "points": int(points),
                      "peak_kib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, **extra}))
    """
)


def generate(folder: Path, points: int, files: int) -> list[Path]:
    """``files`` LAS tiles on a square field, ``points / files`` points each (cached)."""
    import laspy  # type: ignore[import-untyped]

    folder.mkdir(parents=True, exist_ok=True)
    side = int(np.ceil(np.sqrt(files)))
    each = points // files
    paths = []
    for i in range(files):
        path = folder / f"tile_{i:04d}_{each}.las"
        paths.append(path)
        if path.exists():
            continue
        rng = np.random.default_rng(i)
        x0 = 500_000.0 + TILE_M * (i % side)
        y0 = 4_100_000.0 + TILE_M * (i // side)
        xy = rng.uniform([x0, y0], [x0 + TILE_M, y0 + TILE_M], (each, 2))
        z = 100 + 5 * np.sin(xy[:, 0] / 40) * np.cos(xy[:, 1] / 55) + rng.normal(0, 0.03, each)
        header = laspy.LasHeader(point_format=0, version="1.2")
        header.scales = np.array([0.001, 0.001, 0.001])
        header.offsets = np.array([500_000.0, 4_100_000.0, 0.0])
        las = laspy.LasData(header)
        las.x, las.y, las.z = xy[:, 0], xy[:, 1], z
        tmp = path.with_suffix(".part")
        las.write(tmp)
        tmp.rename(path)
    return paths


def run(mode: str, files: list[Path], work: Path) -> dict[str, float]:
    out = work / mode
    proc = subprocess.run(
        [sys.executable, "-c", RUNNER, mode, str(RES), str(out), *map(str, files)],
        capture_output=True,
        text=True,
        check=False,
    )
    if proc.returncode:
        raise SystemExit(f"{mode} failed:\n{proc.stderr[-3000:]}")
    result: dict[str, float] = json.loads(proc.stdout.strip().splitlines()[-1])
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--points", type=float, default=1e8)
    ap.add_argument("--files", type=int, default=100)
    ap.add_argument("--octree-points", type=float, default=1e7)
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "s2t_bench_las")
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    if args.quick:
        args.points, args.files = 1e7, 10
    points = int(args.points)
    t = time.perf_counter()
    files = generate(args.cache, points, args.files)
    size = sum(f.stat().st_size for f in files)
    print(
        f"{len(files)} LAS tiles, {points:,} points, {size / 1e9:.2f} GB "
        f"(ready in {time.perf_counter() - t:.0f} s); grid {RES} m; load {os.getloadavg()}"
    )
    modes = ["stream", "dask-2", "numpy"]
    if points <= args.octree_points:
        modes.append("octree")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        rows = {m: run(m, files, work) for m in modes}
        ref_max = np.load(work / "stream_max.npy")
        ref_count = np.load(work / "stream_count.npy")
        same = {
            m: bool(
                np.array_equal(np.load(work / f"{m}_count.npy"), ref_count)
                and np.array_equal(np.load(work / f"{m}_max.npy"), ref_max, equal_nan=True)
            )
            for m in ("dask-2", "numpy")
        }
    print(
        "\n| run | wall s | M points/s | start-up s | M points/s past start-up | peak MB (client) "
        "| notes |\n|---|---|---|---|---|---|---|"
    )
    for m, r in rows.items():
        notes = []
        if "cluster_start_s" in r:
            notes.append(f"cluster start {r['cluster_start_s']:.1f} s (excluded from rate)")
            notes.append(f"worker peak {r['worker_peak_kib'] / 1024:.0f} MB")
        if m in same:
            notes.append("same max/count grid as stream" if same[m] else "GRIDS DIFFER")
        wall = r["wall_s"] - r.get("cluster_start_s", 0.0)
        past = r["wall_s"] - r["startup_s"]
        print(
            f"| {m} | {r['wall_s']:.2f} | {r['points'] / wall / 1e6:.2f} | {r['startup_s']:.2f} "
            f"| {r['points'] / past / 1e6:.2f} | {r['peak_kib'] / 1024:.0f} | {'; '.join(notes)} |"
        )
    d = rows["dask-2"]
    per_worker = d["points"] / (d["wall_s"] - d["cluster_start_s"]) / 2
    busy = d["points"] / d["task_compute_s"]
    print(
        f"\nper-worker throughput (dask-2): {per_worker / 1e6:.2f} M points/s of wall time; "
        f"{busy / 1e6:.2f} M points/s of task compute time (two workers sharing two cores "
        "with the client)"
    )
    for n in (2, 8, 32, 128):
        hours = 1e10 / (per_worker * n) / 3600
        print(f"  10^10 points on {n:>3} workers: {hours:6.2f} h (reading and rasterising only)")
    print(f"load after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
