"""--geometry voxels: triangles and meshing speed (run by hand, not a test).

    python benchmarks/bench_voxels.py [--big 10000000]

Targets (issue 15): >= 10x fewer triangles than one cube per occupied voxel (12 each) on
geb079.bt and the FR-079 scans (reported beside a naive surface, 2 per exposed voxel face, and
beside the least any exact triangulation of the same faces can have: per planar region of
faces, its outline vertices + 2 per hole - 2); meshing geb079.bt <= 1 s; 10 M occupied voxels
<= 10 s and <= 2 GB (a synthetic rough terrain with walls: peak RSS in a fresh process).
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the repository: tests.fixtures

from tests.fixtures import FR079, GEB079


def geb079_voxels() -> tuple[np.ndarray, float]:
    from scan2terrain.grids.occupied import occupied_voxels
    from scan2terrain.grids.projection import leaf_columns
    from scan2terrain.octree.bt import read_bt

    bt = read_bt(GEB079)
    keys, occ, runs = leaf_columns(bt.keys, bt.depth, bt.occupied)
    solid = occupied_voxels(keys, occ, runs, GEB079, why="bench")
    return solid.astype(np.int64) - 32768, bt.resolution


def fr079_voxels(resolution: float) -> tuple[np.ndarray, float]:
    from scan2terrain.commands.voxels import build_octree
    from scan2terrain.config import load_config

    cfg = load_config(overrides={"octree.resolution": resolution})
    keys, occupied = build_octree(FR079, cfg).occupied_and_free()
    return keys[occupied].astype(np.int64) - 32768, resolution


def exposed_faces(keys: np.ndarray) -> int:
    lo = keys.min(0) - 1
    k = keys - lo
    dims = k.max(0) + 2
    code = np.sort((k[:, 0] * dims[1] + k[:, 1]) * dims[2] + k[:, 2])
    total = 0
    for step in ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)):
        n = k + np.array(step)
        c = (n[:, 0] * dims[1] + n[:, 1]) * dims[2] + n[:, 2]
        at = np.minimum(np.searchsorted(code, c), len(code) - 1)
        total += int((code[at] != c).sum())
    return total


def least_triangles(keys: np.ndarray) -> int:
    """The fewest triangles any crack-free triangulation of the exposed faces can have: per
    planar region of faces (4-connected, one direction and layer), its outline's corner
    vertices + 2 per hole - 2 (a polygon with V vertices and H holes needs V + 2H - 2, and
    T-junction points only add to V). Summed over regions through Euler's formula:
    corners - 2 * (sum of the regions' Euler characteristics)."""
    lo = keys.min(0) - 1
    k = keys - lo
    dims = k.max(0) + 2
    code = np.sort((k[:, 0] * dims[1] + k[:, 1]) * dims[2] + k[:, 2])
    corner_count = np.array([0, 1, 1, 0, 1, 0, 2, 1, 1, 2, 0, 1, 0, 1, 1, 0])  # 2x2 patterns
    total = 0
    for axis in range(3):
        ua, va = [a for a in range(3) if a != axis]
        for sign in (1, -1):
            n = k.copy()
            n[:, axis] += sign
            c = (n[:, 0] * dims[1] + n[:, 1]) * dims[2] + n[:, 2]
            at = np.minimum(np.searchsorted(code, c), len(code) - 1)
            f = k[code[at] != c]
            layer, u, v = f[:, axis].astype(np.int64), f[:, ua] + 1, f[:, va] + 1
            w = int(dims.max()) + 3
            # Lattice vertices around each cell, with the cell's bit in their 2x2 pattern.
            vert = np.concatenate(
                [((layer * w + u + du) * w + v + dv) for dv in (0, 1) for du in (0, 1)]
            )
            bit = np.repeat([8, 4, 2, 1], len(f))  # the cell is up-right of vertex (u, v): bit 3
            vs, inv = np.unique(vert, return_inverse=True)
            pattern = np.bincount(inv.reshape(-1), weights=bit, minlength=len(vs)).astype(int)
            corners = int(corner_count[pattern].sum())
            diagonal = int(np.isin(pattern, (6, 9)).sum())
            h_edges = np.unique(
                np.concatenate([(layer * w + u) * w + v, (layer * w + u) * w + v + 1])
            )
            v_edges = np.unique(
                np.concatenate([(layer * w + u) * w + v, (layer * w + u + 1) * w + v])
            )
            euler = len(f) - len(h_edges) - len(v_edges) + len(vs) + diagonal
            total += corners - 2 * euler
    return total


def row(name: str, keys: np.ndarray, resolution: float, runs: int = 3) -> None:
    from scan2terrain.geometry.voxel_mesh import mesh_voxels

    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        chunks = mesh_voxels(keys, resolution, chunk_cells=max(1, round(16 / resolution)))
        times.append(time.perf_counter() - t0)
    tris = sum(len(c.mesh.faces) for c in chunks)
    faces = exposed_faces(keys)
    least = least_triangles(keys)
    print(
        f"  {name:26s} {len(keys):>10,} {tris:>10,} {12 * len(keys) / tris:>7.1f}x"
        f" {2 * faces / tris:>7.1f}x {12 * len(keys) / least:>7.1f}x"
        f" {min(times):>7.2f} s {len(keys) / min(times) / 1e6:>6.2f}"
    )


def big(n: int) -> None:
    """A rough terrain with walls, about ``n`` occupied voxels, in this (fresh) process."""
    from scan2terrain.geometry.voxel_mesh import mesh_voxels

    side = int(np.sqrt(n / 3))
    rng = np.random.default_rng(0)
    x, y = np.meshgrid(np.arange(side), np.arange(side), indexing="ij")
    z = (8 * np.sin(x / 40) + 8 * np.cos(y / 55) + rng.integers(0, 2, x.shape)).astype(np.int64)
    layers = [np.stack([x, y, z - d], -1).reshape(-1, 3) for d in range(3)]
    keys = np.unique(np.concatenate(layers), axis=0)
    del x, y, z, layers
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    t0 = time.perf_counter()
    chunks = mesh_voxels(keys, 0.05, chunk_cells=320)
    dt = time.perf_counter() - t0
    tris = sum(len(c.mesh.faces) for c in chunks)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(
        f"  {'synthetic terrain':26s} {len(keys):>10,} {tris:>10,} {12 * len(keys) / tris:>7.1f}x"
        f" {'':>8} {dt:>7.2f} s {len(keys) / dt / 1e6:>6.2f}   peak {peak:.0f} MiB"
        f" (input built: {before:.0f} MiB)"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--big", type=int, default=10_000_000, help="voxels of the large case")
    parser.add_argument("--child", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        big(args.child)
        return
    print(f"  {'input':26s} {'voxels':>10} {'triangles':>10} {'vs cubes':>8} {'vs faces':>8}"
          f" {'at best':>8} {'time':>9} {'M vox/s':>6}")  # fmt: skip
    row("geb079.bt (0.08 m)", *geb079_voxels())
    row("FR-079 scans, 0.1 m", *fr079_voxels(0.1), runs=1)
    row("FR-079 scans, 0.05 m", *fr079_voxels(0.05), runs=1)
    subprocess.run([sys.executable, __file__, "--child", str(args.big)], check=True)


if __name__ == "__main__":
    main()
