"""VoxelOctree against OctoMap (octomap-python), side by side in one run (by hand, not a test).

    python benchmarks/bench_octree.py [--quick]

Measures, and prints as tables:

1. Ray-cast insertion (``VoxelOctree.insert_scan`` vs ``OcTree.insertPointCloud(pts, origin,
   -1.0)``), points/s and the speed-up: (a) the FR-079 corridor scan (88,206 points, sensor at the
   origin) into a fresh tree per repetition, at 0.05 m and 0.1 m; (b) a synthetic 100-scan room
   (10k points per scan, ranges 5-18 m) into one tree, total time, at 0.1 m (and 0.05 m when
   OctoMap's run is expected to stay under ~3 minutes). Targets (issue 3): >= 40x at 0.05 m on
   FR-079, >= 20x at 0.1 m, >= 20x on the room.
2. End-point-only insertion (``VoxelOctree.insert_endpoints``) of 10 M points, points/s, against
   OctoMap's per-point ``updateNode`` timed on 100k points and extrapolated: uniform in a box
   (~46 points per 8 x 8 x 8 block: the sparse store), a surface (dense blocks) and uniform in a
   1 km box (about one point per block). Target >= 20 M points/s.
3. Peak memory of a fresh process that builds the map (``ru_maxrss`` after the build minus after
   imports, data loading and warm-up), FR-079 at 0.05 m, the room at 0.1 m and 2 M uniform end
   points at 0.1 m (``insert_endpoints`` vs ``updateNodes``). Target: ours <= 0.5x OctoMap's.
4. ``.bt`` size and write time: ``write_bt`` vs ``OcTree.writeBinary`` for FR-079 at 0.05 m.
   Target: size within 1.05x.
5. End to end on FR-079 at 0.05 m, each a fresh process (3 runs): ``scan2terrain octree2world
   scan_node.dat -o OUT --resolution 0.05`` (read, ray cast, .bt, projection, walls world,
   preview) against OctoMap's own tools making only the ``.bt``: ``log2graph`` (scan_node.dat
   to a graph) then ``graph2tree -res 0.05``; time and peak memory (ru_maxrss), and whether the
   two ``.bt`` files are the same bytes. Both read the same file, ``scan.dat.bz2`` decompressed
   beforehand with a ``NODE 0 0 0 0 0 0`` line first (log2graph reads neither bz2 nor a file
   without NODE lines), and our run may use Python's bytecode caches, as an installed package
   does. Target (issue 17): >= 10x OctoMap's time, peak memory <= OctoMap's.

Times are wall clock (time.perf_counter); "best" is the minimum over the repetitions and "median"
their median. Other processes may share the machine: the load average is printed before and
after. The octomap-python wheel is built without OpenMP, so OctoMap runs on one core while the
numba kernels use every numba thread; a one-thread row of ours is printed for comparison.
``--quick`` uses 20 room scans, 2 M end points (1 M for memory) and fewer repetitions;
``--only 2`` (or ``--only 1 3``, ...) runs only those parts.
"""

from __future__ import annotations

import argparse
import bz2
import contextlib
import functools
import gc
import importlib.metadata
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the repository: tests.fixtures

from tests.fixtures import FR079

FR079_POINTS = 88_206

#: The synthetic room: a hall, pillars and crates (axis-aligned boxes, metres).
HALL = (np.array([-18.0, -18.0, 0.0]), np.array([18.0, 18.0, 6.0]))
_PILLARS = [(-9, -9), (-9, 9), (9, -9), (9, 9), (0, -12), (0, 12), (-12, 0), (12, 0)]
OBSTACLES = [
    (np.array([x - 0.4, y - 0.4, 0.0]), np.array([x + 0.4, y + 0.4, 6.0])) for x, y in _PILLARS
]
OBSTACLES += [
    (np.array([x0, y0, 0.0]), np.array([x0 + w, y0 + d, h]))
    for x0, y0, w, d, h in [
        (-15.0, -6.0, 2.0, 1.2, 1.0),
        (13.0, 5.0, 1.2, 2.0, 1.5),
        (-4.0, 14.0, 3.0, 1.0, 2.0),
        (6.0, -15.0, 1.5, 1.5, 0.8),
        (-14.0, 12.0, 1.0, 3.0, 2.5),
        (11.0, -11.0, 2.5, 1.0, 1.2),
    ]
]
RANGE_MIN, RANGE_MAX = 5.0, 18.0
ROOM_SEED = 20240613


# --- data ---------------------------------------------------------------------------------------


def load_fr079() -> NDArray[np.float64]:
    """The FR-079 scan: ``x y z`` text lines (``NODE`` pose lines, if any, are skipped)."""
    with bz2.open(FR079, "rt") as f:
        rows = [line for line in f if line.strip() and not line.startswith(("NODE", "#"))]
    pts = np.loadtxt(rows, dtype=np.float64).reshape(-1, 3)
    if len(pts) != FR079_POINTS:
        sys.exit(f"{FR079}: expected {FR079_POINTS} points, read {len(pts)}")
    return pts


def first_hit(origin: NDArray[np.float64], dirs: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distance along unit ``dirs`` from ``origin`` (inside the hall) to the first surface."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / dirs
        lo, hi = HALL
        exit_t = np.where(dirs > 0, (hi - origin) * inv, (lo - origin) * inv)
        exit_t = np.where(dirs == 0, np.inf, exit_t)
        t: NDArray[np.float64] = exit_t.min(axis=1)
        for blo, bhi in OBSTACLES:
            t1, t2 = (blo - origin) * inv, (bhi - origin) * inv
            near = np.fmin(t1, t2).max(axis=1)
            far = np.fmax(t1, t2).min(axis=1)
            hit = (near <= far) & (near > 0) & (near < t)
            t = np.where(hit, near, t)
    return t


def room_scans(
    n_scans: int, per_scan: int, seed: int = ROOM_SEED
) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """``n_scans`` (origin, points) pairs: sensor poses on a loop through the hall, points where
    random directions first meet a surface, kept when the range is in [5, 18] m."""
    rng = np.random.default_rng(seed)
    scans = []
    for i in range(n_scans):
        a = 2 * np.pi * i / 100  # the full run is one lap; --quick takes its first 20 poses
        origin = np.array([4.5 * np.cos(a), 3.5 * np.sin(a), 1.5 + 0.3 * np.sin(3 * a)])
        got: list[NDArray[np.float64]] = []
        have = 0
        while have < per_scan:
            dirs = rng.normal(size=(3 * per_scan, 3))
            dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
            t = first_hit(origin, dirs)
            keep = (t >= RANGE_MIN) & (t <= RANGE_MAX)
            got.append(origin + t[keep, None] * dirs[keep])
            have += int(keep.sum())
        scans.append((origin, np.concatenate(got)[:per_scan]))
    return scans


def save_scans(path: Path, scans: list[tuple[NDArray[np.float64], NDArray[np.float64]]]) -> None:
    counts = [len(p) for _, p in scans]
    np.savez(
        path,
        origins=np.array([o for o, _ in scans]),
        points=np.concatenate([p for _, p in scans]),
        starts=np.r_[0, np.cumsum(counts)],
    )


def load_scans(path: Path) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
    with np.load(path) as z:
        origins, points, starts = z["origins"], z["points"], z["starts"]
    return [(origins[i], points[starts[i] : starts[i + 1]]) for i in range(len(origins))]


# --- the two libraries, behind one interface --------------------------------------------------


def build_ours(scans: list[tuple[NDArray[np.float64], NDArray[np.float64]]], res: float) -> Any:
    from scan2terrain.octree.tree import VoxelOctree

    tree = VoxelOctree(res)
    for origin, pts in scans:
        tree.insert_scan(pts, origin, max_range=-1.0)
    return tree


def build_octomap(scans: list[tuple[NDArray[np.float64], NDArray[np.float64]]], res: float) -> Any:
    import octomap

    tree = octomap.OcTree(res)
    for origin, pts in scans:
        tree.insertPointCloud(pts, origin, -1.0)
    return tree


def warm_up() -> float:
    """Load (or compile) every numba kernel the benchmark uses; return the seconds it took."""
    from scan2terrain.octree.tree import VoxelOctree

    t0 = time.perf_counter()
    rng = np.random.default_rng(1)
    tree = VoxelOctree(0.1)
    tree.insert_scan(rng.uniform(-3, 3, (500, 3)), (0.0, 0.0, 0.0))
    tree.insert_scan(rng.uniform(-3, 3, (500, 3)), (0.1, 0.2, 0.3), max_range=2.0)
    # a scan of 4096 rays or more: the parallel path, into the scan's own box of bits
    tree.insert_scan(rng.uniform(-3, 3, (5000, 3)), (0.0, 0.0, 0.0))
    tree.insert_endpoints(rng.uniform(-3, 3, (500, 3)).astype(np.float32))
    # enough points for the parallel kernels: sparse and dense blocks, then the same again
    ends = np.concatenate([rng.uniform(-30, 30, (100_000, 3)), rng.uniform(-1, 1, (100_000, 3))])
    for _ in range(2):
        tree.insert_endpoints(ends.astype(np.float32))
    tree.occupied_and_free()
    return time.perf_counter() - t0


# --- timing helpers ---------------------------------------------------------------------------


@dataclass
class Timing:
    times: list[float]

    @property
    def best(self) -> float:
        return min(self.times)

    @property
    def median(self) -> float:
        return statistics.median(self.times)

    def __str__(self) -> str:
        return f"{self.best:8.3f} {self.median:8.3f}"


def timed(fn: Callable[[], Any], repeats: int, keep: list[Any] | None = None) -> Timing:
    """Wall-clock times of ``repeats`` calls (garbage collected before each, not timed)."""
    times = []
    for _ in range(repeats):
        gc.collect()
        t0 = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t0)
        if keep is not None:
            keep[:] = [result]
        del result
    return Timing(times)


@contextlib.contextmanager
def numba_threads(n: int) -> Iterator[None]:
    import numba

    old = numba.get_num_threads()
    numba.set_num_threads(n)
    try:
        yield
    finally:
        numba.set_num_threads(old)


STAGES: tuple[str, ...] = ("_points", "scan_rays", "_scan_box", "flag_blocks", "alloc_flagged")
STAGES += ("mark_hits",)
STAGES += ("cast_parallel", "cast_serial", "block_bounds", "cast_box", "alloc_box", "apply_box")
STAGES += ("apply_blocks", "_fresh_blocks", "_adopt", "_grow")
ENDPOINT_STAGES: tuple[str, ...] = ("_points_any", "count_points", "place_points", "touch_points")
ENDPOINT_STAGES += ("group_new_points", "sparse_rehash", "upsert_sparse", "alloc_dense_runs")
ENDPOINT_STAGES += ("_fresh_blocks", "adopt_sparse", "mark_point_bits", "apply_blocks", "_grow")


@contextlib.contextmanager
def stage_timer(acc: dict[str, float], names: tuple[str, ...] = STAGES) -> Iterator[None]:
    """Accumulate the time spent in VoxelOctree's stages into ``acc`` (the kernels are looked up
    on their modules, or in the PARALLEL and SERIAL kernel sets, at call time, so wrapping those
    times them)."""
    from scan2terrain.octree import _group, _points, _raybox, _raycast, _sparse
    from scan2terrain.octree import _kernels as K
    from scan2terrain.octree.tree import VoxelOctree

    def wrap(fn: Callable[..., Any], name: str) -> Callable[..., Any]:
        @functools.wraps(fn)
        def inner(*args: Any, **kwargs: Any) -> Any:
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                acc[name] = acc.get(name, 0.0) + time.perf_counter() - t0

        return inner

    saved: list[tuple[Any, str, Any]] = []
    modules = (_raycast, _raybox, _points, _group, _sparse)
    for name in names:
        owner: Any = VoxelOctree
        if not name.startswith("_"):
            owner = next((m for m in modules if name in m.__dict__), K)
        if name in K.Kernels._fields or name not in owner.__dict__:
            continue  # in the kernel sets (below), or not in this version of the code
        original = owner.__dict__[name]
        saved.append((owner, name, original))
        timed_fn = wrap(getattr(owner, name), name)
        setattr(
            owner, name, staticmethod(timed_fn) if isinstance(original, staticmethod) else timed_fn
        )
    for kind in ("PARALLEL", "SERIAL"):
        kernels = getattr(K, kind)
        saved.append((K, kind, kernels))
        timed_set = {f: wrap(getattr(kernels, f), f) for f in kernels._fields if f in names}
        setattr(K, kind, kernels._replace(**timed_set))
    try:
        yield
    finally:
        for owner, name, original in reversed(saved):
            setattr(owner, name, original)


def stage_profile(
    scans: list[tuple[NDArray[np.float64], NDArray[np.float64]]], res: float, repeats: int
) -> tuple[dict[str, float], float]:
    """Per-stage seconds (minimum over ``repeats`` fresh builds) and the best total."""
    per: dict[str, list[float]] = {name: [] for name in STAGES}
    totals = []
    for _ in range(repeats):
        acc: dict[str, float] = {}
        gc.collect()
        with stage_timer(acc):
            t0 = time.perf_counter()
            build_ours(scans, res)
            totals.append(time.perf_counter() - t0)
        for name in STAGES:
            per[name].append(acc.get(name, 0.0))
    return {name: min(v) for name, v in per.items()}, min(totals)


def print_stages(
    label: str, stages: dict[str, float], total: float, call: str = "insert_scan"
) -> None:
    rest = total - sum(stages.values())
    parts = [f"{n} {s * 1e3:.0f} ({s / total:.0%})" for n, s in stages.items() if s > 0.0005]
    print(f"     {label}: total {total * 1e3:.0f} ms = " + ", ".join(parts))
    print(
        f"       {'':<{len(label)}}  other Python in {call} {rest * 1e3:.0f} ms "
        f"({rest / total:.0%})"
    )


# --- memory: a fresh process per build ----------------------------------------------------------


def _status_kb(field: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    return -1


def endpoints_ours(points: NDArray[np.float64], res: float) -> Any:
    from scan2terrain.octree.tree import VoxelOctree

    tree = VoxelOctree(res)
    tree.insert_endpoints(points)
    return tree


def endpoints_octomap(points: NDArray[np.float64], res: float) -> Any:
    import octomap

    tree = octomap.OcTree(res)
    tree.updateNodes(points, True)
    return tree


def child_memory(which: str, data: Path, res: float) -> None:
    """Runs in the child process: build one map, print its memory as JSON. ``which``: ours or
    octomap (scans, ray cast), ours-endpoints or octomap-endpoints (points, end points only)."""
    build: Callable[[Any, float], Any]
    if which.endswith("-endpoints"):
        scans: Any = np.load(data)
        if which.startswith("ours"):
            warm_up()
            build = endpoints_ours
        else:
            build = endpoints_octomap
            build(scans[:10].copy(), res)  # loads the library's code
    else:
        scans = load_scans(data)
        if which == "ours":
            warm_up()
            build = build_ours
        else:
            build_octomap([(np.zeros(3), np.ones((2, 3)))], res)  # loads the library's code
            build = build_octomap
    gc.collect()
    base = {
        "base_peak_kb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss,
        "base_hwm_kb": _status_kb("VmHWM"),
        "base_rss_kb": _status_kb("VmRSS"),
    }
    t0 = time.perf_counter()
    tree = build(scans, res)
    seconds = time.perf_counter() - t0
    out = base | {
        "peak_kb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss,
        "hwm_kb": _status_kb("VmHWM"),
        "rss_kb": _status_kb("VmRSS"),
        "own_bytes": int(tree.memory_bytes() if which.startswith("ours") else tree.memoryUsage()),
        "seconds": seconds,
    }
    print(json.dumps(out))


#: Linux carries a process's peak RSS into ru_maxrss across fork and exec, so a child of this
#: (by then large) process would report at least the parent's peak. A small launcher in between
#: gives the child a clean count: it inherits only the launcher's ~10 MB.
_LAUNCHER = "import subprocess, sys; sys.exit(subprocess.run(sys.argv[1:]).returncode)"


def measure_memory(which: str, data: Path, res: float) -> dict[str, Any]:
    """Build one map in a fresh process (via the launcher); its memory figures and build time."""
    script = str(Path(__file__).resolve())
    child = [sys.executable, script, "--child", which, str(data), str(res)]
    cmd = [sys.executable, "-S", "-c", _LAUNCHER, *child]
    done = subprocess.run(cmd, check=True, capture_output=True, text=True)
    result: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


#: Runs a command and prints its wall time and peak memory (its ru_maxrss) as JSON.
_TIMER = (
    "import json, resource, subprocess, sys, time; t = time.perf_counter(); "
    "r = subprocess.run(sys.argv[1:], capture_output=True); "
    "print(json.dumps({'seconds': time.perf_counter() - t, 'rc': r.returncode, "
    "'peak_kb': resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss}))"
)


def run_timed(cmd: list[str]) -> dict[str, Any]:
    """``cmd`` in a fresh process (through a small launcher): seconds, exit code, peak KB.
    Python may write and reuse its bytecode caches, as an installed package does (a shell with
    PYTHONDONTWRITEBYTECODE set would otherwise compile every module of ours at each run)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    done = subprocess.run(
        [sys.executable, "-S", "-c", _TIMER, *cmd],
        check=True,
        capture_output=True,
        text=True,
        env=env,
    )
    result: dict[str, Any] = json.loads(done.stdout)
    if result["rc"] != 0:
        raise RuntimeError(f"{cmd[0]} failed ({result['rc']})")
    return result


def end_to_end(tmp: Path, summary: list[tuple[str, str, str, bool]]) -> None:
    """Part 5: octree2world on FR-079 against log2graph + graph2tree, fresh processes."""
    import shutil

    print()
    print("5. End to end, FR-079 at 0.05 m, a fresh process per run (3 runs, wall time, peak RSS)")
    tools = [shutil.which(t) for t in ("log2graph", "graph2tree")]
    cli = shutil.which("scan2terrain") or str(Path(sys.executable).parent / "scan2terrain")
    if None in tools:
        print("   skipped: octomap-tools (log2graph, graph2tree) not installed")
        return
    log = tmp / "scan_node.dat"
    log.write_bytes(b"NODE 0 0 0 0 0 0\n" + bz2.decompress(FR079.read_bytes()))
    graph, bt, out = tmp / "scan.graph", tmp / "octomap.bt", tmp / "fr079_world"
    ours, octo = [], []
    for _ in range(3):
        ours.append(
            run_timed([cli, "octree2world", str(log), "-o", str(out), "--resolution", "0.05",
                       "--overwrite", "-q"])
        )  # fmt: skip
        a = run_timed([str(tools[0]), str(log), str(graph)])
        b = run_timed([str(tools[1]), "-i", str(graph), "-o", str(bt), "-res", "0.05"])
        octo.append(
            {"seconds": a["seconds"] + b["seconds"], "peak_kb": max(a["peak_kb"], b["peak_kb"])}
        )
    same = (out / "octree.bt").read_bytes() == bt.read_bytes()
    t_ours = Timing([r["seconds"] for r in ours])
    t_octo = Timing([r["seconds"] for r in octo])
    m_ours = max(r["peak_kb"] for r in ours) / 1024
    m_octo = max(r["peak_kb"] for r in octo) / 1024
    print(f"   {'':<38} {'best s':>7} {'median':>7} {'peak MB':>8}")
    for name, t, m in (
        ("scan2terrain octree2world (a world)", t_ours, m_ours),
        ("log2graph + graph2tree (a .bt)", t_octo, m_octo),
    ):
        print(f"   {name:<38} {t.best:7.2f} {t.median:7.2f} {m:8.0f}")
    ratio = t_octo.best / t_ours.best
    bytes_ = "are" if same else "are NOT"
    print(f"   speed-up {ratio:.1f}x (target >= 10x); the two .bt files {bytes_} the same bytes")
    summary.append(("end to end FR-079 0.05 m", f"{ratio:.1f}x", ">= 10x", ratio >= 10.0))
    summary.append(
        ("end to end peak memory", f"{m_ours:.0f} MB", f"<= {m_octo:.0f} MB", m_ours <= m_octo)
    )


# --- printing -----------------------------------------------------------------------------------


def mb(n_bytes: float) -> str:
    return f"{n_bytes / 2**20:8.1f}"


def verdict(ok: bool) -> str:
    return "PASS" if ok else "FAIL"


def machine_info() -> None:
    import numba
    import octomap  # noqa: F401

    try:
        cpu = next(
            line.split(":", 1)[1].strip()
            for line in Path("/proc/cpuinfo").read_text().splitlines()
            if line.startswith("model name")
        )
    except (OSError, StopIteration):
        cpu = platform.processor() or "?"
    print(f"machine: {platform.machine()}, {cpu}")
    print(
        f"cpus: os.cpu_count()={os.cpu_count()}, affinity={len(os.sched_getaffinity(0))}; "
        f"numba threads {numba.get_num_threads()} (NUMBA_NUM_THREADS="
        f"{numba.config.NUMBA_NUM_THREADS}, layer {numba.config.THREADING_LAYER!r})"  # type: ignore[attr-defined]
    )
    versions = {
        "python": platform.python_version(),
        "numpy": np.__version__,
        "numba": numba.__version__,
        "octomap-python": importlib.metadata.version("octomap-python"),
        "scan2terrain": importlib.metadata.version("scan2terrain"),
    }
    print("versions: " + ", ".join(f"{k} {v}" for k, v in versions.items()))
    print("OctoMap: octomap-python wheel, no OpenMP (single-threaded insertPointCloud)")
    print("load average (1, 5, 15 min) at start: " + ", ".join(f"{x:.2f}" for x in os.getloadavg()))


# --- part 2: end points only -------------------------------------------------------------------


def endpoint_clouds(n: int) -> list[tuple[str, str, NDArray[np.float32]]]:
    """(short name, description, points float32 (n, 3)) of part 2's clouds."""
    rng = np.random.default_rng(7)
    box = rng.uniform((-50.0, -50.0, 0.0), (50.0, 50.0, 10.0), (n, 3)).astype(np.float32)
    xy = rng.uniform(-50.0, 50.0, (n, 2))
    z = 2.0 + 1.5 * np.sin(xy[:, 0] / 7.0) * np.cos(xy[:, 1] / 5.0) + rng.normal(0, 0.03, n)
    surface = np.column_stack([xy, z]).astype(np.float32)
    del xy, z
    wide = rng.uniform((-500.0, -500.0, 0.0), (500.0, 500.0, 10.0), (n, 3)).astype(np.float32)
    return [
        ("uniform", "uniform in a 100 x 100 x 10 m box", box),
        ("surface", "surface z = f(x, y), 100 x 100 m", surface),
        ("sparse", "uniform in a 1 km x 1 km x 10 m box", wide),
    ]


def endpoint_part(n_end: int, quick: bool, summary: list[tuple[str, str, str, bool]]) -> Any:
    """Part 2, ours: insert_endpoints of each cloud into a fresh tree and again; returns the
    best fresh rates (M points/s) by cloud."""
    from scan2terrain.octree.tree import VoxelOctree

    reps = 2 if quick else 3
    print()
    print(f"2. End points only: insert_endpoints, {n_end / 1e6:g} M points, 0.1 m")
    print(
        "   'fresh': into a new tree (includes growing the storage), best and median of "
        f"{reps}; 'again': the same points into that tree once more, best and median of 3"
    )
    print(
        "   'dense': 8 x 8 x 8 blocks of the dense store, 'sparse': voxels in the sparse store, "
        "'MB': VoxelOctree.memory_bytes() after 'fresh'"
    )
    print(
        f"   {'points':<36} {'fresh best':>10} {'median':>7} {'Mpts/s':>6} "
        f"{'again best':>10} {'median':>7} {'Mpts/s':>6} {'dense':>7} {'sparse':>9} {'MB':>6} "
        f"{'target':>6}"
    )
    ours_rate: dict[str, float] = {}
    profiles: list[tuple[str, dict[str, float], float]] = []
    for short, name, pts in endpoint_clouds(n_end):
        if short == "sparse" and not hasattr(VoxelOctree, "n_sparse"):
            print(f"   {name:<36} skipped: a block per point, ~2 KB each, without a sparse store")
            continue
        keep: list[Any] = []

        def fresh(pts: NDArray[np.float32] = pts) -> Any:
            tree = VoxelOctree(0.1)
            tree.insert_endpoints(pts)
            return tree

        t_fresh = timed(fresh, reps, keep)
        tree = keep[0]
        size = tree.memory_bytes()
        t_again = timed(functools.partial(tree.insert_endpoints, pts), 3)
        rate = n_end / t_fresh.best / 1e6
        ours_rate[short] = rate
        print(
            f"   {name:<36} {t_fresh.best:10.3f} {t_fresh.median:7.3f} {rate:6.2f} "
            f"{t_again.best:10.3f} {t_again.median:7.3f} {n_end / t_again.best / 1e6:6.2f} "
            f"{tree.n_blocks:7d} {getattr(tree, 'n_sparse', 0):9d} {size / 2**20:6.0f} "
            f"{'>=20':>6} {verdict(rate >= 20)}",
            flush=True,
        )
        summary.append((f"insert_endpoints {short}", f"{rate:.2f} M/s", ">= 20 M/s", rate >= 20))
        builds: list[tuple[str, Callable[[], Any]]] = [
            ("fresh", fresh),
            ("again", functools.partial(tree.insert_endpoints, pts)),
        ]
        for label, build in builds:
            acc: dict[str, float] = {}
            gc.collect()
            with stage_timer(acc, ENDPOINT_STAGES):
                t0 = time.perf_counter()
                build()
                total = time.perf_counter() - t0
            profiles.append((f"{short} {label}", acc, total))
        del tree, keep
        gc.collect()
    print("   where ours spends its time (ms, one run each):")
    for label, acc, total in profiles:
        print_stages(label, acc, total, "insert_endpoints")
    return ours_rate


def octomap_endpoints(n_end: int, ours_rate: dict[str, float]) -> None:
    """Part 2, OctoMap: updateNode per point on the first 100k points of each cloud."""
    import octomap

    n_o = 100_000
    print(
        f"   OctoMap, one updateNode(point, True) per point, timed on the first {n_o:,} points "
        f"into a fresh tree (best of 2), EXTRAPOLATED to {n_end / 1e6:g} M:"
    )
    for short, _, pts in endpoint_clouds(n_end):
        sub = pts[:n_o].astype(np.float64).tolist()

        def loop(sub: list[list[float]] = sub) -> None:
            t = octomap.OcTree(0.1)
            for p in sub:
                t.updateNode(p, True)

        def cython(sub: list[list[float]] = sub) -> None:
            octomap.OcTree(0.1).updateNodes(sub, True)

        for how, fn in [("updateNodes (Cython loop)", cython), ("updateNode (Python loop)", loop)]:
            t = timed(fn, 2)
            rate = n_o / t.best
            ours = (
                f"ours {ours_rate[short] * 1e6 / rate:5.1f}x faster" if short in ours_rate else ""
            )
            print(
                f"   {short:<8} {how:<26} {t.best:6.3f} s per 100k = {rate / 1e6:5.3f} M pts/s; "
                f"{n_end / 1e6:g} M: ~{n_end / rate:5.1f} s (extrapolated); {ours} (fresh)"
            )


# --- the benchmark ------------------------------------------------------------------------------


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="20 room scans, fewer repetitions")
    parser.add_argument(
        "--only",
        nargs="+",
        type=int,
        choices=(1, 2, 3, 4, 5),
        default=(1, 2, 3, 4, 5),
        help="run only these parts (part 4 needs part 1's FR-079 trees)",
    )
    parser.add_argument(
        "--child", nargs=3, metavar=("WHICH", "DATA", "RES"), help=argparse.SUPPRESS
    )
    args = parser.parse_args()
    if args.child:
        child_memory(args.child[0], Path(args.child[1]), float(args.child[2]))
        return
    with tempfile.TemporaryDirectory(prefix="bench_octree_") as tmp:
        run(quick=args.quick, tmp=Path(tmp), parts=set(args.only))


def run(*, quick: bool, tmp: Path, parts: set[int]) -> None:
    import octomap

    from scan2terrain.octree.bt import write_bt

    reps_ours, reps_octo = (3, 2) if quick else (5, 3)
    n_room = 20 if quick else 100
    n_end = 2_000_000 if quick else 10_000_000
    n_mem = 1_000_000 if quick else 2_000_000  # end points for part 3 (OctoMap: ~6 s per M)
    wall0 = time.perf_counter()
    print(f"bench_octree ({'--quick' if quick else 'full'} mode)")
    machine_info()
    print(f"numba warm-up (first calls load/compile the kernels): {warm_up():.2f} s")

    summary: list[tuple[str, str, str, bool]] = []
    memory: dict[tuple[str, str], dict[str, Any]] = {}
    fr_trees: dict[float, tuple[Any, Any]] = {}
    if parts & {1, 3, 4}:
        fr = load_fr079()
        fr_scan = [(np.zeros(3), fr)]
        fr_data, room_data = tmp / "fr079.npz", tmp / "room.npz"
        save_scans(fr_data, fr_scan)
    if parts & {1, 3}:
        t0 = time.perf_counter()
        room = room_scans(n_room, 10_000)
        save_scans(room_data, room)
        ranges = np.concatenate([np.linalg.norm(p - o, axis=1) for o, p in room])
        print(
            f"room: {n_room} scans x 10,000 points, hall 36 x 36 x 6 m, {len(OBSTACLES)} boxes, "
            f"ranges {ranges.min():.2f}-{ranges.max():.2f} m (median {np.median(ranges):.1f}), "
            f"generated in {time.perf_counter() - t0:.1f} s"
        )
        n_room_pts = sum(len(p) for _, p in room)

    if 1 in parts:
        # --- 1. ray-cast insertion ----------------------------------------------------------------
        print()
        print("1. Ray-cast insertion (insert_scan vs insertPointCloud(points, origin, -1.0))")
        print(
            f"   FR-079: a fresh tree per repetition, ours best of {reps_ours}, "
            f"OctoMap best of {reps_octo}"
        )
        print("   room: all scans into one tree, total time; ours best of 3 (in this process),")
        print("   OctoMap 1 run (the fresh process of part 3's memory measurement)")
        print(
            f"   {'case':<27} {'ours best':>9} {'median':>7} {'Mpts/s':>6} "
            f"{'octomap best':>12} {'median':>7} {'Mpts/s':>6} {'ratio':>6} {'(med)':>6} "
            f"{'target':>6}"
        )

        def row(
            name: str, n_pts: int, ours: Timing, octo: Timing | None, target: float | None
        ) -> None:
            line = (
                f"   {name:<27} {ours.best:9.3f} {ours.median:7.3f} {n_pts / ours.best / 1e6:6.2f} "
            )
            if octo is not None:
                ratio = octo.best / ours.best
                line += f"{octo.best:12.3f} {octo.median:7.3f} {n_pts / octo.best / 1e6:6.3f} "
                line += f"{ratio:6.1f} {octo.median / ours.median:6.1f}"
                if target is not None:
                    line += f" {'>=' + format(target, 'g'):>6} {verdict(ratio >= target)}"
                    summary.append((name, f"{ratio:.1f}x", f">= {target:g}x", ratio >= target))
            print(line, flush=True)

        for res, target in [(0.05, 40.0), (0.1, 20.0)]:
            keep_o: list[Any] = []
            keep_c: list[Any] = []
            ours = timed(functools.partial(build_ours, fr_scan, res), reps_ours, keep_o)
            octo = timed(functools.partial(build_octomap, fr_scan, res), reps_octo, keep_c)
            row(f"FR-079 {res:g} m", FR079_POINTS, ours, octo, target)
            with numba_threads(1):
                one = timed(functools.partial(build_ours, fr_scan, res), reps_ours)
            row(f"FR-079 {res:g} m, ours 1 thread", FR079_POINTS, one, octo, None)
            fr_trees[res] = (keep_o[0], keep_c[0])

        ours_room = timed(lambda: build_ours(room, 0.1), 3)
        for which in ("ours", "octomap"):
            memory[which, "room"] = measure_memory(which, room_data, 0.1)
        octo_room = Timing([memory["octomap", "room"]["seconds"]])
        row(f"room {n_room} scans 0.1 m", n_room_pts, ours_room, octo_room, 20.0)
        with numba_threads(1):
            one = timed(lambda: build_ours(room, 0.1), 2)
        row("room 0.1 m, ours 1 thread", n_room_pts, one, octo_room, None)
        estimate = 5.0 * octo_room.best  # on FR-079, 0.05 m costs OctoMap ~5x what 0.1 m does
        if estimate < 180.0:
            ours05 = timed(lambda: build_ours(room, 0.05), 3)
            octo05 = timed(lambda: build_octomap(room, 0.05), 1)
            row(f"room {n_room} scans 0.05 m", n_room_pts, ours05, octo05, 20.0)
        else:
            print(
                f"   room 0.05 m not run: OctoMap would take ~{estimate:.0f} s (5x its 0.1 m time, "
                "the FR-079 factor), over the ~3 minute budget"
            )
        # What the binding adds: insertPointCloud copies the points into an octomap::Pointcloud
        # row by row; with every point at the origin no ray is cast, leaving mostly that copy.
        at_origin = np.zeros_like(fr)
        bind = timed(lambda: octomap.OcTree(0.1).insertPointCloud(at_origin, np.zeros(3), -1.0), 3)
        print(
            f"   octomap-python's own overhead (88,206 points all at the origin, no rays): "
            f"{bind.best:.3f} s per scan, included in OctoMap's times"
        )

        print("   where ours spends its time (ms, minimum per stage over 3 fresh builds):")
        for res in (0.05, 0.1):
            st, tot = stage_profile(fr_scan, res, 3)
            print_stages(f"FR-079 {res:g} m", st, tot)
        st, tot = stage_profile(room, 0.1, 3)
        print_stages("room 0.1 m", st, tot)

    if 5 in parts:
        end_to_end(tmp, summary)

    if 2 in parts:
        ours_rate = endpoint_part(n_end, quick, summary)
        octomap_endpoints(n_end, ours_rate)

    if 3 in parts:
        # --- 3. memory ----------------------------------------------------------------------------
        print()
        print("3. Peak memory of a fresh process building the map: ru_maxrss after the build minus")
        print(
            "   ru_maxrss after imports, loading the points and warm-up ('peak+'); VmHWM the same"
        )
        print(
            "   way as a check ('HWM+'); VmRSS after minus before the build ('rss+'); 'own': ours"
        )
        print("   VoxelOctree.memory_bytes() (allocated capacity), OctoMap OcTree.memoryUsage()")
        print(
            f"   end points: {n_mem / 1e6:g} M uniform in part 2's 100 x 100 x 10 m box, "
            "insert_endpoints vs updateNodes(points, True)"
        )
        end_data = tmp / "endpoints.npy"
        np.save(end_data, endpoint_clouds(n_mem)[0][2].astype(np.float64))
        for which in ("ours", "octomap"):
            memory[which, "fr"] = measure_memory(which, fr_data, 0.05)
            if (which, "room") not in memory:  # measured in part 1 when it runs
                memory[which, "room"] = measure_memory(which, room_data, 0.1)
            memory[which, "end"] = measure_memory(f"{which}-endpoints", end_data, 0.1)
        print(
            f"   {'map':<23} {'lib':<8} {'base MB':>8} {'peak+ MB':>8} {'HWM+ MB':>8} "
            f"{'rss+ MB':>8} {'own MB':>8} {'build s':>7} {'ours/octo':>9} {'target':>6}"
        )
        maps = [
            ("fr", "FR-079 0.05 m"),
            ("room", f"room {n_room} scans 0.1 m"),
            ("end", f"end points {n_mem / 1e6:g} M 0.1 m"),
        ]
        for key, name in maps:
            got = {which: memory[which, key] for which in ("ours", "octomap")}
            grow = {w: (g["peak_kb"] - g["base_peak_kb"]) * 1024 for w, g in got.items()}
            for which, g in got.items():
                line = (
                    f"   {name:<23} {which:<8} {mb(g['base_peak_kb'] * 1024)} {mb(grow[which])} "
                    f"{mb((g['hwm_kb'] - g['base_hwm_kb']) * 1024)} "
                    f"{mb((g['rss_kb'] - g['base_rss_kb']) * 1024)} {mb(g['own_bytes'])} "
                    f"{g['seconds']:7.2f}"
                )
                if which == "octomap":
                    ratio = grow["ours"] / grow["octomap"]
                    own_ratio = got["ours"]["own_bytes"] / got["octomap"]["own_bytes"]
                    line += f" {ratio:9.2f} {'<=0.5':>6} {verdict(ratio <= 0.5)}"
                    line += f"  (own: {own_ratio:.2f})"
                    summary.append(
                        (f"peak memory {name}", f"{ratio:.2f}x", "<= 0.5x", ratio <= 0.5)
                    )
                print(line, flush=True)

    if 4 in parts:
        # --- 4. .bt files -------------------------------------------------------------------------
        print()
        print("4. .bt of the FR-079 0.05 m map: write_bt(occupied_and_free()) vs")
        print("   OcTree.writeBinary")
        if 0.05 not in fr_trees:
            fr_trees[0.05] = (build_ours(fr_scan, 0.05), build_octomap(fr_scan, 0.05))
        ours_tree, octo_tree = fr_trees[0.05]
        ours_bt, octo_bt = tmp / "ours.bt", tmp / "octomap.bt"

        def write_ours() -> None:
            keys, occ = ours_tree.occupied_and_free()
            write_bt(ours_bt, resolution=0.05, keys=keys, occupied=occ)

        keys, occ = ours_tree.occupied_and_free()
        t_ours = timed(write_ours, 3)
        t_enc = timed(lambda: write_bt(ours_bt, resolution=0.05, keys=keys, occupied=occ), 3)
        t_first = timed(lambda: octo_tree.writeBinary(os.fsencode(octo_bt)), 1)
        t_again = timed(lambda: octo_tree.writeBinary(os.fsencode(octo_bt)), 3)
        s_ours, s_octo = ours_bt.stat().st_size, octo_bt.stat().st_size
        same = ours_bt.read_bytes() == octo_bt.read_bytes()
        ratio = s_ours / s_octo
        print(f"   {'':<47} {'best s':>8} {'median':>8} {'bytes':>10}")
        print(f"   {'ours: occupied_and_free() + write_bt':<47} {t_ours} {s_ours:10d}")
        print(f"   {'ours: write_bt alone':<47} {t_enc}")
        print(f"   {'octomap: writeBinary, first call':<47} {t_first} {s_octo:10d}")
        print(f"   {'octomap: writeBinary again (tree already pruned)':<47} {t_again}")
        print(
            f"   size ours/octomap {ratio:.4f} (target within 1.05x) "
            f"{verdict(abs(ratio - 1) <= 0.05)}; identical bytes: {'yes' if same else 'NO'}; "
            f"{len(keys):,} known voxels, {int(occ.sum()):,} occupied"
        )
        print(
            f"   write time ours/octomap(first call) {t_ours.best / t_first.best:.2f}x "
            "(writeBinary's first call also runs toMaxLikelihood() and prune() on the tree)"
        )
        summary.append(
            ("FR-079 0.05 m .bt size", f"{ratio:.4f}x", "within 1.05x", abs(ratio - 1) <= 0.05)
        )

    print()
    print("Summary (ratios are best/best)")
    for name, value, wanted, ok in summary:
        print(f"   {name:<40} {value:>12} {wanted:>14}  {verdict(ok)}")
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    print(f"load average at end: {load}; total {time.perf_counter() - wall0:.0f} s")


if __name__ == "__main__":
    main()
