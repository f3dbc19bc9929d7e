"""Streamed, tiled rasterisation (stream.py) on one process and on Dask (issue 6).

The same generated LAS tiles go through: one pass (one task, one chunk, one tile), the streamed
path (many tasks, small chunks, small tiles), a Dask LocalCluster started by our code
(``--workers 2``) and one started by the test (``--scheduler``), also with a worker killed
mid-run; max, min, count and mean must be identical, cell for cell.
"""

from __future__ import annotations

import http.server
import itertools
import json
import os
import re
import signal
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import laspy  # type: ignore[import-untyped]
import numpy as np
import pytest

from scan2terrain.cli import main
from scan2terrain.commands import stream
from scan2terrain.commands.scans import _bag_hits
from scan2terrain.config import Config, StreamConfig, load_config
from scan2terrain.errors import InputError
from scan2terrain.grids.tiles import TileSet
from scan2terrain.readers.bag import open_bag
from tests.bagmaker import synthetic_room

FIELDS = ("max_z", "min_z", "mean_z", "count", "known")


def write_las_tiles(folder: Path, n_files: int, points_each: int, seed: int = 0) -> list[Path]:
    """Terrain-like LAS tiles side by side (UTM-like coordinates, so a local origin applies),
    overlapping a little, with a few points far above (birds) and a ground class."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    paths = []
    for i in range(n_files):
        x0 = 500_000.0 + 60.0 * i
        xy = rng.uniform([x0 - 2.0, 4_100_000.0], [x0 + 62.0, 4_100_050.0], (points_each, 2))
        z = 120.0 + 3.0 * np.sin(xy[:, 0] / 7.0) + 0.05 * rng.standard_normal(points_each)
        z[::500] += 40.0
        header = laspy.LasHeader(point_format=3, version="1.2")
        header.scales = np.array([0.001, 0.001, 0.001])
        header.offsets = np.array([500_000.0, 4_100_000.0, 0.0])
        las = laspy.LasData(header)
        las.x, las.y, las.z = xy[:, 0], xy[:, 1], z
        las.classification = np.where(np.arange(points_each) % 500 == 0, 1, 2).astype(np.uint8)
        path = folder / f"tile_{i:02d}.{'laz' if i % 2 else 'las'}"
        las.write(path)
        paths.append(path)
    return paths


def config(**stream_options: Any) -> Config:
    cfg = load_config(None, {"octree.resolution": 0.5, "octree.grid": "height"})
    cfg.stream = replace(StreamConfig(enabled=True), **stream_options)
    return cfg.validate()


def stats(tiles: TileSet) -> dict[str, Any]:
    s = tiles.column_stats()
    return {**{f: getattr(s, f) for f in FIELDS}, "origin": s.origin}


def assert_same_grid(a: dict[str, Any], b: dict[str, Any]) -> None:
    assert a["origin"] == b["origin"]
    for f in FIELDS:
        assert a[f].dtype == b[f].dtype, f
        assert np.array_equal(a[f], b[f], equal_nan=a[f].dtype.kind == "f"), f


@pytest.fixture(scope="module")
def las_tiles(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    return write_las_tiles(tmp_path_factory.mktemp("las"), 6, 20_000)


@pytest.fixture(scope="module")
def one_pass(las_tiles: list[Path]) -> dict[str, Any]:
    """Everything in one task, one chunk, one tile."""
    cfg = config(chunk_points=10**7, tile_cells=4096)
    _, job, _ = stream.plan_clouds(las_tiles, cfg)
    whole = TileSet(job.lattice)
    pts = np.concatenate([laspy.read(p).xyz for p in las_tiles]) - np.array(job.origin)
    whole.add_points(pts)
    return stats(whole)


def test_tiled_streamed_result_is_the_one_pass_result(
    las_tiles: list[Path], one_pass: dict[str, Any]
) -> None:
    cfg = config(chunk_points=1_500, tile_cells=16)
    chunks, _, notes = stream.plan_clouds(las_tiles, cfg)
    assert len(chunks) == 6 * 4  # 20,000 points a file in ranges of 4 x 1,500
    got = stream.stream_clouds(las_tiles, cfg)
    assert got.tiles.points == 6 * 20_000
    assert_same_grid(stats(got.tiles), one_pass)
    assert any("local origin (500180, 4100025, " in n for n in notes)


def test_dask_local_cluster_gives_the_same_grid(
    las_tiles: list[Path], one_pass: dict[str, Any]
) -> None:
    cfg = config(chunk_points=2_000, tile_cells=32, workers=2)
    got = stream.stream_clouds(las_tiles, cfg)
    assert_same_grid(stats(got.tiles), one_pass)


def test_killed_worker_loses_and_doubles_nothing(
    las_tiles: list[Path], one_pass: dict[str, Any]
) -> None:
    from dask.distributed import Client, LocalCluster

    with (
        LocalCluster(  # type: ignore[no-untyped-call]  # distributed has no annotations
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
        ) as cluster,
        Client(cluster) as client,  # type: ignore[no-untyped-call]
    ):
        cfg = config(chunk_points=200, tile_cells=8, scheduler=cluster.scheduler_address)
        chunks, _, _ = stream.plan_clouds(las_tiles, cfg)
        assert len(chunks) >= 60
        pids = client.run(os.getpid)
        killed: list[tuple[str, int]] = []

        def kill_one(done: int, total: int, points: int) -> None:
            if killed or done < 3:
                return
            busy = {w: n for w, n in client.processing().items() if n}
            victim = next(w for w in pids if busy.get(w))  # a worker with tasks in hand
            killed.append((victim, len(busy[victim])))
            os.kill(pids[victim], signal.SIGKILL)

        got = stream.stream_clouds(las_tiles, cfg, progress=kill_one)
    assert killed and killed[0][1] >= 1, "no worker was killed while it held tasks"
    assert got.tiles.points == 6 * 20_000
    assert_same_grid(stats(got.tiles), one_pass)


def test_single_process_path_never_imports_dask(las_tiles: list[Path]) -> None:
    code = textwrap.dedent(
        f"""
        import sys
        from scan2terrain.cli import main
        rc = main(["cloud2world", *{[str(p) for p in las_tiles[:2]]!r}, "-o", sys.argv[1],
                   "--stream", "--grid", "height", "--resolution", "1", "-q"])
        loaded = sorted(m for m in sys.modules if m.split(".")[0] in ("dask", "distributed"))
        print(rc, loaded)
        """
    )
    out = Path(las_tiles[0]).parent / "nodask"
    run = subprocess.run(
        [sys.executable, "-c", code, str(out)], capture_output=True, text=True, check=True
    )
    assert run.stdout.strip() == "0 []", run.stdout + run.stderr


def _peak_rss(files: list[Path], out: Path) -> int:
    code = textwrap.dedent(
        """
        import json, resource, sys
        from scan2terrain.cli import main
        rc = main(["cloud2world", *sys.argv[2:], "-o", sys.argv[1], "--stream", "--grid",
                   "height", "--resolution", "1", "--chunk-points", "50000", "-q",
                   "--simulator", "gz", "--no-preview"])
        print(json.dumps([rc, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss]))
        """
    )
    run = subprocess.run(
        [sys.executable, "-c", code, str(out), *map(str, files)],
        capture_output=True,
        text=True,
        check=True,
    )
    rc, kib = json.loads(run.stdout.strip().splitlines()[-1])
    assert rc == 0
    return int(kib)


def test_memory_stays_flat_when_the_input_grows_tenfold(tmp_path: Path) -> None:
    """The same 100 m x 50 m ground, once with 0.4 M points and once with 4 M: the grid is the
    same size, so peak memory must be too (holding 4 M points would add ~200 MB)."""
    small = write_las_tiles(tmp_path / "small", 2, 200_000, seed=1)
    large = write_las_tiles(tmp_path / "large", 2, 2_000_000, seed=2)
    peak_small = _peak_rss(small, tmp_path / "w1")
    peak_large = _peak_rss(large, tmp_path / "w2")
    assert peak_large <= 1.2 * peak_small, (peak_small, peak_large)


def test_bag_streamed_equals_its_hits_rasterised_on_one_process_and_on_dask(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    room = synthetic_room("cloud", n_scans=21, resolution=0.1)
    bag = room.write(tmp_path / "room.mcap", "mcap")
    monkeypatch.setattr(stream, "SCANS_PER_TASK", 4)  # time slices of ~4 scans
    cfg = config(chunk_points=5_000, tile_cells=16)
    cfg.octree.resolution = 0.1
    with open_bag([bag]) as b:
        hits, _ = _bag_hits(b, cfg)
    whole = TileSet(stream.lattice_for(cfg))
    whole.add_points(hits)
    local = stream.stream_bag([bag], cfg)
    assert any("streamed: 6 piece(s)" in n for n in local.notes)
    assert local.tiles.points == len(hits)
    assert_same_grid(stats(local.tiles), stats(whole))
    cfg.stream = replace(cfg.stream, workers=2)
    on_dask = stream.stream_bag([bag], cfg)
    assert_same_grid(stats(on_dask.tiles), stats(whole))


def test_time_slices_are_disjoint_and_cover_the_range() -> None:
    chunks = stream.plan_bag_chunks([Path("a.bag")], 1_000, 1_999, messages=1000)
    assert chunks[0].start_ns == 1_000 and chunks[-1].end_ns == 1_999
    for a, b in itertools.pairwise(chunks):
        assert b.start_ns == a.end_ns + 1
    assert len(stream.plan_bag_chunks([Path("a.bag")], 5, 5, messages=10**6)) == 1


# --- the command ------------------------------------------------------------------------------


def run_cli(capsys: pytest.CaptureFixture[str], *args: object) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_stream_and_workers_write_the_same_world(
    tmp_path: Path, las_tiles: list[Path], capsys: pytest.CaptureFixture[str]
) -> None:
    common = ["--grid", "height", "--resolution", "0.5", "--las-classes", "2"]
    code, out, err = run_cli(
        capsys, "cloud2world", *las_tiles, "-o", tmp_path / "a", "--stream", *common
    )
    assert code == 0, err
    assert "streamed: 6 piece(s) over 120,000 points" in out
    assert "points counted: 119,760" in out  # class 1 (every 500th point) dropped
    code, _, err = run_cli(
        capsys, "cloud2world", *las_tiles, "-o", tmp_path / "b", "--workers", "2", *common
    )
    assert code == 0, err
    for f in sorted((tmp_path / "a").rglob("*")):
        if f.is_file() and f.name != "scan2terrain.yaml":
            assert f.read_bytes() == (tmp_path / "b" / f.relative_to(tmp_path / "a")).read_bytes()


def test_stream_refuses_ray_casting(
    tmp_path: Path, las_tiles: list[Path], capsys: pytest.CaptureFixture[str]
) -> None:
    code, _, err = run_cli(
        capsys, "cloud2world", las_tiles[0], "-o", tmp_path / "w", "--stream", "--insert",
        "raycast",
    )  # fmt: skip
    assert code == 2
    assert "cannot be streamed or distributed" in err
    assert not (tmp_path / "w").exists()


def _truncated(tmp: Path, source: Path) -> Path:
    bad = tmp / "cut.las"
    data = source.read_bytes()
    bad.write_bytes(data[: len(data) * 2 // 3])
    return bad


@pytest.mark.parametrize("dask", [False, True])
def test_broken_file_one_line_exit_2_nothing_written(
    tmp_path: Path, las_tiles: list[Path], capsys: pytest.CaptureFixture[str], dask: bool
) -> None:
    las = next(p for p in las_tiles if p.suffix == ".las")
    laz = next(p for p in las_tiles if p.suffix == ".laz")
    cut_laz = tmp_path / "cut.laz"
    cut_laz.write_bytes(laz.read_bytes()[: laz.stat().st_size // 2])
    text = tmp_path / "notes.las"
    text.write_text("not a point cloud\n")
    extra = ["--workers", "2"] if dask else ["--stream"]
    for bad, why in (
        (_truncated(tmp_path, las), "truncated LAS file"),
        (cut_laz, "cannot read as LAS/LAZ|truncated"),
        (text, "cannot read as LAS/LAZ"),
        (tmp_path / "missing.las", "not found"),
    ):
        out = tmp_path / f"w_{bad.stem}"
        code, _, err = run_cli(capsys, "cloud2world", las, bad, "-o", out, *extra)
        assert code == 2, (bad, err)
        assert len(err.strip().splitlines()) == 1, err
        assert str(bad.name) in err and re.search(why, err), err
        assert not out.exists()
        assert not list(tmp_path.glob(".w_*"))


def test_unreachable_scheduler_is_a_clear_error(
    tmp_path: Path, las_tiles: list[Path], capsys: pytest.CaptureFixture[str]
) -> None:
    code, _, err = run_cli(
        capsys, "cloud2world", las_tiles[0], "-o", tmp_path / "w", "--scheduler",
        "tcp://127.0.0.1:9",
    )  # fmt: skip
    assert code == 2
    assert "tcp://127.0.0.1:9" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "w").exists()


def test_input_error_survives_the_trip_from_a_worker() -> None:
    import pickle

    err = pickle.loads(pickle.dumps(InputError(Path("/x/y.las"), "truncated")))
    assert isinstance(err, InputError)
    assert err.path == Path("/x/y.las") and err.problem == "truncated"


def test_bag2world_stream_writes_the_octree_end_points_map(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Laser hits on the room's walls lie 0.025 m off cell boundaries, so float32 (octree) and
    float64 (tiles) keys agree: the streamed map must be the octree's end-point map, pixel for
    pixel."""
    room = synthetic_room("tf", n_scans=12, resolution=0.1)
    bag = room.write(tmp_path / "room.bag", "ros1")
    common = ["--resolution", "0.1", "--simulator", "gz", "--no-preview", "--no-filter"]
    code, out, err = run_cli(
        capsys, "bag2world", bag, "-o", tmp_path / "s", "--stream", *common
    )  # fmt: skip
    assert code == 0, err
    assert "streamed: 1 piece(s) over 12 scan messages" in out
    code, _, err = run_cli(
        capsys, "bag2world", bag, "-o", tmp_path / "o", "--insert", "endpoints", *common
    )  # fmt: skip
    assert code == 0, err
    streamed = (tmp_path / "s" / "map" / "map.pgm").read_bytes()
    assert streamed == (tmp_path / "o" / "map" / "map.pgm").read_bytes()
    assert (tmp_path / "s" / "map" / "map_gz.yaml").read_bytes() == (
        tmp_path / "o" / "map" / "map_gz.yaml"
    ).read_bytes()


class _RangeHandler(http.server.SimpleHTTPRequestHandler):
    """Static files with single ``Range: bytes=a-b`` requests (fsspec reads by range)."""

    def log_message(self, *args: object) -> None:
        pass

    def do_GET(self) -> None:
        match = re.fullmatch(r"bytes=(\d+)-(\d*)", self.headers.get("Range", ""))
        path = Path(self.translate_path(self.path))
        if match is None or not path.is_file():
            super().do_GET()
            return
        data = path.read_bytes()
        a = int(match[1])
        b = min(int(match[2]) if match[2] else len(data) - 1, len(data) - 1)
        self.send_response(206)
        self.send_header("Content-Range", f"bytes {a}-{b}/{len(data)}")
        self.send_header("Content-Length", str(b - a + 1))
        self.send_header("Accept-Ranges", "bytes")
        self.end_headers()
        self.wfile.write(data[a : b + 1])


@pytest.fixture
def http_root(las_tiles: list[Path]) -> Iterator[str]:
    """The LAS tiles' folder served over HTTP on localhost."""
    import functools
    import threading

    handler = functools.partial(_RangeHandler, directory=str(las_tiles[0].parent))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()


def test_urls_are_read_by_the_workers(
    las_tiles: list[Path], one_pass: dict[str, Any], http_root: str
) -> None:
    urls = [f"{http_root}/{p.name}" for p in las_tiles]
    cfg = config(chunk_points=3_000, tile_cells=64, workers=2)
    got = stream.stream_clouds(urls, cfg)
    assert_same_grid(stats(got.tiles), one_pass)
    assert any(n.startswith("tile_00.las: 20,000 points") for n in got.notes)


def test_bad_urls_are_one_line_errors(
    tmp_path: Path, http_root: str, capsys: pytest.CaptureFixture[str]
) -> None:
    for url, why in (
        (f"{http_root}/missing.laz", "cannot open the URL|cannot read"),
        (f"{http_root}/tile_00.las?x=1", None),  # a query is fine
        (f"{http_root}/notes.pcd", "LAS/LAZ files only"),
    ):
        out = tmp_path / f"w{len(why or '')}"
        code, _, err = run_cli(
            capsys, "cloud2world", url, "-o", out, "--stream", "--grid", "height",
            "--resolution", "2",
        )  # fmt: skip
        if why is None:
            assert code == 0, err
            continue
        assert code == 2, err
        assert url in err and re.search(why, err) and len(err.strip().splitlines()) == 1, err
        assert not out.exists()
    code, _, err = run_cli(capsys, "cloud2world", f"{http_root}/tile_00.las", "-o", tmp_path / "x")
    assert code == 2 and "URLs are read with --stream" in err
