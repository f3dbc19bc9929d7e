"""Point-cloud files -> float64 points: PCD, PLY, XYZ-style text, CSV, LAS and LAZ.

Which library reads what, and why:

* ``.pcd`` (``DATA ascii`` / ``binary``) and ``.ply`` (ascii, binary of either byte order): the
  header is parsed and checked here and the data decoded with numpy (a structured dtype over the
  bytes, ``numpy.loadtxt`` for ASCII), keeping float64 for double properties. Open3D
  (``open3d.io.read_point_cloud``) decodes what numpy cannot do without a loop: PCD
  ``binary_compressed`` (LZF) and PLY files with list properties before or inside the vertex
  element. Open3D is not used for everything because on bad input it prints to the console and
  returns no points, or (short ASCII PCD/PLY data, truncated binary PLY; Open3D 0.20) returns
  uninitialised memory as points; so sizes are checked before it is called wherever the header
  allows, its point count afterwards, and its import (~1.5 s) is paid only when needed.
* ``.xyz .xyzn .xyzrgb .pts .txt .csv``: ``numpy.loadtxt`` (its C parser, no loop per row). A
  header line picks the x/y/z columns by name (``x``, ``X``, ``"X"``, ``//X``, in any order);
  without one the first three columns are x, y, z. Open3D skips unreadable lines silently and
  reads neither ``.txt`` nor ``.csv``.
* ``.las .laz``: laspy (LAZ through its lazrs backend), read chunk by chunk; coordinates are the
  scaled float64 ``x, y, z`` (UTM eastings ~5e6 m lose centimetres in float32). Before laspy
  opens a file its header and (LAZ) chunk table are checked here against the file's size, from
  the raw bytes: laspy reads VLRs by a count and lazrs allocates a chunk table by another, and a
  corrupt count made them take all memory or abort the process (a Rust allocation failure is
  not an exception). A Rust panic in lazrs (pyo3's ``PanicException``, a ``BaseException``) is
  caught too and refused like any corrupt file.

Points are returned as the file stores them (no ``VIEWPOINT`` or CRS applied, as PCL and Open3D
do); every problem is an :class:`InputError` naming the file.
"""

from __future__ import annotations

import contextlib
import io
import logging
import math
import os
import re
import struct
import sys
import tempfile
import threading
import warnings
from collections.abc import Callable, Collection, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError
from scan2terrain.readers._files import regular_file

TEXT_SUFFIXES = (".xyz", ".xyzn", ".xyzrgb", ".pts", ".txt", ".csv")
LAS_SUFFIXES = (".las", ".laz")
SUFFIXES = (".pcd", ".ply", *LAS_SUFFIXES, *TEXT_SUFFIXES)
#: LAS points decoded per chunk (about 50 MB of LAS records at most).
LAS_CHUNK = 1_000_000

_PCD_TYPES = {
    ("F", 4): "f4",
    ("F", 8): "f8",
    ("I", 1): "i1",
    ("I", 2): "i2",
    ("I", 4): "i4",
    ("I", 8): "i8",
    ("U", 1): "u1",
    ("U", 2): "u2",
    ("U", 4): "u4",
    ("U", 8): "u8",
}
_PCD_KEYS = ("VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT")
_PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
_XYZ = ("x", "y", "z")
# laspy logs a backend it could not build (a corrupt LAZ) before raising; library code never
# prints, and without a handler Python's last resort would print it to stderr.
logging.getLogger("laspy").addHandler(logging.NullHandler())
_FD2_LOCK = threading.Lock()


@dataclass(frozen=True)
class Cloud:
    """The points of a point-cloud file.

    Attributes
    ----------
    points : float64 array, shape (N, 3), N >= 1
        x, y, z as stored (metres for ROS/PCL data; LAS in its CRS units), in the file's own
        frame, finite only.
    path : Path
        The file read.
    format : str
        What was read, e.g. ``"pcd binary_compressed"``, ``"ply binary_little_endian"``,
        ``"laz 1.2 point format 3"``, ``"csv"``.
    records : int
        Points in the file (of the requested LAS classes) before non-finite ones were dropped.
    """

    points: NDArray[np.float64]
    path: Path
    format: str
    records: int


def read_cloud(path: Path | str, *, las_classes: Collection[int] | None = None) -> Cloud:
    """Read the points of a point-cloud file, chosen by its extension (case-insensitive).

    Parameters
    ----------
    path : Path or str
        A ``.pcd``, ``.ply``, ``.las``, ``.laz``, ``.xyz``, ``.xyzn``, ``.xyzrgb``, ``.pts``,
        ``.txt`` or ``.csv`` file.
    las_classes : collection of int, optional
        Keep only LAS points of these classification codes (e.g. ``(2,)``, ground). LAS/LAZ
        only.

    Returns
    -------
    Cloud
        The finite points, float64 (N, 3), N >= 1.

    Raises
    ------
    InputError
        Missing or empty file, unknown extension, a malformed or truncated file, text that is not
        numbers, no x/y/z columns, no finite point, no point of the requested classes.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise InputError(
            path,
            f"unknown point-cloud extension {suffix or '(none)'!r} (known: {' '.join(SUFFIXES)})",
        )
    size = regular_file(path, "point-cloud file")
    classes = None if las_classes is None else _classes(path, suffix, las_classes)
    try:
        if size == 0:
            raise InputError(path, "empty file")
        if suffix == ".pcd":
            raw, fmt = _read_pcd(path)
        elif suffix == ".ply":
            raw, fmt = _read_ply(path)
        elif suffix in LAS_SUFFIXES:
            raw, fmt = _read_las(path, classes)
        else:
            raw, fmt = _read_text(path, suffix)
    except OSError as exc:
        raise InputError(path, f"cannot read the file ({exc.strerror or exc})") from None
    finite = np.isfinite(raw).all(axis=1)
    points = raw if finite.all() else raw[finite]
    if len(points) == 0:
        detail = "no points" if len(raw) == 0 else f"all {len(raw)} points are NaN or infinite"
        raise InputError(path, f"no finite point in the cloud ({detail})")
    return Cloud(np.ascontiguousarray(points, dtype=np.float64), path, fmt, len(raw))


def _classes(path: Path | str, suffix: str, las_classes: Collection[int]) -> NDArray[np.int64]:
    if suffix not in LAS_SUFFIXES:
        raise InputError(path, "LAS classes can only be selected in .las/.laz files")
    classes = np.array(sorted({int(c) for c in las_classes}), dtype=np.int64)
    if classes.size == 0 or classes.min() < 0 or classes.max() > 255:
        raise ValueError(f"las_classes must be LAS class codes 0..255, got {las_classes!r}")
    return classes


# --- PCD ------------------------------------------------------------------------------------


def _read_pcd(path: Path) -> tuple[NDArray[np.float64], str]:
    raw = path.read_bytes()
    head, start = _pcd_header(path, raw)
    names = head["FIELDS"]
    sizes, types = head.get("SIZE", []), head.get("TYPE", [])
    counts = head.get("COUNT", ["1"] * len(names))
    if not (len(names) == len(sizes) == len(types) == len(counts)):
        raise InputError(path, "PCD header: FIELDS, SIZE, TYPE and COUNT differ in length")
    width, height = _pcd_int(path, head, "WIDTH"), _pcd_int(path, head, "HEIGHT")
    n = _pcd_int(path, head, "POINTS") if "POINTS" in head else width * height
    if n != width * height:
        raise InputError(path, f"PCD header: POINTS {n} is not WIDTH x HEIGHT {width}x{height}")
    # Two fields of one name (PCL names its padding fields "_", any number of them) would make
    # the x, y or z read an accident of which one is taken.
    twice = next((n for i, n in enumerate(names) if n != "_" and n in names[:i]), None)
    if twice is not None:
        raise InputError(path, f"PCD header: field {twice!r} appears twice in FIELDS")
    missing = [a for a in _XYZ if a not in names]
    if missing:
        raise InputError(path, f"PCD has no field {', '.join(missing)} (FIELDS {' '.join(names)})")
    try:
        size_l, count_l = [int(s) for s in sizes], [int(c) for c in counts]
    except ValueError:
        raise InputError(path, "PCD header: SIZE and COUNT must be integers") from None
    if min(size_l, default=1) < 1 or min(count_l, default=0) < 0:
        raise InputError(path, "PCD header: SIZE must be positive and COUNT not negative")
    offsets = np.concatenate([[0], np.cumsum(np.multiply(size_l, count_l))]).tolist()
    columns = np.concatenate([[0], np.cumsum(count_l)]).tolist()
    step = int(offsets[-1])
    formats, at, cols = [], [], []
    for axis in _XYZ:
        i = names.index(axis)
        code = _PCD_TYPES.get((types[i].upper(), size_l[i]))
        if code is None or count_l[i] != 1:
            raise InputError(
                path,
                f"PCD field {axis}: unsupported TYPE {types[i]} SIZE {sizes[i]} COUNT {counts[i]}",
            )
        formats.append("<" + code)
        at.append(int(offsets[i]))
        cols.append(int(columns[i]))
    kind = head["DATA"][0].lower() if head["DATA"] else ""
    if kind == "ascii":
        text = _decode(path, raw[start:])
        pts = _loadtxt(path, io.StringIO(text), cols, delimiter=None, skiprows=0)
        if len(pts) != n:
            cut = "truncated: " if len(pts) < n else ""
            raise InputError(path, f"{cut}PCD header says {n} points, the data has {len(pts)}")
        return pts, "pcd ascii"
    if kind == "binary":
        _need(path, len(raw), start + n * step, f"{n} points of {step} bytes")
        dtype = np.dtype({"names": list(_XYZ), "formats": formats, "offsets": at, "itemsize": step})
        rec = np.frombuffer(raw, dtype=dtype, count=n, offset=start)
        return _stack(rec), "pcd binary"
    if kind == "binary_compressed":
        _need(path, len(raw), start + 8, "the compressed block's sizes")
        packed, unpacked = (int(v) for v in np.frombuffer(raw, dtype="<u4", count=2, offset=start))
        if unpacked != n * step:
            raise InputError(
                path,
                f"PCD compressed block unpacks to {unpacked} bytes, {n} points need {n * step}",
            )
        _need(path, len(raw), start + 8 + packed, f"a compressed block of {packed} bytes")
        return _open3d_points(path, n), "pcd binary_compressed"
    raise InputError(path, f"PCD header: unknown DATA {' '.join(head['DATA'])!r}")


def _pcd_header(path: Path, raw: bytes) -> tuple[dict[str, list[str]], int]:
    """Header keys -> values, and the byte offset where the data starts (after the DATA line)."""
    head: dict[str, list[str]] = {}
    pos = 0
    while pos < len(raw):
        end = raw.find(b"\n", pos)
        end = len(raw) if end < 0 else end
        try:
            line = raw[pos:end].decode("ascii").strip()
        except UnicodeDecodeError:
            line = "\ufffd"
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        key, *values = line.split()
        key = key.upper()
        if not head and key not in _PCD_KEYS:
            raise InputError(path, f"not a PCD file (it starts with {line[:40]!r})")
        head[key] = values
        if key == "DATA":
            if "FIELDS" not in head:
                raise InputError(path, "PCD header has no FIELDS line")
            return head, min(pos, len(raw))
    raise InputError(path, "not a PCD file (no DATA line in its header)")


def _pcd_int(path: Path, head: dict[str, list[str]], key: str) -> int:
    try:
        value = int(head[key][0])
    except (KeyError, IndexError, ValueError):
        raise InputError(path, f"PCD header: {key} is missing or not an integer") from None
    if value < 0:
        raise InputError(path, f"PCD header: {key} {value} is negative")
    return value


# --- PLY ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Element:
    name: str
    count: int
    props: list[tuple[str, str | None]]  # (name, numpy code), None for a list property
    lists: list[str] = field(default_factory=list)  # numpy code of each list's length

    @property
    def fixed(self) -> bool:
        return all(code is not None for _, code in self.props)

    @property
    def min_row(self) -> int:
        """Bytes of a binary row whose lists are all empty."""
        return _row_size(self) + sum(np.dtype(code).itemsize for code in self.lists)


def _read_ply(path: Path) -> tuple[NDArray[np.float64], str]:
    raw = path.read_bytes()
    fmt, elements, start = _ply_header(path, raw)
    index = [e.name for e in elements].index("vertex")
    vertex, before = elements[index], elements[:index]
    names = [p for p, _ in vertex.props]
    if not vertex.fixed or not all(e.fixed for e in before):
        # Rows of varying length: Open3D (RPly) walks them.
        _check_ply_rows(path, fmt, raw, start, [*before, vertex])
        return _open3d_points(path, vertex.count), f"ply {fmt}"
    if fmt == "ascii":
        cols = [names.index(a) for a in _XYZ]
        skip = sum(e.count for e in before)  # one line per item of each earlier element
        lines = raw.count(b"\n", start) + (not raw.endswith(b"\n"))
        if lines < skip + vertex.count:  # before numpy sizes its table by the header's count
            after = f" after {skip} rows of earlier elements" if skip else ""
            raise InputError(
                path,
                f"truncated: PLY header says {vertex.count} vertices, the data has "
                f"{max(lines - skip, 0)} lines{after}",
            )
        text = _decode(path, raw[start:])
        pts = _loadtxt(
            path,
            io.StringIO(text),
            cols,
            delimiter=None,
            skiprows=skip,
            max_rows=vertex.count,
            comments=None,
        )
        if len(pts) != vertex.count:
            raise InputError(
                path, f"truncated: PLY header says {vertex.count} vertices, the data has {len(pts)}"
            )
        return pts, "ply ascii"
    order = "<" if fmt == "binary_little_endian" else ">"
    offset = start + sum(e.count * _row_size(e) for e in before)
    step = _row_size(vertex)
    sizes = np.cumsum([0] + [np.dtype(code).itemsize for _, code in vertex.props]).tolist()
    dtype = np.dtype(
        {
            "names": list(_XYZ),
            "formats": [order + str(vertex.props[names.index(a)][1]) for a in _XYZ],
            "offsets": [int(sizes[names.index(a)]) for a in _XYZ],
            "itemsize": step,
        }
    )
    _need(path, len(raw), offset + vertex.count * step, f"{vertex.count} vertices of {step} bytes")
    return _stack(np.frombuffer(raw, dtype=dtype, count=vertex.count, offset=offset)), f"ply {fmt}"


def _ply_header(path: Path, raw: bytes) -> tuple[str, list[_Element], int]:
    if not raw.startswith((b"ply\n", b"ply\r\n")):
        raise InputError(path, "not a PLY file (it does not start with 'ply')")
    end = raw.find(b"end_header")
    if end < 0:
        raise InputError(path, "PLY header has no end_header line")
    newline = raw.find(b"\n", end)
    start = len(raw) if newline < 0 else newline + 1
    fmt = ""
    elements: list[_Element] = []
    for line in _decode(path, raw[:end]).splitlines()[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        try:
            if words[0] == "format":
                fmt = words[1]
            elif words[0] == "element":
                elements.append(_Element(words[1], int(words[2]), []))
            elif words[0] == "property" and words[1] == "list":
                length, _ = _PLY_TYPES[words[2]], _PLY_TYPES[words[3]]
                if np.dtype(length).kind not in "iu":
                    raise ValueError
                elements[-1].props.append((words[4], None))
                elements[-1].lists.append(length)
            elif words[0] == "property":
                elements[-1].props.append((words[2], _PLY_TYPES[words[1]]))
            else:
                raise ValueError
        except (IndexError, ValueError, KeyError):
            raise InputError(path, f"PLY header: cannot read the line {line[:60]!r}") from None
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise InputError(path, f"PLY header: unknown format {fmt!r}")
    vertices = [e for e in elements if e.name == "vertex"]
    if not vertices:
        raise InputError(path, "PLY has no vertex element")
    props = dict(vertices[0].props)
    missing = [a for a in _XYZ if a not in props]
    if missing:
        raise InputError(path, f"PLY vertex element has no property {', '.join(missing)}")
    if any(props[a] is None for a in _XYZ):
        raise InputError(path, "PLY vertex x/y/z must be numbers, not lists")
    if any(e.count < 0 for e in elements):
        raise InputError(path, "PLY header: negative element count")
    return fmt, elements, start


def _row_size(element: _Element) -> int:
    return sum(np.dtype(code).itemsize for _, code in element.props if code is not None)


def _check_ply_rows(path: Path, fmt: str, raw: bytes, start: int, elements: list[_Element]) -> None:
    """Refuse PLY data too short for its elements' counts even with every list empty, before
    Open3D (RPly) reads it: it keeps the rows it could not read as uninitialised points."""
    if fmt == "ascii":  # one number per property, at least (a list's length)
        need = sum(e.count * len(e.props) for e in elements)
        have, unit = _count_words(raw, start), "numbers"
    else:
        need = sum(e.count * e.min_row for e in elements)
        have, unit = len(raw) - start, "bytes"
    if have < need:
        raise InputError(
            path,
            f"truncated: the PLY header's {elements[-1].count} vertices need at least {need} "
            f"{unit} of data, the file has {have}",
        )


def _count_words(data: bytes, start: int) -> int:
    """Whitespace-separated words in ``data[start:]`` (numpy over the bytes, no Python loop)."""
    view = np.frombuffer(data, dtype=np.uint8, offset=start)
    space = np.isin(view, np.frombuffer(b" \t\n\r\v\f", dtype=np.uint8))
    starts = np.count_nonzero(space[:-1] & ~space[1:])
    return int(starts) + int(view.size > 0 and not space[0])


# --- text -----------------------------------------------------------------------------------

_HEADER_NAME = re.compile(r"^[\s\"'/#]*(.*?)[\s\"']*$")


def _read_text(path: Path, suffix: str) -> tuple[NDArray[np.float64], str]:
    kind = suffix[1:]
    lines = _content_lines(path, 2)
    if not lines:
        raise InputError(path, "no points (only blank or comment lines)")
    (number, line), expected = lines[0], None
    delimiter = _delimiter(line)
    tokens = _split(line, delimiter)
    if kind == "pts" and len(tokens) == 1 and tokens[0].isdigit():
        # Leica-style .pts: a count line, then the points.
        expected = int(tokens[0])
        if len(lines) < 2:
            raise InputError(path, f"truncated: the .pts file says {expected} points, has none")
        number, line = lines[1]
        delimiter = _delimiter(line)
        tokens = _split(line, delimiter)
    if all(_is_number(t) for t in tokens):
        if len(tokens) < 3:
            raise InputError(path, f"line {number}: {len(tokens)} numbers, expected x y z")
        cols, skip = [0, 1, 2], number - 1
    else:
        names = [_HEADER_NAME.sub(r"\1", t).lower() for t in tokens]
        if not all(names.count(a) == 1 for a in _XYZ):
            raise InputError(
                path,
                f"line {number} ({line.strip()[:60]!r}) is neither numbers nor a header naming "
                "one x, one y and one z column",
            )
        cols, skip = [names.index(a) for a in _XYZ], number
    pts = _loadtxt(path, path, cols, delimiter=delimiter, skiprows=skip)
    if expected is not None and len(pts) != expected:
        raise InputError(path, f"the .pts file says {expected} points, has {len(pts)}")
    return pts, kind


def _content_lines(path: Path, wanted: int) -> list[tuple[int, str]]:
    """The first ``wanted`` lines that are neither blank nor ``#`` comments, with their 1-based
    numbers (a loop over a few header lines, not over points)."""
    found: list[tuple[int, str]] = []
    try:
        with path.open(encoding="utf-8", newline=None) as text:
            for number, line in enumerate(text, start=1):
                stripped = line.strip()
                if stripped and not stripped.startswith("#"):
                    found.append((number, stripped))
                    if len(found) == wanted:
                        break
    except UnicodeDecodeError:
        raise InputError(path, "not a text file (not UTF-8)") from None
    return found


def _delimiter(line: str) -> str | None:
    for candidate in (",", ";"):
        if candidate in line:
            return candidate
    return None  # any whitespace


def _split(line: str, delimiter: str | None) -> list[str]:
    return [t.strip() for t in line.split(delimiter)]


def _is_number(token: str) -> bool:
    try:
        float(token.strip("\"'"))
    except ValueError:
        return False
    return True


def _loadtxt(
    path: Path,
    source: Path | io.StringIO,
    cols: list[int],
    *,
    delimiter: str | None,
    skiprows: int,
    max_rows: int | None = None,
    comments: str | None = "#",
) -> NDArray[np.float64]:
    """x, y, z columns of a text table as float64 (N, 3), through numpy's C parser."""
    try:
        with warnings.catch_warnings():
            # An empty table is reported below as "no points", not as a warning.
            warnings.filterwarnings("ignore", message="loadtxt: input contained no data")
            pts = np.loadtxt(
                source,
                dtype=np.float64,
                comments=comments,
                delimiter=delimiter,
                skiprows=skiprows,
                usecols=cols,
                ndmin=2,
                max_rows=max_rows,
                encoding="utf-8",
                quotechar='"',
            )
    except UnicodeDecodeError:
        raise InputError(path, "not a text file (not UTF-8)") from None
    except ValueError as exc:
        raise InputError(
            path, f"not a table of numbers: {exc} (data rows counted from 0)"
        ) from None
    return np.asarray(pts, dtype=np.float64).reshape(-1, 3)


# --- LAS / LAZ ------------------------------------------------------------------------------


def _read_las(path: Path, classes: NDArray[np.int64] | None) -> tuple[NDArray[np.float64], str]:
    import laspy  # type: ignore[import-untyped]

    parts: list[NDArray[np.float64]] = []
    present: set[int] = set()
    seen = 0
    with path.open("rb") as raw:
        _check_las_layout(raw, path.stat().st_size, path, decode=(0, None))
    try:
        with laspy.open(path) as reader:
            header = reader.header
            n = int(header.point_count)
            version = f"{header.version.major}.{header.version.minor}"
            fmt = f"{path.suffix.lower()[1:]} {version} point format {header.point_format.id}"
            for chunk in reader.chunk_iterator(LAS_CHUNK):
                seen += len(chunk)
                xyz = _xyz(chunk)
                if classes is not None:
                    codes = np.asarray(chunk.classification)
                    present.update(np.unique(codes).tolist())
                    xyz = xyz[np.isin(codes, classes)]
                parts.append(xyz)
    except (laspy.errors.LaspyException, ValueError, RuntimeError, EOFError) as exc:
        # lazrs raises LazrsError (a RuntimeError) for corrupt or truncated LAZ data.
        raise InputError(path, f"cannot read as LAS/LAZ ({exc})") from None
    except BaseException as exc:
        if not _is_panic(exc):
            raise
        raise _panic_error(path, exc) from None
    if seen != n:
        raise InputError(path, f"truncated LAS file: the header says {n} points, read {seen}")
    points = np.concatenate(parts) if parts else np.zeros((0, 3))
    if classes is not None and len(points) == 0 and seen > 0:
        raise InputError(
            path,
            f"no point of class {', '.join(map(str, classes.tolist()))} "
            f"(classes present: {', '.join(map(str, sorted(present)))})",
        )
    return points, fmt


# LAS 1.0-1.4 "public header block" and LAZ (LASzip) layout: the laszip VLR, then at the start
# of the point data an int64 offset to the chunk table (-1 or 0: the writer could not seek back
# and put it in the file's last 8 bytes), and there uint32 version 0, uint32 number of chunks and
# the arithmetic-coded entries (byte counts; point counts too for variable-size chunks).
_LAS_HEADER_MIN = 227  # LAS 1.0-1.2
_LAS14_HEADER = 375
_VLR_HEADER = 54
_EVLR_HEADER = 60
_LASZIP_VLR = (b"laszip encoded", 22204)  # user id, record id
_LASZIP_FIXED = 34  # payload bytes before its item records (6 bytes each)
_VARIABLE_CHUNKS = 0xFFFFFFFF
_CHUNKED = (2, 3)  # the laszip VLR's compressor: pointwise chunked, layered chunked
#: Points a byte of LAZ data can hold at most. LASzip packs about 150 identical points into a
#: byte; a header claiming hundreds of times more is corrupt, and would be planned by.
_LAZ_POINTS_PER_BYTE = 1 << 16


def _check_las_layout(
    f: BinaryIO, size: int, where: Path | str, *, decode: tuple[int, int | None] | None
) -> None:
    """Refuse a LAS/LAZ file whose header counts and offsets (and LAZ chunk table) do not fit
    in its ``size`` bytes, reading a few raw bytes from ``f`` (left at an arbitrary position).

    Done before laspy reads the header (it reads VLRs and EVLRs by the header's counts and
    lengths) and before lazrs decodes (it allocates the chunk table by its count: 2^32 chunks
    made it abort the process). ``decode``: the points ``[start, stop)`` (stop None: to the
    end) about to be decoded, whose LAZ chunks' layer sizes are checked too; None: none. A file
    that is no LAS file at all is left to laspy to name.
    """
    head = _read_at(f, 0, _LAS14_HEADER)
    if len(head) < _LAS_HEADER_MIN or not head.startswith(b"LASF"):
        return
    header_size, start, n_vlrs, format_id, record, count = struct.unpack_from("<HIIBHI", head, 94)
    _check_scales(head, where)
    first_evlr = n_evlrs = 0
    if head[25] >= 4 and len(head) >= _LAS14_HEADER:  # LAS 1.4: 64-bit count, EVLRs
        first_evlr, n_evlrs, count = struct.unpack_from("<QIQ", head, 235)
    if start > size:
        raise InputError(
            where, f"truncated LAS file: its points start at byte {start}, the file has {size}"
        )
    if header_size <= start and n_vlrs * _VLR_HEADER > start - header_size:
        raise InputError(
            where,
            f"corrupt LAS header: {n_vlrs:,} VLRs cannot fit in the {start - header_size} bytes "
            "between the header and the points",
        )
    if n_evlrs:
        _check_evlrs(f, size, first_evlr, n_evlrs, where)
    if format_id & 0xC0 != 0x80:  # not compressed (laspy's rule: bit 7 set, bit 6 clear)
        need = start + count * record
        if size < need:
            raise InputError(
                where,
                f"truncated LAS file: {count} points of {record} bytes need {need} bytes, "
                f"the file has {size}",
            )
        return
    if count and header_size <= start:
        laszip = _laszip_payload(_read_at(f, header_size, start - header_size), n_vlrs)
        if laszip is not None:
            _check_laz(
                f, size, laszip, start=start, record=record, count=count, where=where, decode=decode
            )


def _check_scales(head: bytes, where: Path | str) -> None:
    """Refuse scale factors that are not positive and finite (0 put every point at the offset,
    a negative one mirrored the cloud, both read without a word) and non-finite offsets."""
    scales = struct.unpack_from("<3d", head, 131)
    offsets = struct.unpack_from("<3d", head, 155)
    if not all(math.isfinite(v) and v > 0 for v in scales):
        raise InputError(
            where,
            f"corrupt LAS header: scale factors ({', '.join(f'{v:g}' for v in scales)}) must be "
            "positive and finite",
        )
    if not all(math.isfinite(v) for v in offsets):
        raise InputError(
            where,
            f"corrupt LAS header: offsets ({', '.join(f'{v:g}' for v in offsets)}) must be finite",
        )


def _check_evlrs(f: BinaryIO, size: int, first: int, n: int, where: Path | str) -> None:
    if first + n * _EVLR_HEADER > size:
        raise InputError(
            where,
            f"corrupt LAS header: {n:,} extended VLRs from byte {first} cannot fit in the file "
            f"({size} bytes)",
        )
    pos = first
    for _ in range(n):  # a loop over the file's few EVLRs, each 60 bytes at least
        raw = _read_at(f, pos, _EVLR_HEADER)
        pos += _EVLR_HEADER + (struct.unpack_from("<Q", raw, 20)[0] if len(raw) == 60 else size)
        if pos > size:
            raise InputError(
                where, f"truncated LAS file: its extended VLRs run past the end ({size} bytes)"
            )


def _laszip_payload(vlrs: bytes, n: int) -> bytes | None:
    """The laszip VLR's data among the ``n`` VLRs in ``vlrs``, or None (laspy refuses then)."""
    pos = 0
    for _ in range(n):  # a loop over the header's few VLRs
        if pos + _VLR_HEADER > len(vlrs):
            return None
        user, record_id, length = struct.unpack_from("<16sHH", vlrs, pos + 2)
        if (user.rstrip(b"\0"), record_id) == _LASZIP_VLR:
            return vlrs[pos + _VLR_HEADER : pos + _VLR_HEADER + length]
        pos += _VLR_HEADER + length
    return None


def _check_laz(
    f: BinaryIO,
    size: int,
    laszip: bytes,
    *,
    start: int,
    record: int,
    count: int,
    where: Path | str,
    decode: tuple[int, int | None] | None,
) -> None:
    """The chunk table against the header's point count and the file's size (LAZ, count > 0),
    and the layer sizes of the chunks holding the points to ``decode``."""

    def corrupt(problem: str) -> InputError:
        return InputError(where, f"corrupt LAZ file: {problem}")

    if len(laszip) < _LASZIP_FIXED:
        raise corrupt(f"its laszip VLR has {len(laszip)} bytes, fewer than {_LASZIP_FIXED}")
    chunk_size = struct.unpack_from("<I", laszip, 12)[0]
    n_items = struct.unpack_from("<H", laszip, 32)[0]
    if len(laszip) < _LASZIP_FIXED + 6 * n_items:
        raise corrupt(f"its laszip VLR lists {n_items} items in {len(laszip)} bytes")
    item_size = sum(
        struct.unpack_from("<H", laszip, _LASZIP_FIXED + 6 * i + 2)[0] for i in range(n_items)
    )
    if item_size != record:
        raise corrupt(
            f"its laszip VLR describes {item_size}-byte points, the header {record}-byte ones"
        )
    if struct.unpack_from("<H", laszip, 0)[0] not in _CHUNKED:
        return  # pointwise LAZ (LASzip 1.x) has no chunk table; lazrs refuses other values
    if chunk_size == 0:
        raise corrupt("its laszip VLR has a chunk size of 0 points")
    data_start = start + 8
    if size < data_start:
        raise InputError(
            where,
            f"truncated LAZ file: it ends at byte {size}, before its compressed points start "
            f"(byte {data_start})",
        )
    table = struct.unpack("<q", _read_at(f, start, 8))[0]
    if table <= start:  # the writer could not seek back: the offset ends the file
        table = struct.unpack("<q", _read_at(f, size - 8, 8))[0]
    if table <= start:
        raise InputError(
            where, "truncated or corrupt LAZ file: it has no chunk table (an unfinished write?)"
        )
    if not data_start <= table <= size - 8:
        raise InputError(
            where,
            f"truncated or corrupt LAZ file: its chunk table offset {table} lies outside the "
            f"compressed data (bytes {data_start}..{size})",
        )
    data = table - data_start
    version, chunks = struct.unpack("<II", _read_at(f, table, 8))
    if version != 0:
        raise corrupt(f"unknown chunk table version {version} (LASzip writes 0)")
    if chunk_size != _VARIABLE_CHUNKS:
        expected = -(-count // chunk_size)
        if chunks != expected:
            raise corrupt(
                f"its chunk table lists {chunks:,} chunks, {count:,} points in chunks of "
                f"{chunk_size:,} make {expected:,}"
            )
    elif not 1 <= chunks <= count:
        raise corrupt(f"its chunk table lists {chunks:,} chunks for {count:,} points")
    if chunks * item_size > data:  # each chunk starts with a raw point
        raise corrupt(f"{chunks:,} chunks cannot fit in {data:,} bytes of compressed points")
    if count > data * _LAZ_POINTS_PER_BYTE:
        raise corrupt(
            f"the header says {count:,} points, more than {data:,} bytes of LAZ data can hold"
        )
    entries = _laz_chunk_table(f, start, laszip, where)
    if sum(b for _, b in entries) != data:
        raise corrupt(
            f"its chunk table's byte counts add up to {sum(b for _, b in entries):,}, the "
            f"compressed points take {data:,}"
        )
    if chunk_size == _VARIABLE_CHUNKS and sum(p for p, _ in entries) != count:
        raise corrupt(
            f"its chunk table's point counts add up to {sum(p for p, _ in entries):,}, the "
            f"header says {count:,}"
        )
    layers = _layer_count(laszip, n_items)
    if layers and decode is not None:
        _check_layers(
            f,
            entries,
            data_start=data_start,
            record=record,
            layers=layers,
            decode=decode,
            corrupt=corrupt,
        )


#: Layers per item of a LASzip layered chunk (point formats 6-10, item version 3), by item type:
#: POINT14 (10) 9 (x/y/returns, z, classification, flags, intensity, scan angle, user data,
#: point source, GPS time), RGB14 (11) 1, RGBNIR14 (12) 2, WAVEPACKET14 (13) 1; BYTE14 (14)
#: has one per byte.
_LAYERS = {10: 9, 11: 1, 12: 2, 13: 1}
_BYTE14 = 14


def _layer_count(laszip: bytes, n_items: int) -> int:
    """Layer sizes at the start of each chunk (after its raw first point and point count); 0
    for pointwise chunks (and items lazrs does not decode layered, which it refuses)."""
    layers = 0
    for i in range(n_items):
        kind, item_size, version = struct.unpack_from("<HHH", laszip, _LASZIP_FIXED + 6 * i)
        if version != 3:
            return 0
        layers += item_size if kind == _BYTE14 else _LAYERS.get(kind, 0)
    return layers


def _check_layers(
    f: BinaryIO,
    entries: list[tuple[int, int]],
    *,
    data_start: int,
    record: int,
    layers: int,
    decode: tuple[int, int | None],
    corrupt: Callable[[str], InputError],
) -> None:
    """Each layered chunk holding points of ``decode`` starts with a raw point, a point count
    and ``layers`` uint32 layer sizes, which lazrs allocates by (4 GB for a corrupt one, which
    aborts the process where that much cannot be had): they must fit in the chunk. A read of a
    few dozen bytes per chunk, one chunk per 50,000 points (LASzip's default)."""
    first, stop = decode
    header = record + 4 + 4 * layers
    pos, done = data_start, 0  # chunk i starts at pos, after `done` points
    for i, (points, nbytes) in enumerate(entries):  # a loop over chunks, not points
        if (stop is None or done < stop) and done + points > first:
            raw = _read_at(f, pos + record + 4, 4 * layers)
            if len(raw) < 4 * layers:
                raise corrupt(f"chunk {i} is cut short")
            claimed = sum(struct.unpack(f"<{layers}I", raw))
            if header + claimed > nbytes:
                raise corrupt(f"chunk {i} ({nbytes:,} bytes) has layers of {claimed:,} bytes")
        pos += nbytes
        done += points


def _laz_chunk_table(
    f: BinaryIO, start: int, laszip: bytes, where: Path | str
) -> list[tuple[int, int]]:
    """(points, bytes) per chunk, read by lazrs (its number of chunks already checked)."""
    import lazrs  # type: ignore[import-untyped]

    f.seek(start)
    try:
        entries = lazrs.read_chunk_table(f, lazrs.LazVlr(laszip))
    except lazrs.LazrsError as exc:
        raise InputError(where, f"corrupt LAZ file: cannot read its chunk table ({exc})") from None
    except BaseException as exc:
        if not _is_panic(exc):
            raise
        raise _panic_error(where, exc) from None
    return [(int(p), int(b)) for p, b in entries]


def _read_at(f: BinaryIO, offset: int, n: int) -> bytes:
    f.seek(offset)
    return bytes(f.read(n))


def _is_panic(exc: BaseException) -> bool:
    """A Rust panic in lazrs: pyo3's PanicException, a BaseException that ``except Exception``
    misses (its class lives in pyo3's runtime module, so it is known by name)."""
    return type(exc).__name__ == "PanicException"


def _panic_error(where: Path | str, exc: BaseException) -> InputError:
    return InputError(where, f"corrupt LAZ data (lazrs failed: {exc})")


@dataclass(frozen=True)
class LasInfo:
    """A LAS/LAZ header: point count and bounds (the file's units) without reading points."""

    path: Path | str  #: a local path, or a URL as given
    points: int
    mins: tuple[float, float, float]
    maxs: tuple[float, float, float]
    format: str


def is_url(name: Path | str) -> bool:
    """``scheme://...`` (http, https, s3, file, ...), as opposed to a local path."""
    return re.match(r"^[A-Za-z][A-Za-z0-9+.-]*://", str(name)) is not None


def url_path(name: Path | str) -> Path:
    """A path, or a URL as a path (its query and fragment dropped), for names and suffixes."""
    return Path(re.split(r"[?#]", str(name), maxsplit=1)[0] if is_url(name) else name)


def url_suffix(name: Path | str) -> str:
    """The lower-case extension of a path or URL."""
    return url_path(name).suffix.lower()


@contextlib.contextmanager
def _las_source(name: Path | str) -> Iterator[Any]:
    """What ``laspy.open`` reads: a local path, or a file object fsspec opens for a URL (any
    protocol fsspec has: http(s) with aiohttp, s3 with s3fs, ...)."""
    if not is_url(name):
        path = Path(name)
        if regular_file(path, "point-cloud file") == 0:
            raise InputError(path, "empty file")
        yield path
        return
    url = str(name)
    try:
        import fsspec  # type: ignore[import-untyped]
    except ImportError:
        raise InputError(url, "URLs need fsspec: pip install 'scan2terrain[dask]'") from None
    try:
        with fsspec.open(url, "rb") as f:
            yield f
    except (FileNotFoundError, ImportError, ValueError) as exc:
        raise InputError(url, f"cannot open the URL ({type(exc).__name__}: {exc})") from None


def las_info(path: Path | str) -> LasInfo:
    """The header of a LAS/LAZ file (a path, or a URL fsspec can open). Raises InputError for a
    missing, empty, foreign or truncated (uncompressed: shorter than its header's points need)
    file."""
    import laspy

    where: Path | str = path if is_url(path) else Path(path)
    try:
        with _las_source(where) as source, _checked(source, where), laspy.open(source) as reader:
            h = reader.header
            n = int(h.point_count)
            version = f"{h.version.major}.{h.version.minor}"
            fmt = f"{url_suffix(where)[1:]} {version} point format {h.point_format.id}"
            mins = tuple(float(v) for v in h.mins)
            maxs = tuple(float(v) for v in h.maxs)
    except (laspy.errors.LaspyException, ValueError, RuntimeError, EOFError, OSError) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(where, f"cannot read as LAS/LAZ ({exc})") from None
    except BaseException as exc:
        if not _is_panic(exc):
            raise
        raise _panic_error(where, exc) from None
    return LasInfo(where, n, mins, maxs, fmt)  # type: ignore[arg-type]  # 3-tuples


@contextlib.contextmanager
def _checked(
    source: Any, where: Path | str, decode: tuple[int, int | None] | None = None
) -> Iterator[None]:
    """:func:`_check_las_layout` on a path or a seekable file object (left at its start); an
    unseekable stream is not checked (the PanicException backstop still applies)."""
    if isinstance(source, Path):
        with source.open("rb") as f:
            _check_las_layout(f, source.stat().st_size, where, decode=decode)
    elif source.seekable():
        _check_las_layout(source, _size(source), where, decode=decode)
        source.seek(0)
    yield


def _size(source: Any) -> int:
    if isinstance(source, Path):
        return source.stat().st_size
    size = getattr(source, "size", None)
    if size is None:
        here = source.tell()
        size = source.seek(0, 2)
        source.seek(here)
    return int(size)


def iter_las(
    path: Path | str,
    *,
    start: int = 0,
    count: int | None = None,
    step: int = LAS_CHUNK,
    las_classes: Collection[int] | None = None,
    origin: NDArray[np.float64] | None = None,
) -> Iterator[NDArray[np.float64]]:
    """Points ``[start, start + count)`` of a LAS/LAZ file (``count`` None: to the end), ``step``
    at a time, as float64 (n, 3) in the file's units (``X * scale + offset``, as laspy computes
    them) less ``origin``, of the requested classes only. Non-finite points are not possible in
    LAS. Raises InputError naming the file for unreadable or truncated data."""
    import laspy

    where: Path | str = path if is_url(path) else Path(path)
    suffix = url_suffix(where)
    classes = None if las_classes is None else _classes(where, suffix, las_classes)
    want = -1
    seen = 0
    try:
        stop = None if count is None else start + count
        with (
            _las_source(where) as source,
            _checked(source, where, (start, stop)),
            laspy.open(source) as reader,
        ):
            total = int(reader.header.point_count)
            want = total - start if count is None else min(count, total - start)
            if start:
                reader.seek(start)
            while seen < want:
                chunk = reader.read_points(min(step, want - seen))
                if len(chunk) == 0:
                    break
                seen += len(chunk)
                xyz = _xyz(chunk, origin)
                if classes is not None:
                    xyz = xyz[np.isin(np.asarray(chunk.classification), classes)]
                yield xyz
    except (laspy.errors.LaspyException, ValueError, RuntimeError, EOFError, OSError) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(where, f"cannot read as LAS/LAZ ({exc})") from None
    except BaseException as exc:  # GeneratorExit at a yield is re-raised as it is
        if not _is_panic(exc):
            raise
        raise _panic_error(where, exc) from None
    if seen != want:
        raise InputError(
            where, f"truncated LAS file: expected points {start}..{start + want}, read {seen}"
        )


def _xyz(points: Any, origin: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """(n, 3) float64 coordinates of a laspy ScaleAwarePointRecord, exactly as laspy scales
    them (``X * scale + offset``), less ``origin`` (metres, default none)."""
    from scan2terrain.readers._las_kernels import scaled_xyz

    out = np.empty((len(points), 3), dtype=np.float64)
    arr = points.array
    scaled_xyz(
        arr["X"],
        arr["Y"],
        arr["Z"],
        np.asarray(points.scales, dtype=np.float64),
        np.asarray(points.offsets, dtype=np.float64),
        np.zeros(3) if origin is None else np.asarray(origin, dtype=np.float64),
        out,
    )
    return out


# --- shared ---------------------------------------------------------------------------------


def _open3d_points(path: Path, expected: int) -> NDArray[np.float64]:
    """Open3D's points for ``path``, which must hold ``expected`` of them.

    A PLY that RPly (Open3D's PLY parser) fails to read still comes back with the header's
    number of points, the unread ones uninitialised: RPly's complaint, which it prints to file
    descriptor 2 and reports nowhere else, is the only sign, so it is captured and refused.
    """
    import open3d

    utility = open3d.utility
    try:
        with _fd2_lines() as printed, utility.VerbosityContextManager(utility.VerbosityLevel.Error):
            cloud = open3d.io.read_point_cloud(
                path, remove_nan_points=False, remove_infinite_points=False
            )
    except RuntimeError as exc:  # Open3D raises its own errors as RuntimeError
        raise InputError(path, f"corrupt data: Open3D cannot read it ({exc})") from None
    complaints = [line for line in printed if line.startswith("RPly")]
    if complaints:
        raise InputError(path, f"corrupt or truncated data ({complaints[0]})")
    points = np.array(cloud.points, dtype=np.float64).reshape(-1, 3)
    if len(points) != expected:
        raise InputError(
            path, f"corrupt data: the header says {expected} points, Open3D decoded {len(points)}"
        )
    return points


@contextlib.contextmanager
def _fd2_lines() -> Iterator[list[str]]:
    """The lines C code writes to file descriptor 2 meanwhile (RPly's errors), captured in a
    temporary file; whatever else was written there is passed on to it afterwards. Where fd 2
    cannot be duplicated nothing is captured."""
    lines: list[str] = []
    with _FD2_LOCK:  # one capture at a time: nested ones in threads would misroute fd 2
        try:
            saved = os.dup(2)
        except OSError:
            yield lines
            return
        with tempfile.TemporaryFile() as tmp:
            sys.stderr.flush()
            os.dup2(tmp.fileno(), 2)
            try:
                yield lines
            finally:
                os.dup2(saved, 2)
                os.close(saved)
                tmp.seek(0)
                lines += tmp.read().decode("utf-8", "replace").splitlines()
                other = [ln for ln in lines if not ln.startswith("RPly")]
                if other:
                    os.write(2, ("\n".join(other) + "\n").encode())


def _stack(records: NDArray[np.void]) -> NDArray[np.float64]:
    out = np.empty((len(records), 3))
    # A signalling NaN in the file raises the "invalid" flag as it is widened; NaN points are
    # dropped by the caller, so that is no warning to print.
    with np.errstate(invalid="ignore"):
        for axis, name in enumerate(_XYZ):  # three column copies
            out[:, axis] = records[name]
    return out


def _need(path: Path, have: int, need: int, what: str) -> None:
    if have < need:
        raise InputError(path, f"truncated: {what} need {need} bytes, the file has {have}")


def _decode(path: Path, data: bytes) -> str:
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise InputError(path, "not a text file where text was expected (not UTF-8)") from None
