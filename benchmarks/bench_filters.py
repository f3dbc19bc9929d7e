"""Time the filters on a 4096 x 4096 trinary occupancy map against scipy's 3 x 3 median.

Run by hand from the project root::

    python benchmarks/bench_filters.py [--size 4096] [--repeats 5] [--seed 0]

Prints one row per filter: the best of ``--repeats`` wall-clock times (time.perf_counter) and its
ratio to ``scipy.ndimage.median_filter(a, size=3)`` timed in the same run. The target for
paper_median_filter and thin_wall_median_filter is a ratio of at most 0.5.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from scan2terrain.filters.majority import majority_filter
from scan2terrain.filters.median import paper_median_filter, thin_wall_median_filter
from scan2terrain.filters.speckle import remove_speckles
from scan2terrain.types import FREE, OCCUPIED, UNKNOWN


def synthetic_map(size: int, seed: int) -> NDArray[np.int8]:
    """A deterministic map: free floor, rooms, straight and diagonal walls, unknown blobs, noise."""
    rng = np.random.default_rng(seed)
    grid = np.full((size, size), FREE, dtype=np.int8)
    n_features = max(1, size // 16)

    # Unknown blobs first, so walls and rooms are drawn over them as a mapper would see them.
    for _ in range(n_features // 8):
        r, c = rng.integers(0, size, 2)
        radius = int(rng.integers(8, 64))
        rows, cols = np.ogrid[-radius : radius + 1, -radius : radius + 1]
        disc = rows**2 + cols**2 <= radius**2
        top, left = max(r - radius, 0), max(c - radius, 0)
        block = grid[top : r + radius + 1, left : c + radius + 1]
        crop = disc[top - (r - radius) :, left - (c - radius) :][: block.shape[0], : block.shape[1]]
        block[crop] = UNKNOWN

    # Rectangular rooms: outlines 1-3 cells thick with a door gap.
    for _ in range(n_features // 2):
        top, left = rng.integers(0, size - 40, 2)
        height, width = rng.integers(20, 200, 2)
        thick = int(rng.integers(1, 4))
        bottom, right = min(top + height, size), min(left + width, size)
        grid[top : top + thick, left:right] = OCCUPIED
        grid[bottom - thick : bottom, left:right] = OCCUPIED
        grid[top:bottom, left : left + thick] = OCCUPIED
        grid[top:bottom, right - thick : right] = OCCUPIED
        door = int(rng.integers(left, max(left + 1, right - 10)))
        grid[top : top + thick, door : door + 8] = FREE

    # Free-standing straight walls.
    for _ in range(n_features):
        r, c = rng.integers(0, size, 2)
        length, thick = int(rng.integers(10, 300)), int(rng.integers(1, 4))
        if rng.random() < 0.5:
            grid[r : r + thick, c : c + length] = OCCUPIED
        else:
            grid[r : r + length, c : c + thick] = OCCUPIED

    # Diagonal walls, 1-3 cells thick, in both directions.
    for _ in range(n_features):
        r, c = rng.integers(0, size, 2)
        length, thick = int(rng.integers(10, 300)), int(rng.integers(1, 4))
        step = 1 if rng.random() < 0.5 else -1
        t = np.arange(length)
        for offset in range(thick):
            rows, cols = r + t, c + step * t + offset
            inside = (rows < size) & (cols >= 0) & (cols < size)
            grid[rows[inside], cols[inside]] = OCCUPIED

    # 1 % salt noise: isolated occupied cells, plus a few unknown ones.
    noise = rng.random((size, size))
    grid[noise < 0.01] = OCCUPIED
    grid[noise > 0.998] = UNKNOWN
    return grid


def best_time(function: Callable[[], Any], repeats: int) -> float:
    """Best wall-clock time of ``repeats`` calls, in seconds."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=4096, help="map side in cells (default 4096)")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per filter (default 5)")
    parser.add_argument("--seed", type=int, default=0, help="RNG seed of the map (default 0)")
    args = parser.parse_args()

    grid = synthetic_map(args.size, args.seed)
    share = {
        name: float(np.mean(grid == v)) for name, v in [("free", FREE), ("occupied", OCCUPIED)]
    }
    print(
        f"map {args.size}x{args.size} int8, seed {args.seed}: "
        f"{share['free']:.1%} free, {share['occupied']:.1%} occupied, "
        f"{1 - share['free'] - share['occupied']:.1%} unknown; best of {args.repeats} runs"
    )

    cases: list[tuple[str, Callable[[], Any]]] = [
        ("scipy.ndimage.median_filter size=3", lambda: ndimage.median_filter(grid, size=3)),
        ("paper_median_filter", lambda: paper_median_filter(grid)),
        ("thin_wall_median_filter", lambda: thin_wall_median_filter(grid)),
        ("majority_filter size=3", lambda: majority_filter(grid, size=3)),
        (
            "remove_speckles occupied <5 cells",
            lambda: remove_speckles(grid, value=OCCUPIED, min_cells=5, replace_with=FREE),
        ),
    ]
    reference = None
    print(f"{'filter':<36} {'time [s]':>9} {'ratio':>7}")
    for name, function in cases:
        seconds = best_time(function, args.repeats)
        reference = seconds if reference is None else reference
        print(f"{name:<36} {seconds:>9.3f} {seconds / reference:>7.2f}")


if __name__ == "__main__":
    main()
