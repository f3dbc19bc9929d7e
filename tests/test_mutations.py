"""A corrupt input file is never a crash (issue 12): every reader, fed seeded mutations of a small
good file, either reads it (exit 0) or refuses it with one line naming the file (exit 2).

For each reader a small good input is made in a temporary folder (a copy of a small fixture, or
written with the project's own writers and ``tests/bagmaker.py``), then mutated: truncated,
bytes flipped, random chunks spliced in or cut out, and header fields set to zero, huge,
negative or NaN where the format has them (for bags also messages whose fields are). Every
mutated file is run through the real command that reads it (``convert``, ``cloud2world
--stream``, ``map2world``, ``image2world``, ``dem2world``, ``octree2world``, ``bag2world``) by
:mod:`tests.mutation_runner`: one process that imports scan2terrain once and forks a child per
case under an address-space limit. Asserted per case: exit 0 or 2, never 1, a signal (SIGABRT
from a Rust allocation, SIGKILL) or a hang; on 2 the last stderr line is ``scan2terrain:
error: <a path of the input>: ...``, every stderr line is scan2terrain's own (no traceback, no
line printed by a library), and nothing new is left next to the output; peak memory under the
budget.

Mutations are deterministic (``random.Random(seed)`` per reader); a case's name says which one
it is (``flip2`` = the third set of random flips, ``chunks-huge`` = the LAZ chunk count set to
2^32 - 1), and its files are kept in pytest's temporary folder for a rerun by hand.
"""

from __future__ import annotations

import bz2
import math
import random
import re
import shutil
import signal
import struct
import tempfile
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.mutation_runner import Case, Outcome, run_cases

#: Minutes of forked runs: `pytest -m 'not slow'` leaves it out, CI runs it.
pytestmark = pytest.mark.slow

FIXTURES = Path(__file__).resolve().parent.parent / "fixtures"
#: Address space a child may take. A normal run of any case below peaks at about 200 MB of
#: resident memory and runs within 1.2 GiB of address space (Open3D, numba and the octree's
#: tables reserve it; 0.5 GiB is too little); 3 GiB leaves room for that and still stops a
#: header-sized allocation of gigabytes (a 4 GB one made lazrs abort).
LIMIT_BYTES = 3 << 30
#: Resident memory any case may reach (MB).
RSS_BUDGET_MB = 1000

Mutation = tuple[str, bytes]

#: Cases that still fail, each for a bug outside the readers, with the reason. The test wants
#: them to fail as described (and says so when one passes: then remove it here).
KNOWN_BUGS: dict[str, str] = {}

#: Cases that must be refused (exit 2), not read: values that make no sense, which exited 0
#: with an absurd world or a silently wrong one (issue 13).
MUST_REFUSE = {
    "bt/res-tiny",  # 1e-12 m voxels
    "bt/res-e20",  # 1e20 m voxels
    "bt/res-e-300",
    "bt/res-max",  # 1.7e308
    "las/x_scale-zero",  # every x at the offset
    "las/x_scale-neg",  # the cloud mirrored
    "las/x_offset-nan",
    "laz/x_scale-zero",
    "pcd-ascii/FIELDS-dup",  # z taken from another column
    "pcd-binary/FIELDS-dup",
    "map-pgm/maxval-low",  # samples above maxval clamped: unknown cells became free
    "dem/photometric-ycbcr",
    "dem/compression-deflate",
    "dem/geokeys-none",  # degrees read as metres
    "map-yaml/resolution-bigint",
    "map-yaml/origin-bigint",
    "map-yaml/deep",
    "map-yaml/image-nul",
    "map-yaml/image-long",
    "scan-dat/long-line",
}


# --- mutations ----------------------------------------------------------------------------------


def truncations(data: bytes, *at: int) -> list[Mutation]:
    """Cut at the given offsets (e.g. the end of a header), half way and before the last byte."""
    cuts = sorted({*at, len(data) // 2, len(data) - 1})
    return [(f"cut{c}", data[:c]) for c in cuts if 0 < c < len(data)]


def flips(
    data: bytes, rng: random.Random, n: int, *, lo: int = 0, hi: int | None = None
) -> list[Mutation]:
    """``n`` copies, each with 1, 2, 4 or 16 random bytes in ``[lo, hi)`` set to random values."""
    hi = len(data) if hi is None else hi
    out = []
    for k in range(n):
        b = bytearray(data)
        for _ in range(rng.choice((1, 2, 4, 16))):
            b[rng.randrange(lo, hi)] = rng.randrange(256)
        out.append((f"flip{k}", bytes(b)))
    return out


def splices(data: bytes, rng: random.Random, n: int, *, lo: int = 0) -> list[Mutation]:
    """``n`` copies with a chunk inserted (random bytes or a copy of another part) or removed at
    a random place at or after ``lo``."""
    out = []
    for k in range(n):
        at = rng.randrange(lo, len(data))
        size = rng.choice((1, 3, 8, 64, 300))
        kind = rng.choice(("insert", "copy", "cut"))
        if kind == "insert":
            b = data[:at] + rng.randbytes(size) + data[at:]
        elif kind == "copy":
            src = rng.randrange(0, len(data))
            b = data[:at] + data[src : src + size] + data[at:]
        else:
            b = data[:at] + data[at + size :]
        out.append((f"splice{k}-{kind}", b))
    return out


def packed(name: str, data: bytes, offset: int, fmt: str, values: dict[str, Any]) -> list[Mutation]:
    """``data`` with the field ``fmt`` at ``offset`` set to each named value."""
    out = []
    for label, value in values.items():
        b = bytearray(data)
        struct.pack_into(fmt, b, offset, value)
        out.append((f"{name}-{label}", bytes(b)))
    return out


def texts(name: str, data: bytes, pattern: bytes, values: dict[str, bytes]) -> list[Mutation]:
    """``data`` with the first match of ``pattern``'s group 1 replaced by each value."""
    m = re.search(pattern, data)
    assert m is not None, pattern
    return [(f"{name}-{k}", data[: m.start(1)] + v + data[m.end(1) :]) for k, v in values.items()]


def after(data: bytes, marker: bytes) -> int:
    """The offset just after the line holding ``marker``."""
    return data.index(b"\n", data.index(marker) + len(marker)) + 1


U32 = {"zero": 0, "huge": 0xFFFFFFFF}
NUMBERS = {"zero": b"0", "neg": b"-1", "huge": b"99999999999999999999", "nan": b"nan"}


# --- point clouds -------------------------------------------------------------------------------


def _points(n: int, seed: int = 1) -> np.ndarray:
    return np.random.default_rng(seed).uniform((-4, -3, 0), (4, 3, 2), size=(n, 3))


def las_header_mutations(data: bytes) -> list[Mutation]:
    """LAS 1.2 header fields: counts and sizes the reader must check against the file."""
    return [
        *packed("header_size", data, 94, "<H", {"zero": 0}),
        *packed("offset_to_points", data, 96, "<I", {"huge": 0xFFFFFFFF}),
        *packed("vlr_count", data, 100, "<I", {"huge": 0xFFFFFFFF}),
        *packed("point_format", data, 104, "<B", {"huge": 0xFF}),
        *packed("record_length", data, 105, "<H", {"zero": 0, "huge": 0xFFFF}),
        *packed("point_count", data, 107, "<I", U32),
        *packed("x_scale", data, 131, "<d", {"zero": 0.0, "nan": math.nan, "neg": -0.01}),
        *packed("x_offset", data, 155, "<d", {"nan": math.nan}),
    ]


def las_mutations(data: bytes, rng: random.Random) -> list[Mutation]:
    return las_header_mutations(data) + truncations(data, 227, 400) + flips(data, rng, 3)


def laz_mutations(data: bytes, rng: random.Random) -> list[Mutation]:
    """LAZ: the LAS header, the laszip VLR, the chunk table offset and the table itself (the
    last bytes of the file), where a corrupt count made lazrs abort the process."""
    start = struct.unpack_from("<I", data, 96)[0]
    table = struct.unpack_from("<q", data, start)[0]
    vlr = data.find(b"laszip encoded") - 2  # the user id is at +2 of a VLR header
    out = las_header_mutations(data)
    out += packed("table_offset", data, start, "<q", {"none": -1, "inside": start + 100})
    out += packed("chunks", data, table + 4, "<I", {**U32, "big": 0x7FFFFFFF})
    out += packed("table_version", data, table, "<I", {"one": 1})
    out += packed("vlr_length", data, vlr + 20, "<H", {"zero": 0})
    chunk_size = vlr + 54 + 12  # in the laszip VLR's payload
    out += packed("chunk_size", data, chunk_size, "<I", {"zero": 0, "one": 1, "var": 0xFFFFFFFF})
    out += packed("item_count", data, vlr + 54 + 32, "<H", {"huge": 0xFFFF})
    for k in range(4):  # random bytes spliced into the chunk table
        b = bytearray(data)
        at = len(data) - rng.randint(1, len(data) - table)
        b[at:at] = rng.randbytes(rng.randint(1, 8))
        out.append((f"table_splice{k}", bytes(b)))
    out += flips(data, rng, 2, lo=table)
    out += flips(data, rng, 2, lo=start + 8, hi=table)
    out += truncations(data, start + 4, table + 2)
    return out


def laz14_file() -> bytes:
    """A LAS 1.4 point format 6 LAZ (LASzip's layered chunks, a 64-bit point count)."""
    import io

    import laspy

    pts = _points(500)
    las = laspy.LasData(laspy.LasHeader(point_format=6, version="1.4"))
    las.header.scales = np.full(3, 0.001)
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    las.intensity = np.arange(500, dtype=np.uint16)
    out = io.BytesIO()
    las.write(out, do_compress=True)
    data = out.getvalue()
    return data[:90] + bytes(4) + data[94:]  # no creation date: the same bytes every day


def laz14_mutations(data: bytes, rng: random.Random) -> list[Mutation]:
    start = struct.unpack_from("<I", data, 96)[0]
    table = struct.unpack_from("<q", data, start)[0]
    out = packed("count64", data, 247, "<Q", {"huge": 1 << 63, "big": 1 << 40})
    out += packed("evlrs", data, 243, "<I", {"huge": 0xFFFFFFFF})
    out += packed("first_evlr", data, 235, "<Q", {"past_end": len(data) - 10})
    layers = start + 8 + 30 + 4  # after the chunk's raw first point and its point count
    out += packed("layer_size", data, layers, "<I", {"huge": 0xFFFFFFF0})
    out += packed("layer_size8", data, layers + 32, "<I", {"huge": 0xFFFFFFF0})
    out += flips(data, rng, 4, lo=start + 8, hi=start + 8 + 200)  # layer sizes, first point
    out += flips(data, rng, 2, lo=table)
    out += truncations(data, table - 10)
    return out


def laz_stream_mutations(data: bytes, rng: random.Random) -> list[Mutation]:
    keep = ("vlr_count", "point_count-huge", "chunks", "chunk_size-one", "table_splice", "cut")
    return [m for m in laz_mutations(data, rng) if m[0].startswith(keep)]


def pcd_ascii() -> bytes:
    pts = _points(200)
    head = (
        "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 4\nTYPE F F F F\n"
        f"COUNT 1 1 1 1\nWIDTH {len(pts)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\n"
        f"POINTS {len(pts)}\nDATA ascii\n"
    )
    return (head + "".join(f"{x:.4f} {y:.4f} {z:.4f} 7\n" for x, y, z in pts)).encode()


def pcd_compressed(folder: Path) -> tuple[Path, Path]:
    import open3d

    cloud = open3d.geometry.PointCloud(open3d.utility.Vector3dVector(_points(400)))
    path = folder / "compressed.pcd"
    assert open3d.io.write_point_cloud(str(path), cloud, write_ascii=False, compressed=True)
    assert b"DATA binary_compressed" in path.read_bytes()[:400]
    return path, path


def pcd_mutations(data: bytes, rng: random.Random) -> list[Mutation]:
    end = after(data, b"DATA ")
    out = truncations(data, end, end + 3)
    out += texts("POINTS", data, rb"\nPOINTS (\S+)", NUMBERS)
    out += texts("WIDTH", data, rb"\nWIDTH (\S+)", {"huge": NUMBERS["huge"]})
    out += texts("HEIGHT", data, rb"\nHEIGHT (\S+)", {"zero": b"0"})
    out += texts("SIZE", data, rb"\nSIZE (\S+)", {"zero": b"0", "odd": b"3"})
    out += texts("COUNT", data, rb"\nCOUNT (\S+)", {"huge": b"99999"})
    out += texts("FIELDS", data, rb"\nFIELDS x y (\S+)", {"dup": b"x"})
    out += flips(data, rng, 3, lo=end)
    out += splices(data, rng, 2, lo=end)
    if b"binary_compressed" in data[:end]:  # the block's sizes, uint32 after the header
        out += packed("packed", data, end, "<I", U32)
        out += packed("unpacked", data, end + 4, "<I", U32)
    return out


def ply_ascii() -> bytes:
    pts = _points(200)
    head = (
        "ply\nformat ascii 1.0\nelement vertex 200\nproperty float x\nproperty float y\n"
        "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
    )
    rows = "".join(f"{x:.4f} {y:.4f} {z:.4f}\n" for x, y, z in pts)
    return (head + rows + "3 0 1 2\n").encode()


def ply_list(fmt: str) -> Callable[[], bytes]:
    """A PLY whose vertex rows vary in length (a list property): the Open3D (RPly) path."""

    def data() -> bytes:
        pts = _points(150)
        head = (
            f"ply\nformat {fmt} 1.0\nelement vertex {len(pts)}\nproperty float x\n"
            "property float y\nproperty float z\nproperty list uchar float extra\nend_header\n"
        )
        if fmt == "ascii":
            rows = "".join(
                f"{x:.4f} {y:.4f} {z:.4f} {k % 3}{' 1.5' * (k % 3)}\n"
                for k, (x, y, z) in enumerate(pts)
            )
            return (head + rows).encode()
        body = bytearray()
        for k, p in enumerate(pts):  # a loop over a test file's 150 points
            body += struct.pack("<3fB", *p, k % 3) + struct.pack(f"<{k % 3}f", *[1.5] * (k % 3))
        return head.encode() + bytes(body)

    return data


def ply_mutations(data: bytes, rng: random.Random) -> list[Mutation]:
    end = after(data, b"end_header")
    out = truncations(data, end, end + 5, len(data) * 9 // 10)
    out += texts("vertex", data, rb"element vertex (\S+)", {**NUMBERS, "big": b"4294967297"})
    if b"element face" in data:
        out += texts("face", data, rb"element face (\S+)", {"huge": NUMBERS["huge"]})
    if b"property list" in data:
        out += texts("list", data, rb"property list (\S+)", {"int": b"int", "float": b"float"})
    out += flips(data, rng, 3, lo=end)
    out += splices(data, rng, 2, lo=end)
    return out


def text_cloud(header: str, sep: str) -> Callable[[], bytes]:
    def data() -> bytes:
        rows = "".join(f"{x:.4f}{sep}{y:.4f}{sep}{z:.4f}{sep}3\n" for x, y, z in _points(200))
        return (header + rows).encode()

    return data


def text_mutations(data: bytes, rng: random.Random) -> list[Mutation]:
    out = truncations(data, 1, 40)
    lines = data.split(b"\n")
    sep = b"," if b"," in lines[1] else b" "
    for name, token in (("nan", b"nan"), ("inf", b"-inf"), ("huge", b"1e400"), ("nul", b"\0")):
        b = list(lines)
        b[3] = sep.join([token, *b[3].split(sep)[1:]])
        out.append((f"row-{name}", b"\n".join(b)))
    out.append(("all-nan", re.sub(rb"-?\d+\.\d+", b"nan", data)))
    out.append(("latin1", data.replace(b"3\n", b"\xe9\n", 5)))
    out += flips(data, rng, 3)
    out += splices(data, rng, 2)
    return out


# --- maps and images ----------------------------------------------------------------------------


def map_files(image_name: str) -> Callable[[Path], tuple[Path, Path]]:
    """A 40x30 map_server map; the mutated file is the YAML or the image."""

    def make(folder: Path) -> tuple[Path, Path]:
        from tests.conftest import write_map

        pixels = np.full((30, 40), 254, dtype=np.uint8)
        pixels[0, :] = pixels[-1, :] = pixels[:, 0] = pixels[:, -1] = 0
        pixels[10:14, 12:30] = 0
        pixels[20:, 30:] = 205
        yaml_path = write_map(folder, pixels, name=image_name, origin="[-2.0, -1.5, 0.0]")
        return yaml_path, folder / image_name

    return make


def map_yaml_file(folder: Path) -> tuple[Path, Path]:
    yaml_path, _ = map_files("m.pgm")(folder)
    return yaml_path, yaml_path


def yaml_mutations(data: bytes, rng: random.Random) -> list[Mutation]:
    out = truncations(data, 10)
    values = {"neg": b"-0.1", "nan": b".nan", "huge": b"1e308", "text": b"abc", "list": b"[1, 2]"}
    out += texts(
        "resolution", data, rb"resolution: (\S+)", {**values, "exp": b"5e-2", "tiny": b"1e-12"}
    )
    out += texts(
        "origin",
        data,
        rb"origin: (\[.*\])",
        {"nan": b"[.nan, 0, 0]", "huge": b"[1e308, -1e308, 0]", "short": b"[1]"},
    )
    out += texts(
        "image",
        data,
        rb"image: (\S+)",
        {"missing": b"nothere.pgm", "self": b"m.yaml", "nul": b'"m\\0.pgm"', "long": b"a" * 300},
    )
    out += texts("resolution", data, rb"resolution: (\S+)", {"bigint": b"9" * 400})
    out += texts("origin", data, rb"origin: (\[.*\])", {"bigint": b"[" + b"9" * 400 + b", 0, 0]"})
    out.append(("deep", data + b"x: " + b"[" * 5000 + b"]" * 5000 + b"\n"))
    out += texts("occupied", data, rb"occupied_thresh: (\S+)", {"nan": b".nan", "huge": b"7"})
    out.append(("anchors", b"a: &a [*a]\n" + data))
    out += flips(data, rng, 2)
    return out


def pgm_mutations(data: bytes, rng: random.Random) -> list[Mutation]:
    m = re.match(rb"P5\s+(\d+)\s+(\d+)\s+(\d+)\s", data)
    assert m is not None
    out = truncations(data, m.end())
    for group, field, values in (
        (1, "width", {"zero": b"0", "huge": b"999999999", "wide": b"70000"}),
        (2, "height", {"neg": b"-5", "huge": b"999999999"}),
        (3, "maxval", {"zero": b"0", "huge": b"70000", "word": b"x", "low": b"200"}),
    ):
        out += [
            (f"{field}-{k}", data[: m.start(group)] + v + data[m.end(group) :])
            for k, v in values.items()
        ]
    out += flips(data, rng, 2, lo=m.end())
    out += splices(data, rng, 2)
    return out


def png_with_ihdr(data: bytes, width: int, height: int, depth: int = 8) -> bytes:
    """The PNG with its IHDR size and bit depth replaced, its CRC recomputed."""
    b = bytearray(data)
    struct.pack_into(">IIB", b, 16, width, height, depth)
    struct.pack_into(">I", b, 29, zlib.crc32(bytes(b[12:29])))
    return bytes(b)


def png_mutations(data: bytes, rng: random.Random) -> list[Mutation]:
    idat = data.index(b"IDAT") - 4
    out = truncations(data, 33, idat + 20)
    for name, (w, h) in {
        "zero": (0, 0),
        "huge": (0x7FFFFFFF, 0x7FFFFFFF),
        "wide": (100_000, 3),
        "big": (20_000, 20_000),
    }.items():
        out.append((f"ihdr-{name}", png_with_ihdr(data, w, h)))
    out.append(("ihdr-depth16", png_with_ihdr(data, *struct.unpack_from(">II", data, 16), 16)))
    out.append(("ihdr-badcrc", data[:16] + b"\0\0\1\0" + data[20:]))
    out += flips(data, rng, 3, lo=idat + 8)
    out += splices(data, rng, 2, lo=idat)
    return out


def image_file(folder: Path) -> tuple[Path, Path]:
    from PIL import Image

    y, x = np.mgrid[0:33, 0:33]
    path = folder / "hill.png"
    Image.fromarray(((x * y) % 256).astype(np.uint8)).save(path)
    return path, path


# --- DEM ----------------------------------------------------------------------------------------


def tiff_entries(data: bytes) -> dict[int, int]:
    """Tag code -> offset of its 12-byte entry in a little-endian TIFF's first IFD."""
    assert data[:4] == b"II*\x00"
    ifd = struct.unpack_from("<I", data, 4)[0]
    n = struct.unpack_from("<H", data, ifd)[0]
    return {struct.unpack_from("<H", data, ifd + 2 + 12 * i)[0]: ifd + 2 + 12 * i for i in range(n)}


def dem_mutations(data: bytes, rng: random.Random) -> list[Mutation]:
    tags = tiff_entries(data)
    value = {code: at + 8 for code, at in tags.items()}  # a short value, or an offset to values
    at_values = {code: struct.unpack_from("<I", data, value[code])[0] for code in tags}
    out = truncations(data, 8, 200)
    out += packed("width", data, value[256], "<H", {"zero": 0, "huge": 0xFFFF})
    out += packed("height", data, value[257], "<H", {"huge": 0xFFFF})
    out += packed("strips", data, tags[273] + 4, "<I", {"huge": 0x7FFFFFFF})  # its count
    out += packed("bits", data, value[258], "<H", {"zero": 0, "odd": 12})
    out += packed("pixelscale", data, at_values[33550], "<d", {"zero": 0.0, "huge": 1e300})
    out += packed("tiepoint", data, at_values[33922] + 24, "<d", {"nan": math.nan, "huge": 1e300})
    out += packed("geokeys", data, at_values[34735] + 6, "<H", {"huge": 0xFFFF})
    out += packed("geokeys", data, tags[34735], "<H", {"none": 34999})  # an unknown tag now
    out += packed("photometric", data, value[262], "<H", {"ycbcr": 6})
    out += packed("compression", data, value[259], "<H", {"deflate": 8})
    out += packed("ifd", data, 4, "<I", {"zero": 0, "huge": 0xFFFFFFF0})
    out += flips(data, rng, 3)
    out += splices(data, rng, 2)
    return out


# --- octrees and scans --------------------------------------------------------------------------


def bt_file(folder: Path) -> tuple[Path, Path]:
    from scan2terrain.octree.bt import bt_bytes

    rng = np.random.default_rng(3)
    keys = np.unique(rng.integers(32768 - 20, 32768 + 20, size=(600, 3)), axis=0)
    occupied = rng.random(len(keys)) < 0.4
    path = folder / "tree.bt"
    path.write_bytes(bt_bytes(resolution=0.1, keys=keys.astype(np.uint16), occupied=occupied))
    return path, path


def bt_mutations(data: bytes, rng: random.Random) -> list[Mutation]:
    end = after(data, b"\ndata")
    out = truncations(data, end, end + 1)
    out += texts(
        "res",
        data,
        rb"\nres (\S+)",
        {**NUMBERS, "tiny": b"1e-12", "e20": b"1e20", "e-300": b"1e-300", "max": b"1.7e308"},
    )
    out += texts("size", data, rb"\nsize (\S+)", {"zero": b"0", "huge": NUMBERS["huge"]})
    out += texts("id", data, rb"\nid (\S+)", {"color": b"ColorOcTree"})
    out.append(("all-inner", data[:end] + b"\xff" * (len(data) - end)))
    out += flips(data, rng, 3, lo=end)
    out += splices(data, rng, 2, lo=end)
    return out


def scan_text() -> bytes:
    rng = np.random.default_rng(5)
    lines = []
    angles = np.linspace(-np.pi, np.pi, 60, endpoint=False)
    for k in range(3):
        lines.append(f"NODE {k * 0.5} 0 0.3 0 0 {k * 0.3}")
        r = 2.0 + rng.random(60)
        xy = np.column_stack([r * np.cos(angles), r * np.sin(angles)])
        lines += [f"{x:.3f} {y:.3f} 0.1" for x, y in xy]
    return ("\n".join(lines) + "\n").encode()


def scan_mutations(data: bytes, rng: random.Random) -> list[Mutation]:
    out = truncations(data, 1)
    lines = data.split(b"\n")
    for name, line in {
        "node-nan": b"NODE nan 0 0 0 0 0",
        "node-huge": b"NODE 1e300 1e300 0 0 0 0",
        "node-short": b"NODE 1 2",
        "point-nan": b"nan nan nan",
        "point-inf": b"inf 0 0",
        "point-huge": b"1e300 -1e300 1e300",
        "point-4": b"1 2 3 4",
        "word": b"hello world !",
        "long-line": b"1" * 5000,
    }.items():
        out.append((name, b"\n".join([*lines[:5], line, *lines[5:]])))
    out += flips(data, rng, 2)
    out += splices(data, rng, 2)
    return out


def scan_bz2_file(folder: Path) -> tuple[Path, Path]:
    path = folder / "scan.dat.bz2"
    path.write_bytes(bz2.compress(scan_text()))
    return path, path


def scan_bz2_mutations(data: bytes, rng: random.Random) -> list[Mutation]:
    inner = scan_mutations(bz2.decompress(data), rng)
    return [
        *truncations(data, 10),
        *flips(data, rng, 2, lo=10),
        *[(f"inner-{k}", bz2.compress(b)) for k, b in inner if k.startswith(("point", "cut"))],
    ]


# --- bags ---------------------------------------------------------------------------------------


@cache
def room(variant: str) -> Any:
    from tests.bagmaker import synthetic_room

    return synthetic_room(variant, n_scans=6, beams=90, rings=4, azimuths=60)  # type: ignore[arg-type]


def bag(fmt: str, variant: str) -> Callable[[Path], tuple[Path, Path]]:
    """A small synthetic-room recording; for rosbag2 the command is given the folder and the
    storage file is mutated."""

    def make(folder: Path) -> tuple[Path, Path]:
        if fmt == "ros1":
            path = folder / "room.bag"
            room(variant).write(path, "ros1")
            return path, path
        path = folder / "room"
        room(variant).write(path, fmt)
        storage = next(p for p in path.iterdir() if p.suffix in (".db3", ".mcap"))
        return path, storage

    return make


def mcap_of(kind: str) -> Callable[[Path], tuple[Path, Path]]:
    """The room's ROS1 bag rewritten as MCAP read with the ``mcap`` package: ROS1 messages
    (profile ros1, as ``mcap convert`` writes) or Foxglove protobuf schemas."""

    def make(folder: Path) -> tuple[Path, Path]:
        from tests.bagmaker import ros1_bag_to_mcap, ros_bag_to_foxglove_mcap

        ros1 = folder / "room.tmp.bag"
        room("tf").write(ros1, "ros1")
        path = folder / "room.mcap"
        if kind == "ros1":
            ros1_bag_to_mcap(ros1, path, compression="zstd")
        else:
            ros_bag_to_foxglove_mcap(ros1, path, "protobuf", compression="lz4")
        ros1.unlink()
        return path, path

    return make


def ros1_records(data: bytes) -> Iterator[tuple[int, int]]:
    """(offset, header length) of each top-level ROS1 bag record."""
    pos = len(b"#ROSBAG V2.0\n")
    while pos + 8 <= len(data):
        header_len = struct.unpack_from("<I", data, pos)[0]
        data_at = pos + 4 + header_len
        yield pos, header_len
        pos = data_at + 4 + struct.unpack_from("<I", data, data_at)[0]


def ros1_mutations(data: bytes, rng: random.Random) -> list[Mutation]:
    records = list(ros1_records(data))
    out = truncations(data, 13, records[1][0] + 10)
    for k in (0, 1, 2, len(records) - 1):  # bag header, first chunk, its index, last record
        pos, header_len = records[k]
        out += packed(f"rec{k}-header_len", data, pos, "<I", {"huge": 0xFFFFFFFF})
        out += packed(f"rec{k}-data_len", data, pos + 4 + header_len, "<I", U32)
    chunk_data = records[1][0] + 8 + records[1][1]
    out += flips(data, rng, 4, lo=chunk_data, hi=records[2][0])  # the messages
    out += splices(data, rng, 2, lo=13)
    return out


def sqlite_mutations(data: bytes, rng: random.Random) -> list[Mutation]:
    out = truncations(data, 100, 4096)
    out += packed("pagesize", data, 16, ">H", {"zero": 0, "odd": 1000})
    out += packed("pagecount", data, 28, ">I", U32)
    out += flips(data, rng, 5, lo=100)
    out += splices(data, rng, 2, lo=100)
    return out


def mcap_mutations(data: bytes, rng: random.Random) -> list[Mutation]:
    out = truncations(data, 8, 30)
    pos = 8
    for k in range(5):  # the first records: opcode uint8, length uint64
        op, length = struct.unpack_from("<BQ", data, pos)
        out += packed(f"rec{k}-op{op}-len", data, pos + 1, "<Q", {"huge": 1 << 63, "big": 1 << 40})
        pos += 9 + length
    out += flips(data, rng, 5, lo=8)
    out += splices(data, rng, 2, lo=8)
    return out


def _edited_bag(messages: list[Any], edit: Callable[[str, dict[str, Any]], None]) -> bytes:
    """A ROS1 bag of ``messages`` (deep-copied) after ``edit(msgtype, message dict)`` on each."""
    import copy

    from tests.bagmaker import write_bag

    edited = []
    for topic, msgtype, t, original in messages:
        msg = copy.deepcopy(original)
        edit(msgtype, msg)
        edited.append((topic, msgtype, t, msg))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "b.bag"
        write_bag(path, "ros1", edited)
        return path.read_bytes()


def _scan_edit(field: str, value: Any) -> Callable[[str, dict[str, Any]], None]:
    def edit(msgtype: str, msg: dict[str, Any]) -> None:
        if msgtype.endswith("LaserScan"):
            msg[field] = value(msg[field]) if callable(value) else value

    return edit


def scan_message_mutations(data: bytes, rng: random.Random) -> list[Mutation]:
    """Messages whose fields are zero, huge, negative or NaN (the bag itself is sound)."""
    msgs = room("tf").messages
    cases: dict[str, Callable[[str, dict[str, Any]], None]] = {
        "increment-zero": _scan_edit("angle_increment", 0.0),
        "increment-nan": _scan_edit("angle_increment", math.nan),
        "angle_min-inf": _scan_edit("angle_min", math.inf),
        "range_max-nan": _scan_edit("range_max", math.nan),
        "range_min-huge": _scan_edit("range_min", 3e38),
        "ranges-nan": _scan_edit("ranges", lambda r: np.full_like(r, np.nan)),
        "ranges-huge": _scan_edit("ranges", lambda r: np.full_like(r, 3e38)),
        "ranges-empty": _scan_edit("ranges", lambda r: r[:0]),
    }

    def tf_edit(value: float) -> Callable[[str, dict[str, Any]], None]:
        def edit(msgtype: str, msg: dict[str, Any]) -> None:
            for tf in msg.get("transforms", []):
                tf["transform"]["rotation"] = {"x": value, "y": 0.0, "z": 0.0, "w": 0.0}
                tf["transform"]["translation"]["x"] = 1e300 if value else 0.0

        return edit

    cases["tf-zero_quaternion"] = tf_edit(0.0)
    cases["tf-nan"] = tf_edit(math.nan)
    return [(name, _edited_bag(msgs, edit)) for name, edit in cases.items()]


def cloud_message_mutations(data: bytes, rng: random.Random) -> list[Mutation]:
    msgs = room("cloud").messages

    def cloud_edit(
        change: Callable[[dict[str, Any]], None],
    ) -> Callable[[str, dict[str, Any]], None]:
        def edit(msgtype: str, msg: dict[str, Any]) -> None:
            if msgtype.endswith("PointCloud2"):
                change(msg)

        return edit

    def field(i: int, key: str, value: Any) -> Callable[[dict[str, Any]], None]:
        def change(msg: dict[str, Any]) -> None:
            msg["fields"][i][key] = value

        return change

    def top(key: str, value: Any) -> Callable[[dict[str, Any]], None]:
        def change(msg: dict[str, Any]) -> None:
            msg[key] = value(msg[key]) if callable(value) else value

        return change

    cases = {
        "point_step-zero": top("point_step", 0),
        "point_step-huge": top("point_step", 0xFFFFFFFF),
        "width-huge": top("width", 0xFFFFFFFF),
        "height-huge": top("height", 0xFFFF),
        "row_step-zero": top("row_step", 0),
        "data-cut": top("data", lambda d: d[: len(d) // 3]),
        "bigendian": top("is_bigendian", True),
        "z-offset-huge": field(2, "offset", 0xFFFFFFF0),
        "z-datatype-bad": field(2, "datatype", 99),
        "z-count-zero": field(2, "count", 0),
        "x-renamed": field(0, "name", "q"),
    }
    return [(name, _edited_bag(msgs, cloud_edit(change))) for name, change in cases.items()]


def map_message_mutations(data: bytes, rng: random.Random) -> list[Mutation]:
    from tests.bagmaker import OCCUPANCY_GRID, occupancy_grid_msg

    grid = np.zeros((20, 30), dtype=np.int8)
    grid[5, 3:25] = 100
    good = occupancy_grid_msg(1_700_000_000_000_000_000, "map", grid, 0.1, (-1.0, -1.0, 0.3))

    def with_info(**info: Any) -> bytes:
        msg = {**good, "info": {**good["info"], **info}}
        return _edited_bag([("/map", OCCUPANCY_GRID, 1_700_000_000_000_000_000, msg)], _keep)

    origin = good["info"]["origin"]
    return [
        ("original-map", with_info()),
        ("width-huge", with_info(width=0xFFFFFFFF)),
        ("height-zero", with_info(height=0)),
        ("resolution-zero", with_info(resolution=0.0)),
        ("resolution-nan", with_info(resolution=math.nan)),
        ("resolution-huge", with_info(resolution=3e38)),
        ("origin-huge", with_info(origin={**origin, "position": {"x": 1e300, "y": 0, "z": 0}})),
        (
            "orientation-nan",
            with_info(origin={**origin, "orientation": {"x": 0, "y": 0, "z": math.nan, "w": 1}}),
        ),
    ]


def _keep(msgtype: str, msg: dict[str, Any]) -> None:
    pass


# --- the readers and their cases ----------------------------------------------------------------


@dataclass(frozen=True)
class Reader:
    """One input reader: ``make`` writes a good input into a folder and returns the path the
    command is given and the file the mutations replace (often the same); ``argv`` builds the
    command for an input and an output path; ``mutate`` lists the mutations (named bytes) of
    that file's bytes."""

    name: str
    make: Callable[[Path], tuple[Path, Path]]
    argv: Callable[[Path, Path], list[str]]
    out_name: str
    mutate: Callable[[bytes, random.Random], list[Mutation]]


def convert(src: Path, out: Path) -> list[str]:
    return ["convert", str(src), str(out)]


def world(command: str, *extra: str) -> Callable[[Path, Path], list[str]]:
    def argv(src: Path, out: Path) -> list[str]:
        return [command, str(src), "-o", str(out), "--simulator", "gz", *extra]

    return argv


def copy_fixture(relative: str) -> Callable[[Path], tuple[Path, Path]]:
    def make(folder: Path) -> tuple[Path, Path]:
        dst = folder / Path(relative).name
        shutil.copyfile(FIXTURES / relative, dst)
        return dst, dst

    return make


def written(name: str, data: Callable[[], bytes]) -> Callable[[Path], tuple[Path, Path]]:
    def make(folder: Path) -> tuple[Path, Path]:
        (folder / name).write_bytes(data())
        return folder / name, folder / name

    return make


def points_file(suffix: str) -> Callable[[], bytes]:
    """A small cloud in the project's own writer's bytes."""

    def data() -> bytes:
        from scan2terrain.exporters.pointcloud import points_bytes

        return points_bytes(_points(300), suffix)

    return data


BAG2WORLD = world("bag2world", "--resolution", "0.2", "--no-preview")
READERS = [
    Reader("las", copy_fixture("clouds/pc_las_simple_twin/simple.las"), convert, "o.xyz",
           las_mutations),
    Reader("laz", copy_fixture("clouds/pc_las_simple_twin/simple.laz"), convert, "o.xyz",
           laz_mutations),
    Reader("laz14", written("c14.laz", laz14_file), convert, "o.xyz", laz14_mutations),
    Reader("laz-stream", written("c.laz", points_file(".laz")),
           world("cloud2world", "--stream", "--resolution", "0.2", "--no-preview"), "o",
           laz_stream_mutations),
    Reader("pcd-ascii", written("a.pcd", pcd_ascii), convert, "o.xyz", pcd_mutations),
    Reader("pcd-binary", written("b.pcd", points_file(".pcd")), convert, "o.xyz", pcd_mutations),
    Reader("pcd-compressed", pcd_compressed, convert, "o.xyz", pcd_mutations),
    Reader("ply-ascii", written("a.ply", ply_ascii), convert, "o.xyz", ply_mutations),
    Reader("ply-binary", written("b.ply", points_file(".ply")),
           world("cloud2world", "--resolution", "0.2", "--no-preview"), "o", ply_mutations),
    Reader("ply-list", written("l.ply", ply_list("binary_little_endian")), convert, "o.xyz",
           ply_mutations),
    Reader("ply-list-ascii", written("la.ply", ply_list("ascii")), convert, "o.xyz",
           ply_mutations),
    Reader("xyz", written("c.xyz", text_cloud("", " ")), convert, "o.ply", text_mutations),
    Reader("csv", written("c.csv", text_cloud("x,y,z,i\n", ",")), convert, "o.ply",
           text_mutations),
    Reader("map-yaml", map_yaml_file, world("map2world"), "o", yaml_mutations),
    Reader("map-pgm", map_files("m.pgm"), world("map2world"), "o", pgm_mutations),
    Reader("map-png", map_files("m.png"), world("map2world", "--no-preview"), "o",
           png_mutations),
    Reader("image-png", image_file, world("image2world", "--resolution", "0.1"), "o",
           png_mutations),
    Reader("dem", copy_fixture("terrain/dem_moon_polar_geotiff/dem_moon.tif"),
           world("dem2world"), "o", dem_mutations),
    Reader("bt", bt_file, world("octree2world"), "o", bt_mutations),
    Reader("scan-dat", written("scan.dat", scan_text),
           world("octree2world", "--resolution", "0.2", "--no-preview"), "o", scan_mutations),
    Reader("scan-bz2", scan_bz2_file, world("octree2world", "--resolution", "0.2"), "o",
           scan_bz2_mutations),
    Reader("ros1", bag("ros1", "tf"), convert, "o.xyz", ros1_mutations),
    Reader("ros1-world", bag("ros1", "tf"), BAG2WORLD, "o",
           lambda d, r: ros1_mutations(d, r)[::5]),
    Reader("ros1-scan-msgs", bag("ros1", "tf"), BAG2WORLD, "o", scan_message_mutations),
    Reader("ros1-cloud-msgs", bag("ros1", "cloud"), convert, "o.xyz", cloud_message_mutations),
    Reader("ros1-map-msgs", bag("ros1", "tf"), BAG2WORLD, "o", map_message_mutations),
    Reader("db3", bag("sqlite3", "cloud"), convert, "o.xyz", sqlite_mutations),
    Reader("mcap", bag("mcap", "tf"), convert, "o.xyz", mcap_mutations),
    Reader("mcap-ros1", mcap_of("ros1"), convert, "o.xyz", mcap_mutations),
    Reader("mcap-foxglove", mcap_of("foxglove"), BAG2WORLD, "o", mcap_mutations),
]  # fmt: skip


@dataclass(frozen=True)
class Built:
    reader: str
    case: Case
    input_dir: Path


def build_cases(root: Path) -> list[Built]:
    """Every reader's good input and its mutations, each in its own folder (``in``) with an
    empty ``out`` folder beside it."""
    built = []
    for seed, reader in enumerate(READERS):
        good = root / reader.name / "good"
        good.mkdir(parents=True)
        given, target = reader.make(good)
        original = target.read_bytes()
        mutations = [("original", original), *reader.mutate(original, random.Random(seed))]
        seen: set[str] = set()
        for given_name, data in mutations:
            name = given_name
            while name in seen:  # the same kind of mutation twice (flips in two regions)
                name += "+"
            seen.add(name)
            case_dir = root / reader.name / name
            shutil.copytree(good, case_dir / "in")
            (case_dir / "in" / target.relative_to(good)).write_bytes(data)
            out = case_dir / "out"
            out.mkdir()
            argv = reader.argv(case_dir / "in" / given.relative_to(good), out / reader.out_name)
            built.append(
                Built(reader.name, Case(f"{reader.name}/{name}", argv, str(out)), case_dir)
            )
    return built


@pytest.fixture(scope="module")
def outcomes(tmp_path_factory: pytest.TempPathFactory) -> dict[str, list[tuple[Built, Outcome]]]:
    root = tmp_path_factory.mktemp("mutations")
    built = build_cases(root)
    results = run_cases([b.case for b in built], limit_bytes=LIMIT_BYTES, workdir=root / "_runner")
    by_reader: dict[str, list[tuple[Built, Outcome]]] = {}
    for b, o in zip(built, results, strict=True):
        by_reader.setdefault(b.reader, []).append((b, o))
    return by_reader


def problems(built: Built, o: Outcome) -> list[str]:
    """What is wrong with how one case ended (empty: nothing)."""
    found = []
    lines = o.stderr.strip().splitlines()
    if o.signal == signal.SIGALRM:
        found.append("timed out (a hang)")
    elif o.signal is not None:
        found.append(f"killed by signal {o.signal}")
    elif o.exit not in (0, 2):
        found.append(f"exit {o.exit}")
    foreign = [ln for ln in lines if not ln.startswith("scan2terrain: ")]
    if foreign:  # a traceback, or a line a library printed
        found.append(f"stderr lines not from scan2terrain: {foreign[:3]}")
    if o.exit == 2:
        last = lines[-1] if lines else ""
        if not last.startswith("scan2terrain: error: "):
            found.append(f"last stderr line is not an error line: {last!r}")
        elif str(built.input_dir / "in") not in last:
            found.append("the error names no input file")
        if o.new_files:
            found.append(f"left behind: {o.new_files}")
    if o.maxrss_mb > RSS_BUDGET_MB:
        found.append(f"peak RSS {o.maxrss_mb:.0f} MB over {RSS_BUDGET_MB} MB")
    return found


@pytest.mark.parametrize("reader", [r.name for r in READERS])
def test_mutated_input_exits_0_or_2(
    reader: str, outcomes: dict[str, list[tuple[Built, Outcome]]]
) -> None:
    cases = outcomes[reader]
    original = cases[0][1]
    assert original.exit == 0, f"the good input fails: {original.describe()}"
    bad = [
        f"{o.describe()}\n  -> {'; '.join(p)}"
        for b, o in cases
        if (p := problems(b, o)) and o.name not in KNOWN_BUGS
    ]
    assert not bad, f"{len(bad)} of {len(cases)} cases:\n" + "\n".join(bad)
    read = [o.describe() for b, o in cases if o.name in MUST_REFUSE and o.exit != 2]
    assert not read, "read, but must be refused:\n" + "\n".join(read)
    fixed = [o.name for b, o in cases if o.name in KNOWN_BUGS and not problems(b, o)]
    assert not fixed, f"known bugs no longer fail, remove them from KNOWN_BUGS: {fixed}"
    assert any(o.exit == 2 for _, o in cases)  # the mutations do reach the reader


def test_must_refuse_names_cases(outcomes: dict[str, list[tuple[Built, Outcome]]]) -> None:
    names = {o.name for cases in outcomes.values() for _, o in cases}
    assert not (MUST_REFUSE - names), sorted(MUST_REFUSE - names)
    assert not (set(KNOWN_BUGS) - names), sorted(set(KNOWN_BUGS) - names)
