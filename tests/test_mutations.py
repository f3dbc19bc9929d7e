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
line printed by a library), and nothing new is left next to the output; peak memory and CPU
time under their budgets.

Issue 28 added seeds cut from every fixture DEM, LAS/LAZ, PLY, PCD, CSV/XYZ, MCAP, db3 and PNG
(each maker says how it was cut small), and mutation kinds: every numeric header field at a
denormal (5e-324), tiny (1e-300) and huge (+-1e300) value (LAS scales, offsets and bounds,
GeoTIFF doubles, PCD and PLY header numbers, map YAML resolution, origin and thresholds; float32
samples at their own extremes), offsets at 0 and at the file's size (TIFF strips and tag values,
LAS points, the LAZ chunk table, MCAP chunks, indexes and summary), MCAP record lengths running
past their chunk or the file, duplicated PLY properties and PCD fields, palette and bit-depth
changes (PNG colour type 3 without PLTE, bit depth and colour type changed; TIFF BitsPerSample,
SampleFormat and Compression changed). On exit 0, what the command wrote must make sense:
:func:`tests.output_sanity.output_problems` (finite numbers, sizes and heights within
``readers/_limits.py``, the heightmap's brightest pixel at full scale).

Mutations are deterministic (``random.Random(seed)`` per reader); a case's name says which one
it is (``flip2`` = the third set of random flips, ``chunks-huge`` = the LAZ chunk count set to
2^32 - 1), and its files are kept in pytest's temporary folder for a rerun by hand.

CI runs the short seeded run (about 1,670 cases). A longer run by hand:
``SCAN2TERRAIN_FUZZ_ROUNDS=N`` (default 1) draws each reader's random mutations (flips,
splices) N times, round r from seed ``seed + 1000 r`` (its cases named ``<mutation>@<r>``),
and tries every value of every field on the seeds CI tries at one value per field (their cases
are slow: laz-autzen, map-levine-yaml, mcap-embark, mcap-nav2; see :func:`pick`). For example
``SCAN2TERRAIN_FUZZ_ROUNDS=20 .venv/bin/pytest tests/test_mutations.py``: about 6,000 cases.
"""

from __future__ import annotations

import bz2
import math
import os
import random
import re
import shutil
import signal
import struct
import tempfile
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.bagmaker import ros_msg
from tests.fixtures import (
    AUTZEN,
    AUTZEN_CSV,
    BOWL,
    EMBARK_MCAP,
    GRIDMAP,
    HDL_PCD,
    HDL_PLY,
    LEVINE_DIR,
    MOON,
    NAV2,
    OFFICE,
    SFBAY,
    SICK_DB3,
    SIMPLE_LAS,
    SIMPLE_LAZ,
    STREET,
    VALLEY,
)
from tests.mutation_runner import Case, Outcome, run_cases
from tests.output_sanity import output_problems
from tests.seeds import bt_file, ply_list, points, room, tiff_entries

#: Minutes of forked runs: `pytest -m 'not slow'` leaves it out, CI runs it.
pytestmark = pytest.mark.slow

#: Address space a child may take. A normal run of any case below peaks at about 200 MB of
#: resident memory and runs within 1.2 GiB of address space (Open3D, numba and the octree's
#: tables reserve it; 0.5 GiB is too little); 3 GiB leaves room for that and still stops a
#: header-sized allocation of gigabytes (a 4 GB one made lazrs abort).
LIMIT_BYTES = 3 << 30
#: Resident memory any case may reach (MB).
RSS_BUDGET_MB = 1000
#: CPU time any case may take (s): every input here is small, and its slowest case takes under
#: 2 s; issue 28 found a PLY declaring x twice, and a fixture CSV, taking over 30 s. CPU time,
#: not wall time: a loaded machine does not make a case fail.
CPU_BUDGET_S = 20.0

Mutation = tuple[str, bytes]

#: Cases that still fail, each with the reason (the bug, outside the fuzz). The test wants
#: them to fail as described (and says so when one passes: then remove it here).
KNOWN_BUGS: dict[str, str] = {}

#: Cases that must be refused (exit 2), not read: values that make no sense, which exited 0
#: with an absurd world or a silently wrong one (issue 13).
MUST_REFUSE = {
    "ros1-cloud-msgs/bigendian",  # little-endian floats read big-endian: 3e38 m
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
#: Issue 28: what the issue names as nonsense must be refused, whatever the world looks like (a
#: tie point at 1e300 m leaves no trace in a world centred on the DEM; a scale of 1e-300 puts
#: every point at the offset): case name patterns, each with why.
MUST_REFUSE_28 = {
    r"dem(-sfbay)?/ModelPixelScale[01]-.*": "pixels of 5e-324 .. 1e300 m (or degrees)",
    r"dem(-sfbay)?/ModelTiepoint[0134]-(e300|-e300)": "a raster position or tie point at 1e300",
    r"dem(-sfbay)?/StripOffsets0-(zero|end)": "samples read from the header or past the end",
    r"dem(-sfbay)?/(SampleFormat-void|ImageWidth-one|BitsPerSample-.*|Compression-.*)":
        "a sample format, size, width or compression that does not match the data",
    r"(las|las-stream|laz-autzen)/[xyz]_scale-.*": "a coordinate scale of 5e-324 .. 1e300",
    r"(las|las-stream|laz-autzen)/[xyz]_offset-(e300|-e300|e17)":
        "coordinates float64 cannot hold to their scale",
    r"map(-levine)?-yaml/resolution-(denormal|tiny|e300|-e300)": "cells of 5e-324 .. 1e300 m",
    r"map(-levine)?-yaml/origin_[xy]-(e300|-e300)": "a map 1e300 m from its frame's origin",
    r"(map-png|image-png|map-levine|image-bowl|image-valley)/palette-none":
        "colour type 3 without a palette",
    r"mcap/chunk\.rec\d+-\w+\.len-(past|end|huge)":
        "a record running past its chunk",
}  # fmt: skip


def must_refuse(name: str) -> str | None:
    """Why the case must be refused (None: it need not be)."""
    if name in MUST_REFUSE:
        return "issue 13"
    return next((why for p, why in MUST_REFUSE_28.items() if re.fullmatch(p, name)), None)


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


# --- issue 28: values no real file holds, offsets, duplicates, palettes -------------------------

#: A float64 header field set to the smallest denormal, a tiny value, and huge ones of either
#: sign (the labels name the values).
FLOATS = {"denormal": 5e-324, "tiny": 1e-300, "e300": 1e300, "-e300": -1e300}
#: The same for float32 fields and samples (1e-300 and 1e300 do not fit in 32 bits).
FLOATS32 = {"denormal": 1e-45, "tiny": 1e-38, "max": 3.4e38, "-max": -3.4e38}
#: The same as text, in a form every parser takes for a float (YAML 1.1 wants a dot and a signed
#: exponent; 4.9e-324 reads as the denormal 5e-324).
FLOAT_TEXTS = {
    "denormal": b"4.9e-324",
    "tiny": b"1.0e-300",
    "e300": b"1.0e+300",
    "-e300": b"-1.0e+300",
}


def fuzz_rounds() -> int:
    """SCAN2TERRAIN_FUZZ_ROUNDS (default 1): how many times each reader's random mutations
    are drawn, each round from its own seed."""
    text = os.environ.get("SCAN2TERRAIN_FUZZ_ROUNDS", "1")
    if not text.isdigit() or int(text) < 1:
        raise ValueError(f"SCAN2TERRAIN_FUZZ_ROUNDS must be a whole number >= 1, not {text!r}")
    return int(text)


#: The long run (SCAN2TERRAIN_FUZZ_ROUNDS > 1) tries every value of every field on every seed;
#: the short one, on the seeds whose cases are slow, one value per field (:func:`pick`).
EVERY_VALUE = fuzz_rounds() > 1


def pick(values: dict[str, Any], k: int, full: bool) -> dict[str, Any]:
    """All ``values``, or (``full`` False) only the ``k``-th, cycling: the k-th field of a seed
    gets the k-th value, so each field is tried and, over the fields, each value."""
    if full:
        return values
    label = list(values)[k % len(values)]
    return {label: values[label]}


def offsets(name: str, data: bytes, at: int, fmt: str) -> list[Mutation]:
    """An offset field pointing at the file's first byte and just past its end."""
    return packed(name, data, at, fmt, {"zero": 0, "end": len(data)})


LAS_DOUBLES = ("x_scale", "y_scale", "z_scale", "x_offset", "y_offset", "z_offset",
               "max_x", "min_x", "max_y", "min_y", "max_z", "min_z")  # fmt: skip


def las_number_mutations(data: bytes, *, full: bool = True) -> list[Mutation]:
    """Every double of the LAS header (scales, offsets, bounds, from byte 131) at each of
    FLOATS, scales also 1e10 and offsets 1e17 (the values of issue 28's report), or at one of
    them (:func:`pick`); the offset to the points at 0 and at the file's end."""
    out = []
    for i, name in enumerate(LAS_DOUBLES):
        extra = {"e10": 1e10} if "scale" in name else {"e17": 1e17} if "offset" in name else {}
        out += packed(name, data, 131 + 8 * i, "<d", pick({**FLOATS, **extra}, i, full))
    out += offsets("offset_to_points", data, 96, "<I")
    if data[25] >= 4:  # LAS 1.4: the first extended VLR
        out += offsets("first_evlr", data, 235, "<Q")
    return out


def laz_table_mutations(data: bytes) -> list[Mutation]:
    """The LAZ chunk table offset (the first 8 bytes of the point data) at 0 and at the end."""
    return offsets("table_offset", data, struct.unpack_from("<I", data, 96)[0], "<q")


def pcd_number_mutations(data: bytes) -> list[Mutation]:
    """Every numeric header line of a PCD (the first number of each, VIEWPOINT's qw too) at each
    of FLOAT_TEXTS; FIELDS with a name given twice; the first point's x at each of FLOATS32
    (binary) or FLOAT_TEXTS (ascii)."""
    out = []
    for key in ("VERSION", "SIZE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT", "POINTS"):
        out += texts(key, data, rb"\n" + key.encode() + rb" (\S+)", FLOAT_TEXTS)
    out += texts("VIEWPOINT-qw", data, rb"\nVIEWPOINT \S+ \S+ \S+ (\S+)", FLOAT_TEXTS)
    m = re.search(rb"\nFIELDS ([^\n]+)", data)
    assert m is not None
    names = m.group(1).split()
    out += texts("FIELDS", data, rb"\nFIELDS ([^\n]+)", {
        "dupfirst": b" ".join([names[0], *names[:-1]]),  # x x y z: every field moved along
        "dupy": b" ".join([*names[:-1], b"y"]),  # x y z y: the last one named y
    })  # fmt: skip
    end = after(data, b"\nDATA ")
    kind = data[data.index(b"\nDATA ") + 6 : end].strip()
    assert names[0] == b"x"
    if kind == b"binary":
        out += packed("x0", data, end, "<f", FLOATS32)
    elif kind == b"ascii":
        out += first_token("x0", data, end, FLOAT_TEXTS)
    return out


def first_token(name: str, data: bytes, start: int, values: dict[str, bytes]) -> list[Mutation]:
    """``data`` with its first word at or after ``start`` replaced by each value."""
    m = re.compile(rb"(\S+)").search(data, start)
    assert m is not None
    return [(f"{name}-{k}", data[: m.start()] + v + data[m.end() :]) for k, v in values.items()]


def ply_header_mutations(data: bytes) -> list[Mutation]:
    """A PLY's numbers (the vertex count, the format version) at each of FLOAT_TEXTS; the x
    property declared twice (added, or y renamed x); the face element declared before the
    vertex element; the first vertex's x at each of FLOAT_TEXTS (ascii) or FLOATS32."""
    out = texts("vertex", data, rb"element vertex (\S+)", FLOAT_TEXTS)
    out += texts("version", data, rb"format \S+ (\S+)", FLOAT_TEXTS)
    x = re.search(rb"property (\S+) x\n", data)
    assert x is not None
    out.append(("dup-x-added", data[: x.end()] + x.group(0) + data[x.end() :]))
    out += texts("dup-x", data, rb"property \S+ (y)\n", {"renamed": b"x"})
    face = re.search(rb"element face[^\n]*\n(?:property[^\n]*\n)*", data)
    if face is not None:
        vertex = data.index(b"element vertex")
        moved = data[: face.start()] + data[face.end() :]
        out.append(("face-first", moved[:vertex] + face.group(0) + moved[vertex:]))
    end = after(data, b"end_header")
    if b"format ascii" in data[:end]:
        out += first_token("x0", data, end, FLOAT_TEXTS)
    elif x.group(1) in (b"float", b"float32") and b"format binary_little_endian" in data[:end]:
        out += packed("x0", data, end, "<f", FLOATS32)
    return out


def yaml_number_mutations(data: bytes, *, full: bool = True) -> list[Mutation]:
    """A map YAML's numbers (resolution, each origin value, the thresholds) at each of
    FLOAT_TEXTS, or at one of them (:func:`pick`)."""
    out = texts("resolution", data, rb"resolution: (\S+)", pick(FLOAT_TEXTS, 0, full))
    m = re.search(rb"origin: \[([^\]]*)\]", data)
    assert m is not None
    parts = [p.strip() for p in m.group(1).split(b",")]
    for i, axis in enumerate(("x", "y", "yaw")):
        for label, text in pick(FLOAT_TEXTS, i + 1, full).items():
            values = b", ".join(text if k == i else p for k, p in enumerate(parts))
            out.append((f"origin_{axis}-{label}", data[: m.start(1)] + values + data[m.end(1) :]))
    out += texts("occupied", data, rb"occupied_thresh: (\S+)", pick(FLOAT_TEXTS, 4, full))
    out += texts("free", data, rb"free_thresh: (\S+)", pick(FLOAT_TEXTS, 5, full))
    return out


def png_ihdr(data: bytes, **fields: int) -> bytes:
    """The PNG with IHDR's one-byte fields (depth, ctype, method, filter, interlace) replaced,
    its CRC recomputed."""
    b = bytearray(data)
    for name, value in fields.items():
        b[24 + ("depth", "ctype", "method", "filter", "interlace").index(name)] = value
    struct.pack_into(">I", b, 29, zlib.crc32(bytes(b[12:29])))
    return bytes(b)


def png_chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def png_format_mutations(data: bytes) -> list[Mutation]:
    """Palette and bit-depth changes, every chunk's CRC right: colour type 3 without a PLTE, with
    a 256-entry grey one (a valid file when the image is 8-bit grey) and with a 2-entry one; a
    PLTE in a grey image; the bit depth and colour type changed under the data; interlacing
    and an unknown filter method declared."""
    ctype, depth = data[25], data[24]
    grey = bytes(np.repeat(np.arange(256, dtype=np.uint8), 3))
    indexed = png_ihdr(data, ctype=3)
    out = [
        ("palette-none", indexed),
        ("palette-grey", indexed[:33] + png_chunk(b"PLTE", grey) + indexed[33:]),
        ("palette-short", indexed[:33] + png_chunk(b"PLTE", grey[:6]) + indexed[33:]),
    ]
    if ctype in (0, 4):
        out.append(("palette-on-grey", data[:33] + png_chunk(b"PLTE", grey) + data[33:]))
    out += [(f"depth{d}", png_ihdr(data, depth=d)) for d in (1, 2, 4) if d != depth]
    out += [(f"ctype{c}", png_ihdr(data, ctype=c)) for c in (0, 2, 4, 6) if c != ctype]
    out.append(("interlace", png_ihdr(data, interlace=1)))
    out.append(("filter-bad", png_ihdr(data, filter=1)))
    return out


#: Names of the TIFF tags the DEM mutations touch.
TIFF_TAGS = {256: "ImageWidth", 257: "ImageLength", 258: "BitsPerSample", 259: "Compression",
             273: "StripOffsets", 277: "SamplesPerPixel", 278: "RowsPerStrip",
             279: "StripByteCounts", 339: "SampleFormat", 33550: "ModelPixelScale",
             33922: "ModelTiepoint", 34735: "GeoKeyDirectory", 34736: "GeoDoubleParams",
             34737: "GeoAsciiParams", 42112: "GDAL_METADATA", 42113: "GDAL_NODATA"}  # fmt: skip
#: Values of one-number TIFF tags: a 1-pixel raster, sample sizes, compressions and sample
#: formats that do not match the data.
TIFF_VALUES: dict[int, dict[str, int]] = {
    256: {"one": 1},
    257: {"zero": 0, "one": 1},
    258: {"8": 8, "16": 16, "64": 64},
    259: {"lzw": 5, "jpeg": 7, "packbits": 32773},
    277: {"zero": 0, "two": 2},
    278: {"zero": 0, "one": 1},
    339: {"uint": 1, "int": 2, "void": 4, "complex": 6},
}
TIFF_SIZES = {1: 1, 2: 1, 3: 2, 4: 4, 12: 8}  # BYTE, ASCII, SHORT, LONG, DOUBLE


def tiff_field_mutations(data: bytes) -> list[Mutation]:
    """A GeoTIFF's numbers: every double (pixel scale, tie point, geo parameters) at each of
    FLOATS; the first and last strip offsets, and every tag's offset to its values, at 0 and
    at the file's end; a strip byte count 0 or huge; the tags of TIFF_VALUES at theirs;
    GDAL_NODATA as each of FLOAT_TEXTS; the IFD offset at the file's end."""
    out = offsets("ifd", data, 4, "<I")[1:]  # 0: an existing case
    for code, entry in tiff_entries(data).items():
        kind, count = struct.unpack_from("<HI", data, entry + 2)
        if kind not in TIFF_SIZES:
            continue
        name = TIFF_TAGS.get(code, str(code))
        inline = count * TIFF_SIZES[kind] <= 4
        at = entry + 8 if inline else struct.unpack_from("<I", data, entry + 8)[0]
        if not inline:
            out += offsets(f"{name}@", data, entry + 8, "<I")
        fmt = {3: "<H", 4: "<I"}.get(kind)
        if kind == 12:
            for i in range(count):
                out += packed(f"{name}{i}", data, at + 8 * i, "<d", FLOATS)
        elif code == 273 and fmt:
            out += offsets(f"{name}0", data, at, fmt)
            if count > 1:
                out += offsets(f"{name}{count - 1}", data, at + (count - 1) * TIFF_SIZES[kind], fmt)
        elif code == 279 and fmt:
            out += packed(
                f"{name}0", data, at, fmt, {"zero": 0, "huge": (1 << (8 * TIFF_SIZES[kind])) - 1}
            )
        elif code in TIFF_VALUES and fmt and count == 1:
            out += packed(name, data, at, fmt, TIFF_VALUES[code])
        elif code == 42113:  # GDAL_NODATA: text, NUL-padded in its own space
            out += [
                (
                    f"{name}-{label}",
                    data[:at] + text.ljust(count, b"\0")[:count] + data[at + count :],
                )
                for label, text in FLOAT_TEXTS.items()
            ]
    return out


MCAP_RECORDS = {1: "Header", 2: "Footer", 3: "Schema", 4: "Channel", 5: "Message", 6: "Chunk",
                7: "MessageIndex", 8: "ChunkIndex", 9: "Attachment", 10: "AttachmentIndex",
                11: "Statistics", 12: "Metadata", 13: "MetadataIndex", 14: "SummaryOffset",
                15: "DataEnd"}  # fmt: skip


def mcap_records(data: bytes, start: int, end: int) -> Iterator[tuple[int, int, int]]:
    """(offset, opcode, length) of the records in ``data[start:end]``."""
    pos = start
    while pos + 9 <= end:
        op, length = struct.unpack_from("<BQ", data, pos)
        yield pos, op, length
        pos += 9 + length


def _after_string(data: bytes, at: int) -> int:
    """The offset after the uint32-prefixed string (or map, or array) at ``at``."""
    (size,) = struct.unpack_from("<I", data, at)
    return at + 4 + int(size)


def mcap_fields(data: bytes, pos: int, op: int) -> list[tuple[str, int, str, str]]:
    """(name, offset, format, kind) of a record's offsets, lengths, counts and ids."""
    b = pos + 9
    if op == 2:
        return [
            ("summary_start", b, "<Q", "offset"),
            ("summary_offset_start", b + 8, "<Q", "offset"),
        ]
    if op == 3:
        return [("id", b, "<H", "id")]
    if op == 4:
        return [("id", b, "<H", "id"), ("schema_id", b + 2, "<H", "id")]
    if op == 5:
        return [("channel_id", b, "<H", "id")]
    if op == 6:
        records = _after_string(data, b + 28)
        return [
            ("uncompressed_size", b + 16, "<Q", "length"),
            ("records_length", records, "<Q", "length"),
        ]
    if op == 7 and struct.unpack_from("<I", data, b + 2)[0]:
        return [("offset0", b + 2 + 4 + 8, "<Q", "offset")]
    if op == 8:
        after_map = _after_string(data, b + 32)
        sizes = _after_string(data, after_map + 8)
        out = [("chunk_start", b + 16, "<Q", "offset"), ("chunk_length", b + 24, "<Q", "length"),
               ("message_index_length", after_map, "<Q", "length"),
               ("compressed_size", sizes, "<Q", "length"),
               ("uncompressed_size", sizes + 8, "<Q", "length")]  # fmt: skip
        if after_map > b + 36:
            out.append(("message_index_offset", b + 36 + 2, "<Q", "offset"))
        return out
    if op == 11:
        return [("message_count", b, "<Q", "count"), ("channel_count", b + 10, "<I", "count"),
                ("chunk_count", b + 22, "<I", "count")]  # fmt: skip
    if op == 13:
        return [("offset", b, "<Q", "offset"), ("length", b + 8, "<Q", "length")]
    if op == 14:
        return [("group_start", b + 1, "<Q", "offset"), ("group_length", b + 9, "<Q", "length")]
    return []


def mcap_field_values(kind: str, fmt: str, size: int) -> dict[str, int]:
    top = (1 << (8 * struct.calcsize(fmt))) - 1
    return {
        "offset": {"zero": 0, "end": size},
        "length": {"zero": 0, "end": size, "huge": top},
        "count": {"zero": 0, "huge": top},
        "id": {"huge": top},
    }[kind]


def mcap_field_mutations(data: bytes, *, full: bool = True) -> list[Mutation]:
    """Of the first record of each kind: its length 0 and running past the file's end, and its
    offsets (to 0, to the file's end), lengths, counts and ids; inside the first uncompressed
    chunk (its CRC recomputed when it has one), the first, second and last records' lengths
    0, one byte past the chunk, past the file and huge, and the first message's channel id;
    a compressed chunk's compression renamed. ``full`` False: one value each (:func:`pick`)."""
    out: list[Mutation] = []
    seen: set[int] = set()
    k = 0
    for pos, op, _ in mcap_records(data, 8, len(data) - 8):
        if op in seen:
            continue
        seen.add(op)
        name = MCAP_RECORDS.get(op, f"op{op}")
        lengths = pick({"zero": 0, "past": len(data) - pos - 8}, k, full)
        out += packed(f"{name}.len", data, pos + 1, "<Q", lengths)
        for field, at, fmt, kind in mcap_fields(data, pos, op):
            k += 1
            values = pick(mcap_field_values(kind, fmt, len(data)), k, full)
            out += packed(f"{name}.{field}", data, at, fmt, values)
        if op == 6:
            out += _chunk_mutations(data, pos, full)
    return out


def _chunk_mutations(data: bytes, pos: int, full: bool) -> list[Mutation]:
    b = pos + 9
    compression_at = b + 28
    compression = data[compression_at + 4 : _after_string(data, compression_at)]
    if compression:
        renamed = b"none"[: len(compression)].ljust(len(compression), b"x")
        return [
            (
                "Chunk.compression-none",
                data[: compression_at + 4]
                + renamed
                + data[compression_at + 4 + len(compression) :],
            )
        ]
    length_at = _after_string(data, compression_at)
    start = length_at + 8
    end = start + struct.unpack_from("<Q", data, length_at)[0]
    crc = struct.unpack_from("<I", data, b + 24)[0]

    def with_crc(buf: bytearray) -> bytes:
        if crc:
            struct.pack_into("<I", buf, pos + 9 + 24, zlib.crc32(bytes(buf[start:end])))
        return bytes(buf)

    inner = list(mcap_records(data, start, end))
    out = []
    for k, (at, op, _) in enumerate(inner):
        if k not in (0, 1, len(inner) - 1):
            continue
        name = f"chunk.rec{k}-{MCAP_RECORDS.get(op, op)}.len"
        past = {
            "zero": 0,
            "past": end - at - 9 + 1,
            "end": len(data) - at - 9,
            "huge": (1 << 64) - 1,
        }
        for label, value in pick(past, k, full).items():
            b2 = bytearray(data)
            struct.pack_into("<Q", b2, at + 1, value)
            out.append((f"{name}-{label}", with_crc(b2)))
    message = next((at for at, op, _ in inner if op == 5), None)
    if message is not None:
        b2 = bytearray(data)
        struct.pack_into("<H", b2, message + 9, 0xFFFF)
        out.append(("chunk.Message.channel_id-huge", with_crc(b2)))
    return out


def mcap_deep_mutations(data: bytes, rng: random.Random, *, full: bool = True) -> list[Mutation]:
    return mcap_mutations(data, rng) + mcap_field_mutations(data, full=full)


def metadata_mutations(data: bytes, rng: random.Random) -> list[Mutation]:
    """A rosbag2 metadata.yaml: binary bytes in it (issue 28: two error lines), a NUL, numbers
    out of range."""
    out = [
        ("binary", data[:200] + rng.randbytes(64) + data[200:]),
        ("nul", data.replace(b": ", b":\0", 1)),
    ]
    out += texts(
        "version", data, rb"\n  version: (\S+)", {"zero": b"0", "huge": b"99999999999999999999"}
    )
    out += texts("message_count", data, rb"\n  message_count: (\S+)", {"neg": b"-1", **FLOAT_TEXTS})
    out += texts("duration", data, rb"nanoseconds: (\S+)", {"neg": b"-5", "e300": b"1.0e+300"})
    out += flips(data, rng, 3)
    return out


# --- point clouds -------------------------------------------------------------------------------


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
    out = las_header_mutations(data) + truncations(data, 227, 400) + flips(data, rng, 3)
    return out + las_number_mutations(data)


def las_stream_mutations(data: bytes, rng: random.Random) -> list[Mutation]:
    """The scales and offsets (``--stream`` reads its own way, issue 28: a scale of 1e10 was
    an exit 1 there), and random flips."""
    keep = ("x_scale", "y_scale", "z_scale", "x_offset", "y_offset", "z_offset")
    return [m for m in las_number_mutations(data) if m[0].startswith(keep)] + flips(data, rng, 2)


def laz_autzen_mutations(data: bytes, rng: random.Random) -> list[Mutation]:
    out = las_number_mutations(data, full=EVERY_VALUE) + laz_table_mutations(data)
    return out + flips(data, rng, 2, lo=227) + truncations(data, len(data) * 3 // 4)


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
    return out + laz_table_mutations(data)


def laz14_file() -> bytes:
    """A LAS 1.4 point format 6 LAZ (LASzip's layered chunks, a 64-bit point count)."""
    import io

    import laspy  # type: ignore[import-untyped]

    pts = points(500)
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
    pts = points(200)
    head = (
        "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 4\nTYPE F F F F\n"
        f"COUNT 1 1 1 1\nWIDTH {len(pts)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\n"
        f"POINTS {len(pts)}\nDATA ascii\n"
    )
    return (head + "".join(f"{x:.4f} {y:.4f} {z:.4f} 7\n" for x, y, z in pts)).encode()


def pcd_compressed(folder: Path) -> tuple[Path, Path]:
    import open3d

    cloud = open3d.geometry.PointCloud(open3d.utility.Vector3dVector(points(400)))
    path = folder / "compressed.pcd"
    assert open3d.io.write_point_cloud(path, cloud, write_ascii=False, compressed=True)
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
    return out + pcd_number_mutations(data)


def ply_ascii() -> bytes:
    pts = points(200)
    head = (
        "ply\nformat ascii 1.0\nelement vertex 200\nproperty float x\nproperty float y\n"
        "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
    )
    rows = "".join(f"{x:.4f} {y:.4f} {z:.4f}\n" for x, y, z in pts)
    return (head + rows + "3 0 1 2\n").encode()


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
    return out + ply_header_mutations(data)


def text_cloud(header: str, sep: str) -> Callable[[], bytes]:
    def data() -> bytes:
        rows = "".join(f"{x:.4f}{sep}{y:.4f}{sep}{z:.4f}{sep}3\n" for x, y, z in points(200))
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
    for label, value in FLOAT_TEXTS.items():  # every value of a row (x, y, z wherever they are)
        b = list(lines)
        b[3] = sep.join(value for _ in b[3].split(sep))
        out.append((f"row-all-{label}", b"\n".join(b)))
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


def yaml_mutations(data: bytes, rng: random.Random, *, full: bool = True) -> list[Mutation]:
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
    return out + yaml_number_mutations(data, full=full)


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
    width, height = struct.unpack_from(">II", data, 16)
    out.append(("ihdr-depth16", png_with_ihdr(data, width, height, 16)))
    out.append(("ihdr-badcrc", data[:16] + b"\0\0\1\0" + data[20:]))
    out += flips(data, rng, 3, lo=idat + 8)
    out += splices(data, rng, 2, lo=idat)
    return out + png_format_mutations(data)


def image_file(folder: Path) -> tuple[Path, Path]:
    from PIL import Image

    y, x = np.mgrid[0:33, 0:33]
    path = folder / "hill.png"
    Image.fromarray(((x * y) % 256).astype(np.uint8)).save(path)
    return path, path


# --- DEM ----------------------------------------------------------------------------------------


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
    return out + tiff_field_mutations(data)


# --- octrees and scans --------------------------------------------------------------------------


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


# --- seeds cut from the fixtures (issue 28) -----------------------------------------------------


def autzen_laz() -> bytes:
    """pc_laz_autzen_trim (110,000 points, 603 KB) cut to every 37th point (2,973 points, 39 KB):
    its header, CRS VLRs and point format 3 kept, compressed again by laspy/lazrs."""
    import io

    import laspy

    with laspy.open(AUTZEN) as f:
        las = f.read()
    small = laspy.LasData(las.header)
    small.points = laspy.ScaleAwarePointRecord(
        np.ascontiguousarray(las.points.array[::37]),
        las.header.point_format,
        las.header.scales,
        las.header.offsets,
    )
    out = io.BytesIO()
    small.write(out, do_compress=True)
    return out.getvalue()


def every_row(src: Path, step: int) -> Callable[[], bytes]:
    """A binary PLY or PCD fixture (fixed-size rows) cut to every ``step``-th row: its header as
    is but for the counts (``element vertex``; ``WIDTH`` and ``POINTS``)."""

    def data() -> bytes:
        raw = src.read_bytes()
        ply = raw.startswith(b"ply")
        end = after(raw, b"end_header") if ply else after(raw, b"\nDATA ")
        key = rb"element vertex (\d+)" if ply else rb"\nPOINTS (\d+)"
        m = re.search(key, raw)
        assert m is not None
        count = int(m.group(1))
        size = (len(raw) - end) // count
        assert size * count == len(raw) - end
        rows = np.frombuffer(raw, dtype=f"V{size}", offset=end)[::step]
        head = raw[:end]
        for pattern in (key,) if ply else (key, rb"\nWIDTH (\d+)"):
            m = re.search(pattern, head)
            assert m is not None
            head = head[: m.start(1)] + str(len(rows)).encode() + head[m.end(1) :]
        return head + rows.tobytes()

    return data


def every_line(src: Path, step: int) -> Callable[[], bytes]:
    """A text cloud fixture cut to every ``step``-th line."""

    def data() -> bytes:
        lines = src.read_bytes().splitlines(keepends=True)
        return b"".join(lines[::step])

    return data


def lzf_decompress(src: bytes, size: int) -> bytes:
    """LZF (liblzf's format, PCD's binary_compressed): literal runs and back references. A
    loop over a test fixture's tokens, run once."""
    out = bytearray()
    i = 0
    while i < len(src):
        c = src[i]
        i += 1
        if c < 32:  # a literal run of c + 1 bytes
            out += src[i : i + c + 1]
            i += c + 1
            continue
        length = c >> 5
        if length == 7:
            length += src[i]
            i += 1
        ref = len(out) - ((c & 31) << 8) - src[i] - 1
        i += 1
        for k in range(length + 2):  # may overlap what it writes
            out.append(out[ref + k])
    assert len(out) == size
    return bytes(out)


def lzf_literal(raw: bytes) -> bytes:
    """``raw`` as a valid LZF stream of literal runs only (32 bytes each)."""
    return b"".join(
        bytes([len(raw[i : i + 32]) - 1]) + raw[i : i + 32] for i in range(0, len(raw), 32)
    )


def office_pcd() -> bytes:
    """pc_pcl_office1_organized (640 x 480, binary_compressed, 1.9 MB) cut to its rows 236..243:
    640 x 8 organized points, NaNs (no return) included, its header as is but the sizes, and
    binary_compressed again (each field's column, LZF literal runs)."""
    raw = OFFICE.read_bytes()
    end = after(raw, b"\nDATA ")
    packed_size, size = struct.unpack_from("<II", raw, end)
    columns = np.frombuffer(lzf_decompress(raw[end + 8 : end + 8 + packed_size], size), "<f4")
    cut = columns.reshape(4, 480, 640)[:, 236:244, :]
    body = np.ascontiguousarray(cut).tobytes()
    head = raw[:end].replace(b"HEIGHT 480", b"HEIGHT 8").replace(b"POINTS 307200", b"POINTS 5120")
    block = lzf_literal(body)
    return head + struct.pack("<II", len(block), len(body)) + block


def png_chunks(raw: bytes) -> list[bytes]:
    """A PNG's chunks, each with its length, type and CRC."""
    out, pos = [], 8
    while pos < len(raw):
        out.append(raw[pos : pos + 12 + struct.unpack_from(">I", raw, pos)[0]])
        pos += len(out[-1])
    return out


def levine_files(folder: Path) -> tuple[Path, Path]:
    """map_levine_thinwalls (2048 x 2048 px, 13 KB) cut to the 512 x 256 px around its walls
    (pixels 800..1312 x 960..1216): its YAML as is, the PNG's own ancillary chunks (gAMA, bKGD,
    tIME, orNT, tEXt) kept around a new IHDR and IDAT."""
    import io

    from PIL import Image

    src = LEVINE_DIR
    raw = (src / "levine.png").read_bytes()
    with Image.open(io.BytesIO(raw)) as im:
        buf = io.BytesIO()
        im.crop((800, 960, 1312, 1216)).save(buf, format="PNG")
    fresh = png_chunks(buf.getvalue())
    kept = [c for c in png_chunks(raw) if c[4:8] not in (b"IHDR", b"IDAT", b"IEND")]
    (folder / "levine.png").write_bytes(raw[:8] + fresh[0] + b"".join(kept + fresh[1:]))
    shutil.copyfile(src / "levine.yaml", folder / "levine.yaml")
    return folder / "levine.yaml", folder / "levine.png"


def levine_yaml(folder: Path) -> tuple[Path, Path]:
    yaml_path, _ = levine_files(folder)
    return yaml_path, yaml_path


def embark_bag(folder: Path) -> tuple[Path, Path]:
    """bag2_derived_embark_luminar_mcap (2.9 MB) with each of its 5 Luminar clouds cut to every
    k-th of its points (2,000 points each): its messages, schemas, channels, metadata record
    and metadata.yaml as they were, written again with the mcap library (zstd chunks of 64
    KiB; 190 KB)."""
    import dataclasses

    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    src = EMBARK_MCAP
    bag = folder / src.name
    bag.mkdir()
    shutil.copyfile(src / "metadata.yaml", bag / "metadata.yaml")
    name = f"{src.name}.mcap"
    with (src / name).open("rb") as f, (bag / name).open("wb") as g:
        reader = make_reader(f)
        header = reader.get_header()
        writer = Writer(g, compression=CompressionType.ZSTD, chunk_size=64 * 1024)
        writer.start(profile=header.profile, library=header.library)
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, msg in reader.iter_messages(log_time_order=False):
            assert schema is not None
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(
                    schema.name, schema.encoding, schema.data
                )
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas[schema.id], channel.metadata
                )
            data: bytes | memoryview = msg.data
            if schema.name == "sensor_msgs/msg/PointCloud2":
                cloud = ros_msg(ts.deserialize_cdr(data, schema.name))
                rows = np.frombuffer(cloud.data, np.uint8).reshape(-1, cloud.point_step)
                rows = rows[:: max(1, len(rows) // 2000)][:2000]
                cloud = dataclasses.replace(
                    cloud, height=1, width=len(rows), row_step=rows.size,
                    data=np.ascontiguousarray(rows).reshape(-1),
                )  # fmt: skip
                data = ts.serialize_cdr(cloud, schema.name)
            writer.add_message(
                channels[channel.id], msg.log_time, bytes(data), msg.publish_time, msg.sequence
            )
        for record in reader.iter_metadata():
            writer.add_metadata(record.name, record.metadata)
        writer.finish()  # type: ignore[no-untyped-call]
    return bag, bag / name


def embark_metadata(folder: Path) -> tuple[Path, Path]:
    bag, _ = embark_bag(folder)
    return bag, bag / "metadata.yaml"


def nav2_bag(folder: Path) -> tuple[Path, Path]:
    """bag2_nav2_collision_mcap_zstd (a whole-file zstd MCAP, 2.4 MB inside) decompressed and
    cut to its first 8 messages of each topic, in uncompressed chunks of 16 KiB (98 KB); its
    metadata.yaml as is but for the compression, the file name and the counts."""
    import io

    import yaml
    import zstandard
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    src = NAV2
    bag = folder / src.name
    bag.mkdir()
    packed_file = (src / "_tmp_cm_bag_0.mcap.zstd").read_bytes()
    raw = zstandard.ZstdDecompressor().decompress(packed_file, max_output_size=1 << 26)
    reader = make_reader(io.BytesIO(raw))
    header = reader.get_header()
    counts: dict[str, int] = {}
    with (bag / "_tmp_cm_bag_0.mcap").open("wb") as g:
        writer = Writer(g, compression=CompressionType.NONE, chunk_size=16 * 1024)
        writer.start(profile=header.profile, library=header.library)
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, msg in reader.iter_messages(log_time_order=False):
            assert schema is not None
            if counts.get(channel.topic, 0) >= 8:
                continue
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(
                    schema.name, schema.encoding, schema.data
                )
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas[schema.id], channel.metadata
                )
            writer.add_message(
                channels[channel.id], msg.log_time, msg.data, msg.publish_time, msg.sequence
            )
        for record in reader.iter_metadata():
            writer.add_metadata(record.name, record.metadata)
        writer.finish()  # type: ignore[no-untyped-call]
    meta = yaml.safe_load((src / "metadata.yaml").read_text())
    info = meta["rosbag2_bagfile_information"]
    info["compression_format"] = info["compression_mode"] = ""
    info["relative_file_paths"] = ["_tmp_cm_bag_0.mcap"]
    for topic in info["topics_with_message_count"]:
        topic["message_count"] = counts[topic["topic_metadata"]["name"]]
    info["message_count"] = info["files"][0]["message_count"] = sum(counts.values())
    (bag / "metadata.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    return bag, bag / "_tmp_cm_bag_0.mcap"


def sick_bag(folder: Path) -> tuple[Path, Path]:
    """bag2_derived_sick_lms1xx_db3 (442 messages, 1.3 MB) cut to the first 12 messages of each
    topic, written again by rosbags (sqlite3, 205 KB)."""
    from rosbags.rosbag2 import Reader, StoragePlugin, Writer

    src = SICK_DB3
    bag = folder / src.name
    counts: dict[str, int] = {}
    with Reader(src) as reader, Writer(bag, version=9, storage_plugin=StoragePlugin.SQLITE3) as w:
        conns = {
            c.id: w.add_connection(
                c.topic, c.msgtype, msgdef=c.msgdef.data, rihs01=c.digest,
                serialization_format=c.ext.serialization_format,  # type: ignore[union-attr]
                offered_qos_profiles=c.ext.offered_qos_profiles,  # type: ignore[union-attr]
            )
            for c in reader.connections
        }  # fmt: skip
        for conn, t, raw in reader.messages():
            if counts.get(conn.topic, 0) < 12:
                counts[conn.topic] = counts.get(conn.topic, 0) + 1
                w.write(conns[conn.id], t, raw)
    return bag, next(bag.glob("*.db3"))


def copy_folder(src: Path, storage: str) -> Callable[[Path], tuple[Path, Path]]:
    """A fixture folder (a rosbag2 bag) copied whole; ``storage`` is the file mutated."""

    def make(folder: Path) -> tuple[Path, Path]:
        dst = folder / src.name
        shutil.copytree(src, dst)
        return dst, dst / storage

    return make


def inspect(src: Path, out: Path) -> list[str]:
    return ["inspect", str(src)]


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


def with_options(
    argv: Callable[[Path, Path], list[str]], *extra: str
) -> Callable[[Path, Path], list[str]]:
    return lambda src, out: [*argv(src, out), *extra]


def world(command: str, *extra: str) -> Callable[[Path, Path], list[str]]:
    def argv(src: Path, out: Path) -> list[str]:
        return [command, str(src), "-o", str(out), "--simulator", "gz", *extra]

    return argv


def copy_fixture(src: Path) -> Callable[[Path], tuple[Path, Path]]:
    def make(folder: Path) -> tuple[Path, Path]:
        dst = folder / src.name
        shutil.copyfile(src, dst)
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

        return points_bytes(points(300), suffix)

    return data


BAG2WORLD = world("bag2world", "--resolution", "0.2", "--no-preview")
FIXED = ("--pose", "0", "0", "0", "0", "0", "0")
EMBARK_CONVERT = with_options(convert, "--topic", "/luminar_pointcloud", *FIXED)
EMBARK_WORLD = world("bag2world", "--topic", "/luminar_pointcloud", *FIXED, "--grid", "height",
                     "--resolution", "0.5", "--no-preview", "--no-fidelity")  # fmt: skip
SICK_CONVERT = with_options(convert, "--topic", "/cloud", "--fixed-frame", "cloud")
SICK_WORLD = world("bag2world", "--topic", "/sick_lms_1xx/scan", "--fixed-frame", "cloud",
                   "--no-preview", "--no-fidelity")  # fmt: skip
READERS = [
    Reader("las", copy_fixture(SIMPLE_LAS), convert, "o.xyz",
           las_mutations),
    Reader("laz", copy_fixture(SIMPLE_LAZ), convert, "o.xyz",
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
    Reader("dem", copy_fixture(MOON),
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
    Reader("mcap", bag("mcap", "tf"), convert, "o.xyz", mcap_deep_mutations),
    Reader("mcap-ros1", mcap_of("ros1"), convert, "o.xyz", mcap_mutations),
    Reader("mcap-foxglove", mcap_of("foxglove"), BAG2WORLD, "o", mcap_mutations),
    # issue 28: seeds from every fixture DEM, LAS/LAZ, PLY, PCD, CSV/XYZ, MCAP, db3 and PNG
    Reader("dem-sfbay", copy_fixture(SFBAY),
           world("dem2world"), "o", dem_mutations),
    Reader("las-stream", copy_fixture(SIMPLE_LAS),
           world("cloud2world", "--stream", "--resolution", "10", "--no-preview"), "o",
           las_stream_mutations),
    Reader("laz-autzen", written("autzen.laz", autzen_laz),
           world("cloud2world", "--resolution", "2", "--no-preview"), "o",
           laz_autzen_mutations),
    Reader("ply-hdl32", written("target.ply",
                                every_row(HDL_PLY, 23)),
           world("cloud2world", "--resolution", "0.2", "--no-preview"), "o", ply_mutations),
    Reader("pcd-hdl32", written("scan.pcd",
                                every_row(HDL_PCD, 23)),
           convert, "o.xyz", pcd_mutations),
    Reader("pcd-office", written("office1.pcd", office_pcd), convert, "o.xyz", pcd_mutations),
    Reader("xyz-street",
           written("street.xyz",
                   every_line(STREET, 11)),
           convert, "o.ply", text_mutations),
    Reader("csv-autzen",
           copy_fixture(AUTZEN_CSV),
           world("cloud2world", "--resolution", "5", "--no-preview"), "o", text_mutations),
    Reader("map-levine", levine_files, world("map2world", "--no-preview"), "o", png_mutations),
    Reader("map-levine-yaml", levine_yaml, world("map2world", "--no-preview"), "o",
           lambda d, r: yaml_mutations(d, r, full=EVERY_VALUE)),
    Reader("image-bowl", copy_fixture(BOWL),
           world("image2world", "--resolution", "0.1"), "o", png_mutations),
    Reader("image-valley", copy_fixture(VALLEY),
           world("image2world", "--resolution", "0.1", "--no-preview"), "o", png_mutations),
    Reader("mcap-embark", embark_bag, EMBARK_CONVERT, "o.xyz",
           lambda d, r: mcap_deep_mutations(d, r, full=EVERY_VALUE)),
    Reader("mcap-embark-world", embark_bag, EMBARK_WORLD, "o",
           lambda d, r: mcap_deep_mutations(d, r, full=EVERY_VALUE)[::4]),
    Reader("rosbag2-metadata", embark_metadata, EMBARK_CONVERT, "o.xyz", metadata_mutations),
    Reader("mcap-nav2", nav2_bag, inspect, "o",
           lambda d, r: mcap_deep_mutations(d, r, full=EVERY_VALUE)),
    Reader("db3-sick", sick_bag, SICK_CONVERT, "o.xyz", sqlite_mutations),
    Reader("db3-sick-world", sick_bag, SICK_WORLD, "o", lambda d, r: sqlite_mutations(d, r)[::2]),
    Reader("db3-gridmap", copy_folder(GRIDMAP, "grid_map_bag.db3"),
           inspect, "o", sqlite_mutations),
]  # fmt: skip


@dataclass(frozen=True)
class Built:
    """A case, the folder of its input (``in``) and what its command writes (``output``)."""

    reader: str
    case: Case
    input_dir: Path
    output: Path


def mutations_of(seed: int, reader: Reader, original: bytes, rounds: int) -> list[Mutation]:
    """The reader's mutations of round 0 (seed ``seed``), then those of rounds 1.. that differ
    from round 0's of the same name (the random ones: flips, splices; the same draws each run),
    named ``<name>@<round>``."""
    first = reader.mutate(original, random.Random(seed))
    out = [("original", original), *first]
    known = dict(first)
    for r in range(1, rounds):
        again = reader.mutate(original, random.Random(seed + 1000 * r))
        out += [(f"{name}@{r}", data) for name, data in again if known.get(name) != data]
    return out


def build_cases(root: Path, rounds: int = 1) -> list[Built]:
    """Every reader's good input and its mutations, each in its own folder (``in``) with an
    empty ``out`` folder beside it."""
    built = []
    for seed, reader in enumerate(READERS):
        good = root / reader.name / "good"
        good.mkdir(parents=True)
        given, target = reader.make(good)
        original = target.read_bytes()
        mutations = mutations_of(seed, reader, original, rounds)
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
            case = Case(f"{reader.name}/{name}", argv, str(out))
            built.append(Built(reader.name, case, case_dir, out / reader.out_name))
    return built


@pytest.fixture(scope="module")
def outcomes(tmp_path_factory: pytest.TempPathFactory) -> dict[str, list[tuple[Built, Outcome]]]:
    root = tmp_path_factory.mktemp("mutations")
    built = build_cases(root, fuzz_rounds())
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
    if o.cpu_seconds > CPU_BUDGET_S:
        found.append(f"{o.cpu_seconds:.0f} s of CPU, over {CPU_BUDGET_S:g} s")
    if o.exit == 0 and (why := must_refuse(o.name)):
        found.append(f"read, but must be refused: {why}")
    if o.exit == 0:  # read: what it wrote must make sense (tests/output_sanity.py)
        found += [f"output: {p}" for p in output_problems(built.output)]
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
    fixed = [o.name for b, o in cases if o.name in KNOWN_BUGS and not problems(b, o)]
    assert not fixed, f"known bugs no longer fail, remove them from KNOWN_BUGS: {fixed}"
    assert any(o.exit == 2 for _, o in cases)  # the mutations do reach the reader


def test_must_refuse_names_cases(outcomes: dict[str, list[tuple[Built, Outcome]]]) -> None:
    names = {o.name for cases in outcomes.values() for _, o in cases}
    assert not (MUST_REFUSE - names), sorted(MUST_REFUSE - names)
    unused = [p for p in MUST_REFUSE_28 if not any(re.fullmatch(p, n) for n in names)]
    assert not unused, unused
    assert not (set(KNOWN_BUGS) - names), sorted(set(KNOWN_BUGS) - names)
