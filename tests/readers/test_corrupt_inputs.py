"""Issue 12: corrupt files the readers once crashed on (an abort, an exit 1, the OOM killer, a
world built from garbage) are refused with an InputError naming the file.

The cases that once aborted or ate all memory run in a fresh Python under an address-space
limit (:func:`isolated`), so a regression fails the test instead of killing the session.
tests/test_mutations.py runs many more such mutations through the real commands.
"""

from __future__ import annotations

import io
import json
import re
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from scan2terrain.errors import InputError
from scan2terrain.readers.cloudfile import read_cloud
from tests.fixtures import (
    AUTZEN,
    CCNY,
    EMBARK_MCAP,
    MOON,
    ROOT,
    SICK_DB3,
    SIMPLE_LAS,
    SIMPLE_LAZ,
)

#: In simple.laz (1065 points, one chunk of LASzip's 50,000): the points start at 333 (the
#: int64 offset to the chunk table), the table at 18203 (uint32 version, uint32 count).
LAZ_START, LAZ_TABLE = 333, 18203
LAZ_CHUNK_SIZE = 227 + 54 + 12  # the laszip VLR's chunk size field


def isolated(code: str, limit: int = 2 << 30) -> list[str]:
    """Run ``code`` in a fresh Python with at most ``limit`` bytes of address space and return
    its output lines; fail on an abort, a signal or an exception."""

    limits = (
        "import resource\n"
        f"resource.setrlimit(resource.RLIMIT_AS, ({limit}, {limit}))\n"
        "resource.setrlimit(resource.RLIMIT_CORE, (0, 0))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", limits + code],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
        check=False,
    )
    assert done.returncode == 0, f"exit {done.returncode}: {done.stderr[-2000:]}"
    return done.stdout.splitlines()


READ_EACH = """
import json
import re
from scan2terrain.errors import InputError
from scan2terrain.readers.cloudfile import read_cloud
from scan2terrain.readers.las import iter_las, las_info
for path in json.loads({paths!r}):
    for name, read in (("read_cloud", read_cloud), ("las_info", las_info),
                       ("iter_las", lambda p: list(iter_las(p)))):
        try:
            read(path)
            print(json.dumps([path, name, "read"]))
        except InputError as exc:
            print(json.dumps([path, name, str(exc)]))
"""


def refusals(paths: list[Path]) -> dict[tuple[str, str], str]:
    """(file name, entry point) -> the InputError message (or "read"), for every LAS/LAZ entry
    point (read_cloud, las_info, iter_las) on every file, run isolated."""
    lines = isolated(READ_EACH.format(paths=json.dumps([str(p) for p in paths])))
    return {(Path(p).name, name): message for p, name, message in map(json.loads, lines)}


def patched(src: Path, tmp: Path, name: str, *edits: tuple[int, str, int]) -> Path:
    data = bytearray(src.read_bytes())
    for offset, fmt, value in edits:
        struct.pack_into(fmt, data, offset, value)
    out = tmp / name
    out.write_bytes(bytes(data))
    return out


# --- LAZ chunk table: lazrs allocated it by its count and aborted the process -------------------


def test_laz_chunk_table_corruption_is_refused_by_every_entry_point(tmp_path: Path) -> None:
    files = [
        # number_of_chunks garbage: "memory allocation of 54216186304 bytes failed", SIGABRT
        patched(SIMPLE_LAZ, tmp_path, "chunks.laz", (LAZ_TABLE + 4, "<I", 0xC9FFFFFF)),
        patched(SIMPLE_LAZ, tmp_path, "chunks_max.laz", (LAZ_TABLE + 4, "<I", 0xFFFFFFFF)),
        # the table offset pointing into the point data: a garbage count there
        patched(SIMPLE_LAZ, tmp_path, "inside.laz", (LAZ_START, "<q", LAZ_START + 100)),
        # chunk size 1: 1065 chunks expected, pyo3's PanicException "capacity overflow"
        patched(SIMPLE_LAZ, tmp_path, "chunk_size.laz", (LAZ_CHUNK_SIZE, "<I", 1)),
        # random bytes spliced into the table
        tmp_path / "spliced.laz",
    ]
    raw = SIMPLE_LAZ.read_bytes()
    files[-1].write_bytes(raw[:-6] + b"\x93\xfe\x17\x00\x88" + raw[-6:])
    seen = refusals(files)
    for f in files:
        for entry in ("read_cloud", "las_info", "iter_las"):
            message = seen[(f.name, entry)]
            assert message.startswith(f"{f}: corrupt LAZ file: "), (entry, message)
    assert (
        "4,294,967,295 chunks, 1,065 points in chunks of 50,000 make 1"
        in (seen[("chunks_max.laz", "read_cloud")])
    )


def test_laz_chunk_table_checks_pass_real_files(tmp_path: Path) -> None:
    """LASzip's own files (one chunk; several chunks) and lazrs' (point format 6, layered)."""
    import laspy  # type: ignore[import-untyped]

    autzen = AUTZEN
    assert len(read_cloud(autzen).points) == 110_000
    assert len(read_cloud(SIMPLE_LAZ).points) == 1065
    path = tmp_path / "f6.laz"
    path.write_bytes(_format6_laz(120_000))  # three chunks
    assert len(read_cloud(path).points) == 120_000
    assert laspy.read(path).header.point_count == 120_000


def _format6_laz(n: int) -> bytes:
    import laspy

    rng = np.random.default_rng(0)
    las = laspy.LasData(laspy.LasHeader(point_format=6, version="1.4"))
    las.header.scales = np.full(3, 0.001)
    pts = rng.uniform(0, 50, size=(n, 3))
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    out = io.BytesIO()
    las.write(out, do_compress=True)
    return out.getvalue()


def test_laz_layer_size_beyond_its_chunk_is_refused(tmp_path: Path) -> None:
    """Point formats 6-10 (LASzip's layered chunks): each chunk lists its layers' sizes, and
    lazrs allocated a corrupt 4 GB one (SIGABRT under a memory limit)."""
    data = _format6_laz(500)
    start = struct.unpack_from("<I", data, 96)[0]
    good = tmp_path / "good.laz"
    good.write_bytes(data)
    # after the chunk's raw 30-byte first point and its uint32 point count: 9 layer sizes
    bad = patched(good, tmp_path, "layer.laz", (start + 8 + 30 + 4 + 8, "<I", 0xFFFFFFF0))
    seen = refusals([good, bad])
    assert all(seen[("good.laz", e)] == "read" for e in ("read_cloud", "las_info", "iter_las"))
    assert "chunk 0 (" in seen[("layer.laz", "read_cloud")]
    assert "has layers of 4,29" in seen[("layer.laz", "iter_las")]
    assert seen[("layer.laz", "las_info")] == "read"  # the header alone is fine


def test_a_rust_panic_in_lazrs_is_an_input_error(monkeypatch: pytest.MonkeyPatch) -> None:
    """pyo3's PanicException is a BaseException: the backstop turns it into an InputError and
    lets every other BaseException through."""
    import laspy

    class PanicException(BaseException):  # pyo3's name
        pass

    def panics(*_: object, **__: object) -> None:
        raise PanicException("capacity overflow")

    monkeypatch.setattr(laspy, "open", panics)
    with pytest.raises(InputError, match="corrupt LAZ data \\(lazrs failed: capacity overflow"):
        read_cloud(SIMPLE_LAZ)

    def interrupted(*_: object, **__: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(laspy, "open", interrupted)
    with pytest.raises(KeyboardInterrupt):
        read_cloud(SIMPLE_LAZ)


# --- header counts: refused by the file's size before anything allocates by them ----------------


def test_header_counts_beyond_the_file_are_refused_before_allocating(tmp_path: Path) -> None:
    """Each of these once took gigabytes (MemoryError, exit 1; SIGKILL by the OOM killer without
    a limit), or 45 s of laspy reading 2^32 VLRs; isolated under a 1 GiB limit."""
    files = [
        patched(SIMPLE_LAS, tmp_path, "vlrs.las", (100, "<I", 0xFFFFFFFF)),
        patched(SIMPLE_LAS, tmp_path, "offset.las", (96, "<I", 0xFFFFFFFF)),
        patched(SIMPLE_LAS, tmp_path, "points.las", (107, "<I", 0xFFFFFFFF)),
        patched(SIMPLE_LAZ, tmp_path, "points.laz", (107, "<I", 0xFFFFFFFF)),
        patched(SIMPLE_LAZ, tmp_path, "vlrs.laz", (100, "<I", 0x7FFFFFFF)),
    ]
    seen = refusals(files)
    assert seen[("vlrs.las", "read_cloud")].endswith(
        "corrupt LAS header: 4,294,967,295 VLRs cannot fit in the 0 bytes between the header "
        "and the points"
    )
    assert (
        "its points start at byte 4294967295, the file has 36437"
        in (seen[("offset.las", "las_info")])
    )
    assert (
        "truncated LAS file: 4294967295 points of 34 bytes need"
        in (seen[("points.las", "iter_las")])
    )
    assert (
        "4,294,967,295 points in chunks of 50,000 make 85,900" in (seen[("points.laz", "las_info")])
    )
    assert all(m != "read" for m in seen.values())


def test_huge_ply_vertex_count_is_refused_before_numpy_sizes_a_table(tmp_path: Path) -> None:
    """numpy.loadtxt(max_rows=count) allocated the header's count: 96 GiB (MemoryError)."""
    path = tmp_path / "a.ply"
    path.write_bytes(
        b"ply\nformat ascii 1.0\nelement vertex 4294967297\nproperty float x\n"
        b"property float y\nproperty float z\nend_header\n1 2 3\n4 5 6\n"
    )
    with pytest.raises(InputError, match="truncated: PLY header says 4294967297 vertices"):
        read_cloud(path)


# --- PLY through Open3D (list properties): a short file gave garbage points and exit 0 ---------


def _ply_with_lists(fmt: str) -> bytes:
    head = (
        f"ply\nformat {fmt} 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
        "property float z\nproperty list uchar float extra\nend_header\n"
    ).encode()
    if fmt == "ascii":
        return head + b"1 2 3 0\n4 5 6 2 7 8\n9 10 11 1 12\n13 14 15 0\n"
    rows = [(1, 2, 3, []), (4, 5, 6, [7, 8]), (9, 10, 11, [12]), (13, 14, 15, [])]
    body = b"".join(
        struct.pack("<3fB", x, y, z, len(e)) + struct.pack(f"<{len(e)}f", *e) for x, y, z, e in rows
    )
    return head + body


@pytest.mark.parametrize("fmt", ["binary_little_endian", "ascii"])
def test_ply_with_list_properties_reads_and_refuses_every_truncation(
    tmp_path: Path, fmt: str
) -> None:
    data = _ply_with_lists(fmt)
    path = tmp_path / "l.ply"
    path.write_bytes(data)
    np.testing.assert_array_equal(
        read_cloud(path).points, [[1, 2, 3], [4, 5, 6], [9, 10, 11], [13, 14, 15]]
    )
    start = data.index(b"end_header\n") + len(b"end_header\n")
    last = len(data) - (2 if fmt == "ascii" else 1)  # an ASCII file may lose its last newline
    for cut in range(start, last):
        path.write_bytes(data[:cut])
        with pytest.raises(InputError, match="truncated") as info:
            read_cloud(path)
        assert info.value.path == path, cut


def test_rply_complaint_is_a_refusal(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    """Long enough for the header's counts with empty lists, short for the lists it has: RPly
    prints "Error reading ..." and Open3D returns uninitialised points; now an InputError from
    the walk over the rows (issue 28), and nothing is printed."""
    data = _ply_with_lists("binary_little_endian")
    path = tmp_path / "l.ply"
    path.write_bytes(data[:-8])
    with pytest.raises(InputError, match=r"truncated: the data ends in row \d+ of element vertex"):
        read_cloud(path)
    assert capfd.readouterr().err == ""


def test_unknown_list_types_are_refused_in_the_header(tmp_path: Path) -> None:
    path = tmp_path / "l.ply"
    path.write_bytes(_ply_with_lists("ascii").replace(b"list uchar", b"list float"))
    with pytest.raises(InputError, match="PLY header: cannot read the line 'property list float"):
        read_cloud(path)


def test_signalling_nan_in_a_binary_pcd_is_dropped_without_a_warning(tmp_path: Path) -> None:
    pts = struct.pack("<6f", 1, 2, 3, 4, 5, 6) + struct.pack("<I", 0x7FA00000) + bytes(8)
    head = (
        "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 3\nHEIGHT 1\n"
        "POINTS 3\nDATA binary\n"
    )
    path = tmp_path / "s.pcd"
    path.write_bytes(head.encode() + pts)
    cloud = read_cloud(path)  # pytest's -W error turns the old RuntimeWarning into a failure
    assert cloud.records == 3 and len(cloud.points) == 2


# --- other readers -------------------------------------------------------------------------------


def test_map_yaml_numbers_in_exponent_form_are_read(tmp_path: Path) -> None:
    """YAML 1.1 (PyYAML) reads 5e-2 as a string; map_server (yaml-cpp) as 0.05."""
    from scan2terrain.readers.mapserver import read_map_yaml
    from tests.conftest import write_map

    pixels = np.full((4, 5), 254, dtype=np.uint8)
    path = write_map(tmp_path, pixels, resolution=0.1)
    path.write_text(path.read_text().replace("resolution: 0.1", "resolution: 5e-2"))
    meta, grid = read_map_yaml(path)
    assert meta.resolution == grid.resolution == 0.05


@pytest.mark.parametrize(
    ("origin", "resolution", "message"),
    [
        ("[1e308, -1e308, 0]", "0.1", "origin x = 1e\\+308 m makes no sense"),  # was exit 1
        ("[0, 0, 0]", "1.0e300", "resolution = 1e\\+300 m makes no sense"),
        ("[2e4, 0, 0]", "1.0e-6", "more than 1e\\+09 m or 2\\^34 of its 1e-06 m cells"),
    ],
)
def test_map_too_far_for_its_cells_is_refused(
    tmp_path: Path, origin: str, resolution: str, message: str
) -> None:
    from scan2terrain.readers.mapserver import read_map_yaml
    from tests.conftest import write_map

    path = write_map(tmp_path, np.full((3, 4), 254, dtype=np.uint8), origin=origin)
    path.write_text(path.read_text().replace("resolution: 0.1", f"resolution: {resolution}"))
    with pytest.raises(InputError, match=message) as info:
        read_map_yaml(path)
    assert info.value.path == path


def test_utm_placed_map_is_read(tmp_path: Path) -> None:
    from scan2terrain.readers.mapserver import read_map_yaml
    from tests.conftest import write_map

    path = write_map(tmp_path, np.full((3, 4), 254, np.uint8), origin="[500000.0, 5e6, 0.3]")
    assert read_map_yaml(path)[1].origin.y == 5e6


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("inf 0 0", "line 3: point 'inf 0 0' is not a finite float32"),
        ("nan nan nan", "line 3: point 'nan nan nan' is not a finite float32"),
        ("1e300 0 0", "line 3: point '1e300 0 0' is not a finite float32"),
    ],
)
def test_octomap_scan_points_beyond_float32_are_refused(
    tmp_path: Path, line: str, message: str
) -> None:
    """They were warnings ("overflow encountered in cast") and a world built without them."""
    from scan2terrain.readers.octomap_scan import read_scans

    path = tmp_path / "scan.dat"
    path.write_text(f"NODE 0 0 0 0 0 0\n1 2 3\n{line}\n4 5 6\n")
    with pytest.raises(InputError, match=message):
        list(read_scans(path))


def test_pointcloud2_point_step_beyond_numpy_is_refused() -> None:
    from types import SimpleNamespace

    from scan2terrain.readers.pointcloud2 import pointcloud2_xyz

    fields = [
        SimpleNamespace(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate("xyz")
    ]
    msg = SimpleNamespace(
        height=1,
        width=2,
        fields=fields,
        is_bigendian=False,
        point_step=0xFFFFFFFF,
        row_step=0,
        data=bytes(24),
    )
    with pytest.raises(InputError, match="point_step 4294967295 is not a point's size"):
        pointcloud2_xyz(msg)


def test_dem_pixel_scale_that_resamples_beyond_the_limit_names_the_file(tmp_path: Path) -> None:
    """A pixel scale of 1e300 was refused by the pipeline without naming the file; it is now
    refused as a pixel size, before any resampling (issue 28)."""
    import shutil

    from scan2terrain.readers.dem import read_dem

    src = MOON
    path = tmp_path / "dem.tif"
    shutil.copyfile(src, path)
    data = bytearray(path.read_bytes())
    ifd = struct.unpack_from("<I", data, 4)[0]
    for i in range(struct.unpack_from("<H", data, ifd)[0]):
        entry = ifd + 2 + 12 * i
        if struct.unpack_from("<H", data, entry)[0] == 33550:  # ModelPixelScale
            struct.pack_into("<d", data, struct.unpack_from("<I", data, entry + 8)[0], 1e300)
    path.write_bytes(bytes(data))
    with pytest.raises(InputError, match=r"ModelPixelScale pixel width = 1e\+300 m") as info:
        read_dem(path)
    assert info.value.path == path


def test_bag_errors_stay_one_short_line() -> None:
    from rosbags.rosbag1 import ReaderError

    from scan2terrain.readers._bag_errors import explain

    text = explain(UnicodeDecodeError("utf-8", b"x" * 5000 + b"\xff", 5000, 5001, "bad"))
    assert text == "the bag is damaged: it holds text (a name or a definition) that is not UTF-8"
    # rosbags' own sentences are quoted, on one short line; Python's texts are not shown.
    assert explain(ReaderError("Could not parse:\n'MSG: a\nb'")) == (
        "cannot read the bag (rosbags: \"Could not parse: 'MSG: a b'\")"
    )
    assert len(explain(ReaderError("x" * 5000))) < 300
    assert explain(ValueError("x" * 5000), storage="mcap") == (
        "the MCAP file is truncated or damaged: rosbags cannot parse it (-v shows where it fails)"
    )
    assert "corrupt length field" in explain(MemoryError())


# --- bags cut to a few bytes: one sentence of ours, never a library's words (issue 25 item 12) ----

#: Layout -> (the fixture whose storage file is cut, the storage file's suffix).
CUT_BAGS = {
    "bag file": (CCNY, ".bag"),
    "mcap file": (EMBARK_MCAP, ".mcap"),
    "db3 file": (SICK_DB3, ".db3"),
    "mcap folder": (EMBARK_MCAP, ".mcap"),
    "db3 folder": (SICK_DB3, ".db3"),
}
MAGIC_ONLY = {
    ".bag": [
        b"#ROSBAG V2.0",
        b"#ROSBAG V2.0\n",
        b"#ROSBAG V2.0\n" * 2,
        b"#ROSBAG V2.0\n" + bytes(4096),
    ],
    ".mcap": [b"\x89MCA", b"\x89MCAP0\r\n", b"\x89MCAP0\r\n" * 2, b"\x89MCAP0\r\n" + bytes(100)],
    ".db3": [b"SQLite format 3\x00", b"SQLite format 3\x00" + bytes(84)],
}
#: How every refusal of such a file begins: sentences written here, not a library's.
OUR_SENTENCES = (
    "the file is empty, not a bag",
    "this is a text file, not a ROS bag",
    "not a ROS bag (expected",
    "unsupported ROS1 bag version",
    "the bag's index is missing or damaged",
    "the ROS1 bag is truncated or damaged",
    "the ROS1 bag is damaged",
    "the MCAP file is empty",
    "the MCAP file is truncated or damaged",
    "the MCAP file is damaged",
    "the sqlite3 file is empty",
    "the sqlite3 file is truncated or damaged",
)
#: What Python or a library says that a user should never read: exception names, builtins'
#: complaints (ord(), struct.unpack), rosbags' own sentences.
RAW = re.compile(
    r"[A-Za-z]+Error\b|ord\(\)|unpack requires|expected a character|KeyError|"
    r"File magic is invalid|Truncated record|Unexpected record|seems to be empty|"
    r"Cannot open database|Could not read|Header field"
)


def _cut_bag(layout: str, blob: bytes, where: Path) -> Path:
    src, suffix = CUT_BAGS[layout]
    storage = src if src.is_file() else next(src.glob(f"*{suffix}"))
    where.mkdir()
    if layout.endswith("file"):
        path = where / f"x{suffix}"
        path.write_bytes(blob)
        return path
    (where / "metadata.yaml").write_bytes((src / "metadata.yaml").read_bytes())
    (where / storage.name).write_bytes(blob)
    return where


@pytest.mark.parametrize("layout", sorted(CUT_BAGS))
def test_a_bag_cut_to_a_few_bytes_is_one_sentence_of_ours(tmp_path: Path, layout: str) -> None:
    """Every prefix of 0..64 bytes, and files of little more than the format's magic: refused
    with one of our sentences naming the file. An 8-byte MCAP file said "ord() expected a
    character, but string of length 0 found (TypeError)"; others "File magic is invalid
    (AnyReaderError)", "Truncated record at offset 8 ...", "Cannot open database ..."."""
    from scan2terrain.readers.bag import open_bag

    src, suffix = CUT_BAGS[layout]
    data = (src if src.is_file() else next(src.glob(f"*{suffix}"))).read_bytes()
    blobs = [data[:n] for n in range(65)] + MAGIC_ONLY[suffix]
    bad = []
    for i, blob in enumerate(blobs):
        path = _cut_bag(layout, blob, tmp_path / str(i))
        with pytest.raises(InputError) as info:
            open_bag(path).close()
        problem = info.value.problem
        if info.value.path != path or RAW.search(problem) or not problem.startswith(OUR_SENTENCES):
            bad.append(f"{len(blob)} bytes {blob[:16]!r}: {info.value}")
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("command", ["inspect", "bag2world"])
def test_an_mcap_file_of_its_magic_only_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str
) -> None:
    from scan2terrain.cli import main

    path = tmp_path / "x.mcap"
    path.write_bytes(b"\x89MCAP0\r\n")
    args = [command, str(path)] + (["-o", str(tmp_path / "out")] if command == "bag2world" else [])
    assert main(args) == 2
    out, err = capsys.readouterr()
    assert out == ""
    problem = "the MCAP file is truncated or damaged: it ends after its magic"
    assert err == f"scan2terrain: error: {path}: {problem}\n"
    assert not (tmp_path / "out").exists()
