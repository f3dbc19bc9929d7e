"""Issue 31: uncompressed LAS read without laspy (readers/_las_plain.py) gives exactly laspy's
points, classes and header values, and refuses a broken file with the message laspy's path
gives; the streamed path's threaded binning gives the same records on any number of threads.
"""

from __future__ import annotations

import os
import struct
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import laspy  # type: ignore[import-untyped]
import numpy as np
import pytest

from scan2terrain.errors import InputError
from scan2terrain.grids import tiles as tiles_module
from scan2terrain.grids.tiles import Lattice, TileSet
from scan2terrain.readers import las
from scan2terrain.readers._las_plain import PlainLas, plain_header, read_records
from scan2terrain.readers.cloudfile import read_cloud
from scan2terrain.readers.las import iter_las, las_info
from tests.fixtures import AUTZEN, ROOT, SIMPLE_LAS, SIMPLE_LAZ

#: (point format, LAS version) laspy writes, every point format in the oldest version it has.
FORMATS = [(0, "1.2"), (1, "1.2"), (2, "1.2"), (3, "1.2"), (4, "1.3"), (5, "1.3")]
FORMATS += [(f, "1.4") for f in range(6, 11)] + [(0, "1.4"), (3, "1.4")]


def write_las(path: Path, fmt: int, version: str, n: int = 3001, *, extra: bool = False) -> Path:
    rng = np.random.default_rng(fmt)
    header = laspy.LasHeader(point_format=fmt, version=version)
    header.scales = np.array([0.001, 0.002, 0.0005])
    header.offsets = np.array([500_000.0, 4_100_000.0, -20.0])
    if extra:
        header.add_extra_dim(laspy.ExtraBytesParams(name="height", type=np.float32))
    data = laspy.LasData(header)
    data.x = rng.uniform(500_000, 500_300, n)
    data.y = rng.uniform(4_100_000, 4_100_200, n)
    data.z = rng.uniform(-10, 90, n)
    data.classification = rng.integers(0, 19 if fmt <= 5 else 200, n).astype(np.uint8)
    data.write(path)
    return path


def laspy_xyz(path: Path) -> tuple[np.ndarray[Any, Any], np.ndarray[Any, Any]]:
    data = laspy.read(path)
    return np.asarray(data.xyz), np.asarray(data.classification)


def plain_of(path: Path) -> PlainLas | None:
    with path.open("rb") as f:
        return plain_header(f)


def concat(parts: Iterator[np.ndarray[Any, Any]]) -> np.ndarray[Any, Any]:
    return np.concatenate([np.zeros((0, 3)), *parts])


@pytest.fixture(scope="module")
def las_files(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    folder = tmp_path_factory.mktemp("plain")
    files = [write_las(folder / f"f{f}_{v}.las", f, v) for f, v in FORMATS]
    return [SIMPLE_LAS, *files]


def test_plain_files_are_read_without_laspy_exactly_as_laspy_reads_them(
    las_files: list[Path],
) -> None:
    for path in las_files:
        plain = plain_of(path)
        assert plain is not None, path  # the fast path is the one tested
        xyz, codes = laspy_xyz(path)
        with laspy.open(path) as reader:
            h = reader.header
        assert plain.count == h.point_count == len(xyz)
        assert np.array_equal(plain.scales, h.scales) and np.array_equal(plain.offsets, h.offsets)
        info = las_info(path)
        assert (info.points, info.mins, info.maxs) == (
            h.point_count,
            tuple(map(float, h.mins)),
            tuple(map(float, h.maxs)),
        )
        assert (
            info.format
            == f"las {h.version.major}.{h.version.minor} point format {h.point_format.id}"
        )
        origin = np.array([500_100.0, 4_100_100.0, 3.0])
        # Whole, in odd steps, from within, less an origin: the same floats, bit for bit.
        assert np.array_equal(concat(iter_las(path)), xyz)
        assert np.array_equal(concat(iter_las(path, step=997, origin=origin)), xyz - origin)
        assert np.array_equal(concat(iter_las(path, start=13, count=1500, step=600)), xyz[13:1513])
        assert np.array_equal(read_cloud(path).points, xyz)
        wanted = sorted({int(c) for c in codes[:40]})[:3]
        keep = np.isin(codes, wanted)
        assert np.array_equal(concat(iter_las(path, las_classes=wanted, step=700)), xyz[keep])
        assert np.array_equal(read_cloud(path, las_classes=wanted).points, xyz[keep])
        with path.open("rb") as f:
            first = next(read_records(f, plain, path, 0, 50, 50))
        assert np.array_equal(plain.classes(first), codes[:50])


def test_laz_and_irregular_headers_are_left_to_laspy_with_the_same_points(tmp_path: Path) -> None:
    extra = write_las(tmp_path / "extra.las", 3, "1.4", extra=True)  # an extra-bytes VLR
    for path in (SIMPLE_LAZ, AUTZEN, extra):
        assert plain_of(path) is None, path
        xyz, _ = laspy_xyz(path)
        assert np.array_equal(concat(iter_las(path, step=5000)), xyz)
        assert np.array_equal(read_cloud(path).points, xyz)


def test_classes_absent_name_the_classes_present_as_before(
    las_files: list[Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    path = las_files[1]
    with pytest.raises(InputError) as fast:
        read_cloud(path, las_classes=[250])
    monkeypatch.setattr(las, "plain_header", lambda f: None)  # laspy's path
    with pytest.raises(InputError) as slow:
        read_cloud(path, las_classes=[250])
    assert str(fast.value) == str(slow.value)
    assert "classes present: 0, 1, 2" in str(fast.value)


def patched(src: Path, out: Path, *edits: tuple[int, str, int]) -> Path:
    data = bytearray(src.read_bytes())
    for offset, fmt, value in edits:
        struct.pack_into(fmt, data, offset, value)
    out.write_bytes(bytes(data))
    return out


def broken_files(tmp: Path) -> list[Path]:
    """Cut, absurd counts and offsets, short records and VLRs that overrun the points."""
    raw = SIMPLE_LAS.read_bytes()  # 1065 points of 34 bytes from byte 1220... (its header says)
    start = struct.unpack_from("<I", raw, 96)[0]
    files = [tmp / "cut_mid_record.las", tmp / "cut_at_start.las"]
    files[0].write_bytes(raw[: start + 34 * 500 + 7])
    files[1].write_bytes(raw[:start])
    files += [
        patched(SIMPLE_LAS, tmp / "count_max.las", (107, "<I", 0xFFFFFFFF)),
        patched(SIMPLE_LAS, tmp / "count_plus_one.las", (107, "<I", 1066)),
        patched(SIMPLE_LAS, tmp / "offset_past_end.las", (96, "<I", 0xFFFFFFF0)),
        patched(SIMPLE_LAS, tmp / "offset_in_header.las", (96, "<I", 100)),
        patched(SIMPLE_LAS, tmp / "offset_in_vlrs.las", (96, "<I", start - 30)),
        patched(SIMPLE_LAS, tmp / "record_short.las", (105, "<H", 20)),
        patched(SIMPLE_LAS, tmp / "header_size_small.las", (94, "<H", 200)),
        patched(SIMPLE_LAS, tmp / "vlrs_max.las", (100, "<I", 0xFFFFFFFF)),
        patched(SIMPLE_LAS, tmp / "version.las", (24, "<B", 2)),
    ]
    return files


ENTRIES: dict[str, Callable[[Path], object]] = {
    "read_cloud": read_cloud,
    "las_info": las_info,
    "iter_las": lambda p: list(iter_las(p)),
    "iter_las_range": lambda p: list(iter_las(p, start=1000, count=60, step=7)),
}


def outcome(read: Callable[[Path], object], path: Path) -> str:
    try:
        read(path)
    except InputError as exc:
        return f"refused: {exc}"
    return "read"


def test_broken_files_are_refused_as_laspy_s_path_refuses_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    files = broken_files(tmp_path)
    fast = {(f.name, e): outcome(r, f) for f in files for e, r in ENTRIES.items()}
    monkeypatch.setattr(las, "plain_header", lambda f: None)
    slow = {(f.name, e): outcome(r, f) for f in files for e, r in ENTRIES.items()}
    assert fast == slow
    for (name, entry), seen in fast.items():
        if name == "version.las" or (name == "count_plus_one.las" and entry != "read_cloud"):
            continue  # read by laspy as before; the bigger count is refused by what reads it all
        assert seen.startswith(f"refused: {tmp_path / name}: "), (name, entry, seen)
    assert "truncated LAS file" in fast[("cut_mid_record.las", "iter_las")]
    assert "truncated LAS file" in fast[("count_max.las", "las_info")]


def test_a_file_cut_while_it_is_read_is_an_input_error(tmp_path: Path) -> None:
    path = tmp_path / "shrinks.las"
    path.write_bytes(SIMPLE_LAS.read_bytes())
    plain = plain_of(path)
    assert plain is not None
    with path.open("rb") as f:
        records = read_records(f, plain, path, 0, plain.count, 400)
        next(records)
        os.truncate(path, plain.start + plain.record * 700 + 5)  # after the header was checked
        with pytest.raises(InputError, match=r"truncated LAS file: .* ends within point 700"):
            list(records)


def test_cli_refuses_a_cut_las_file_with_one_line_exit_2(tmp_path: Path) -> None:
    cut = broken_files(tmp_path)[0]
    for extra in ([], ["--stream"]):
        out = tmp_path / f"world{len(extra)}"
        done = subprocess.run(
            [sys.executable, "-m", "scan2terrain", "cloud2world", str(cut), "-o", str(out),
             "--resolution", "0.5", *extra],
            capture_output=True, text=True, cwd=ROOT, check=False,
        )  # fmt: skip
        assert done.returncode == 2, done.stderr
        lines = done.stderr.strip().splitlines()
        assert len(lines) == 1 and str(cut) in lines[0] and "truncated LAS file" in lines[0]
        assert not out.exists()


# --- threads ----------------------------------------------------------------------------------


def records_of(tiles: TileSet) -> list[np.ndarray[Any, Any]]:
    r = tiles.records()
    return [r.tiles, r.ends, r.cell, r.records]


@pytest.mark.parametrize(
    "lattice", [Lattice(0.5), Lattice(0.1, 64, z_min=-1.0, z_max=1.0), Lattice(0.5, 1)]
)
def test_threaded_binning_gives_the_same_records_as_one_thread(
    lattice: Lattice, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(tiles_module, "_PIECE", 200_000)  # chunks binned in pieces too
    rng = np.random.default_rng(3)
    points = rng.uniform(-150, 150, (700_001, 3))
    points[::7, 2] *= 0.01  # many in the z band
    points[5] = np.nan
    points[10:20] = points[30]  # one cell many times
    sets = [TileSet(lattice, threads=t) for t in (1, 2, 3)]
    for s in range(0, len(points), 300_000):  # chunks that grow the tiles, some in the band
        for tiles in sets:
            tiles.add_points(points[s : s + 300_000])
    one = records_of(sets[0])
    assert one[3].shape[0] > 1000
    for tiles in sets[1:]:
        assert all(np.array_equal(a, b) for a, b in zip(one, records_of(tiles), strict=True))


def test_stream_writes_the_same_bytes_on_one_and_two_threads(tmp_path: Path) -> None:
    files = [write_las(tmp_path / f"t{i}.las", 0, "1.2", n=400_000) for i in range(2)]
    worlds = []
    for threads in ("1", "2"):
        out = tmp_path / f"world{threads}"
        subprocess.run(
            [sys.executable, "-m", "scan2terrain", "cloud2world", *map(str, files), "-o",
             str(out), "--resolution", "0.5", "--stream"],
            check=True, capture_output=True, cwd=ROOT,
            env={**os.environ, "NUMBA_NUM_THREADS": threads},
        )  # fmt: skip
        worlds.append({p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()})
    assert worlds[0].keys() == worlds[1].keys() and len(worlds[0]) > 3
    assert worlds[0] == worlds[1]
