"""Compile the numba kernels into numba's on-disk cache once, before a user waits for them.

``python -m scan2terrain.warmup`` (``scripts/setup.sh`` runs it after installing, so the README's
first command leaves a warm cache) runs every kernel on small synthetic inputs of the types the
commands pass, so each signature the commands use is compiled and cached: beside the package
(``__pycache__``), or in numba's user-wide cache when the package folder is read-only (a
non-editable ``pip install``). Later processes load the machine code instead of compiling it
(the first run after install took 38-40 s on this machine's 2 cores, a warm one 1.5 s). With
two cores or more, two processes compile its parts (:data:`PARTS`) side by side, then this one
loads them all: 23 s here, against 35 s in one process.

:func:`cold` tells whether any kernel module has never been cached (the warm-up's own test).
:class:`CompileWatch` tells the CLI when numba really compiles during a command, so that it says
so then, and how long it took afterwards; a module-level guess said "compiling" on every run of
a command while some kernel module it never uses stayed out of the cache.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import laspy  # type: ignore[import-untyped]
import numpy as np
from numba.core import event
from numba.core.registry import CPUDispatcher

import scan2terrain._numba  # noqa: F401  (numba readied as the kernels need it)
from scan2terrain.commands.voxels import new_tree
from scan2terrain.config import load_config
from scan2terrain.geometry.outlines import trace
from scan2terrain.geometry.simplify import simplify
from scan2terrain.grids.tiles import Lattice, TileSet
from scan2terrain.octree import _table
from scan2terrain.octree._kernels import SERIAL
from scan2terrain.octree.bt import bt_bytes
from scan2terrain.readers import _ply_kernels
from scan2terrain.readers.las import iter_las
from scan2terrain.replay.agreement import agreement
from scan2terrain.slam.matching import LikelihoodGrid
from scan2terrain.types import Pose2D

#: Every module holding numba kernels (``cache=True``).
KERNEL_MODULES = (
    "scan2terrain.octree._table",
    "scan2terrain.octree._bt",
    "scan2terrain.octree._raycast",
    "scan2terrain.octree._raybox",
    "scan2terrain.octree._batch",
    "scan2terrain.octree._waves",
    "scan2terrain.octree._sparse",
    "scan2terrain.octree._points",
    "scan2terrain.octree._group",
    "scan2terrain.grids._tile_kernels",
    "scan2terrain.readers._las_kernels",
    "scan2terrain.readers._ply_kernels",
    "scan2terrain.geometry._outline_kernels",
    "scan2terrain.slam._bnb_kernels",
    "scan2terrain.replay._march_kernels",
)


def dispatchers() -> list[Any]:
    """The numba dispatchers of :data:`KERNEL_MODULES` and the octree's serial kernel set
    (built from them in octree/_kernels.py); importing them loads numba."""

    found = []
    for name in KERNEL_MODULES:
        module = importlib.import_module(name)
        for value in vars(module).values():
            if isinstance(value, CPUDispatcher) and value.__module__ == name:
                found.append(value)
    known = {id(d) for d in found}
    found += [d for d in SERIAL if isinstance(d, CPUDispatcher) and id(d) not in known]
    return found


def cold() -> bool:
    """Whether some kernel module has nothing in numba's cache yet (a run will compile it).
    Each module's cache folder comes from its dispatchers' own cache locator (beside the
    package, numba's user-wide cache for a read-only package, or NUMBA_CACHE_DIR), so the
    answer follows numba's rules instead of guessing them. Imports numba and the kernel
    modules (a command that needs them imports them anyway); compiles nothing."""
    folders: dict[str, Path] = {}
    for d in dispatchers():
        folders.setdefault(d.__module__, Path(d._cache._cache_path))
    return any(
        not any(folder.glob(f"{module.rsplit('.', 1)[-1]}.*.nbi"))
        for module, folder in folders.items()
    )


#: What the CLI says when numba starts compiling during a command (it says how long it took
#: afterwards). From an empty cache on this 2-core machine: the whole warm-up 38-40 s when idle,
#: 100 s and 288 s with other work on the cores (load 8); a first cloud2world 74 s.
COMPILING = (
    "compiling numba kernels into numba's cache (once; 30 s to 2 minutes on 2 cores; "
    "`python -m scan2terrain.warmup` compiles them all ahead)"
)


class CompileWatch:
    """Notices numba compiling while a block runs, by numba's compile events: they are sent
    only for a signature that is not in the cache (loading one from the cache sends none), so
    what is noticed is a real compilation.

    ``on_start`` is called once, when the first compilation begins. :attr:`seconds` is the time
    spent compiling (a kernel's callees, compiled within it, are counted once). numba compiles
    under one global lock, so the events of two threads never interleave. Compilations in other
    processes (Dask workers) are not seen.
    """

    def __init__(self, on_start: Callable[[], None]) -> None:
        self._on_start = on_start
        self.compiled = False
        self.seconds = 0.0
        self._depth = 0
        self._since = 0.0
        self._listener: Any = None

    def __enter__(self) -> CompileWatch:

        watch = self

        class _Listener(event.Listener):
            def on_start(self, _event: Any) -> None:
                watch._started()

            def on_end(self, _event: Any) -> None:
                watch._ended()

        self._listener = _Listener()
        event.register("numba:compile", self._listener)  # type: ignore[no-untyped-call]
        return self

    def __exit__(self, *exc: object) -> None:

        event.unregister("numba:compile", self._listener)  # type: ignore[no-untyped-call]
        if self._depth:  # left while compiling (an exception)
            self._depth = 1
            self._ended()

    def _started(self) -> None:
        self._depth += 1
        if self._depth == 1:
            self._since = time.perf_counter()
            if not self.compiled:
                self.compiled = True
                self._on_start()

    def _ended(self) -> None:
        self._depth -= 1
        if self._depth == 0:
            self.seconds += time.perf_counter() - self._since


def warm(parts: tuple[str, ...] = ()) -> float:
    """Run every kernel (or those of ``parts``, names of :data:`PARTS`) on small inputs of the
    commands' types; return the seconds it took."""
    start = time.perf_counter()
    for name in parts or tuple(PARTS):
        PARTS[name]()
    return time.perf_counter() - start


def _warm_scans() -> None:
    """Ray casting: each kernel set (serial under PARALLEL_MIN_RAYS rays, parallel above), the
    box of bits and the dense store's; voxel extraction; the .bt writer."""

    rng = np.random.default_rng(0)
    tree = _tree()
    for rays in (720, 8192):
        angles = np.linspace(-np.pi, np.pi, rays, endpoint=False)
        z = rng.uniform(0, 1, rays)
        scan = np.column_stack([4 * np.cos(angles), 3 * np.sin(angles), z])
        tree.insert_scan(scan, np.zeros(3), max_range=-1.0)
        tree.insert_scan(scan.astype(np.float32) + 0.3, np.full(3, 0.3), max_range=3.0)
    # A box too large for its rays (a few beams reach 30 m out in every direction): the dense
    # store's bits instead. Few long beams, so little memory (a fan of 4,096 beams of 400 m
    # made 20 M free voxels here: 5.8 GB and 10 s of the warm-up).
    far = scan.copy()
    far[:8] = 30.0 * np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    tree.insert_scan(far, np.zeros(3), max_range=-1.0)
    # Many small scans in one call (a laser log's path: waves on every core, or one serial
    # call), with bag2world's argument types.
    pts = scan[:720].astype(np.float32)
    origins = np.array([[0.0, 0.0, 0.0], [0.2, 0.2, 0.2]])
    offsets = np.array([0, 720, 1440])
    tree.insert_scans(np.concatenate([pts, pts + 0.2]), offsets, origins, np.array([-1.0, 3.0]))
    tree.insert_scans(pts, offsets[:2], origins[:1], np.array([3.0]))  # one scan: serial
    keys, occupied = tree.occupied_and_free()
    bt_bytes(resolution=tree.resolution, keys=keys, occupied=occupied)
    # The dense store's block table grows only past thousands of dense blocks, more than these
    # inputs make: its rehash, called with the tree's argument types.
    _table.rehash(np.zeros((1, 3), np.int32), 0, 4096)


def _warm_points(sizes: tuple[int, ...]) -> None:
    """End points only, ``sizes`` points a call: the serial kernel set under 16 x
    PARALLEL_MIN_RAYS points, the parallel one above; points that fill the sparse store, make
    it grow and promote blocks to the dense store; voxel extraction and queries by key from
    both stores."""

    rng = np.random.default_rng(1)
    tree = _tree()
    for n in sizes:
        for spread in (60.0, 2.0):
            tree.insert_endpoints(rng.uniform(-spread, spread, (n, 3)))
            tree.insert_endpoints(rng.uniform(-spread, spread, (n, 3)).astype(np.float32))
    keys, _ = tree.occupied_and_free()  # both stores hold voxels now
    tree.logodds_at(keys[:100].astype(np.float64) * 0.1 - 3276.8)


def _warm_grids() -> None:
    """The streamed tiles, outline simplification, LAS scaling."""

    rng = np.random.default_rng(2)
    for lattice in (Lattice(0.1, 64), Lattice(0.1, 64, z_min=-1.0, z_max=1.0)):
        tiles = TileSet(lattice)
        tiles.add_points(rng.uniform(-5, 5, (10_000, 3)))
        tiles.merge(TileSet(lattice))
        tiles.column_stats()
    # The streamed path's binning on two threads (a chunk of 2^17 points a thread at least).
    TileSet(Lattice(0.1, 64), threads=2).add_points(rng.uniform(-5, 5, (1 << 18, 3)))
    walls = np.zeros((12, 12), bool)
    walls[2:10, 3] = walls[5, 2:11] = True
    simplify(trace(walls, 0.05, Pose2D(0.0, 0.0)), 0.05, resolution=0.05, origin=Pose2D(0.0, 0.0))
    _warm_las()
    _warm_ply()
    _warm_correction()


def _warm_correction() -> None:
    """The correlative matcher's branch and bound and the agreement's beam marching."""

    t = np.linspace(0.0, 1.0, 200)
    walls = np.concatenate([np.c_[8 * t, 0 * t], np.c_[0 * t, 5 * t], np.c_[8 * t, 5 + 0 * t]])
    grid = LikelihoodGrid(walls, 0.1, 0.1, margin=1.0)
    grid.match(walls - (2.0, 2.0), np.array([2.1, 1.9, 0.02]), 0.5, 0.1, 0.3)
    poses = np.array([[2.0 + 0.1 * k, 2.0, 0.0] for k in range(10)])
    agreement(poses, [walls - p[:2] for p in poses], 0.1)


def _tree() -> Any:

    return new_tree(load_config(overrides={"octree.resolution": 0.1}))


#: The warm-up in parts that compile apart (seconds each from an empty cache, alone, on this
#: 2-core machine; 35 s all in one process).
PARTS: dict[str, Callable[[], None]] = {
    "scans": _warm_scans,  # 10 s
    "points-serial": lambda: _warm_points((2_000,)),  # 12 s
    "points-parallel": lambda: _warm_points((300_000,)),  # 22 s
    "grids": _warm_grids,  # 7 s
}
#: How the parts are shared out when two processes compile side by side (23 s in all).
_SIDES = (("scans", "points-serial", "grids"), ("points-parallel",))


def warm_side_by_side() -> float:
    """:func:`warm`, its parts compiled by two processes at once where two cores are there,
    then a pass in this process that loads them all (and compiles whatever the two did not
    leave in the cache, e.g. where both wrote one function's cache index at once)."""
    start = time.perf_counter()
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    if (cores or 1) >= 2:
        runs = [
            subprocess.Popen(
                [sys.executable, "-m", "scan2terrain.warmup", "--parts", ",".join(side)],
                stdout=subprocess.DEVNULL,
            )
            for side in _SIDES
        ]
        for run in runs:
            run.wait()
    warm()
    return time.perf_counter() - start


def _warm_las() -> None:
    with tempfile.TemporaryDirectory(prefix="scan2terrain-warmup-") as tmp:
        path = Path(tmp) / "warm.las"
        header = laspy.LasHeader(point_format=3, version="1.2")
        header.scales = np.array([0.01, 0.01, 0.01])
        las = laspy.LasData(header)
        las.x, las.y, las.z = (np.arange(10.0),) * 3
        las.write(path)
        for _ in iter_las(path):
            pass


def _warm_ply() -> None:
    """The walks over PLY rows of varying length, with the argument types ply.py passes."""

    data = np.frombuffer(b"1 2 3 1 4\n", np.uint8)
    counts, signed = np.array([0, 0, 0, 1], np.int64), np.array([False, False, False, True])
    _ply_kernels.walk_ascii(data, 0, 1, counts, signed)
    sizes = np.array([1, 1, 1, 1], np.int64)
    _ply_kernels.walk_binary(data, 0, 1, sizes, counts, signed, False)
    _ply_kernels.skip_space(data, 0)


USAGE = f"usage: python -m scan2terrain.warmup [--parts {','.join(PARTS)}]"


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if args in (["-h"], ["--help"]):
        print(USAGE)
        return 0
    parts = tuple(args[1].split(",")) if args[:1] == ["--parts"] and len(args) == 2 else ()
    if args and (not parts or not set(parts) <= set(PARTS)):
        print(USAGE, file=sys.stderr)
        return 2
    if parts:  # one side of warm_side_by_side, quietly
        warm(parts)
        return 0
    if not cold():  # nothing to do, nothing to say (setup runs this every time)
        return 0
    print("scan2terrain: compiling the numba kernels once into numba's cache (30 s to 2"
          " minutes on 2 cores)...", flush=True)  # fmt: skip
    seconds = warm_side_by_side()
    print(f"scan2terrain: kernels compiled in {seconds:.0f} s; later runs load them")
    return 0


if __name__ == "__main__":
    sys.exit(main())
