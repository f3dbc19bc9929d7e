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
  scaled float64 ``x, y, z`` (UTM eastings ~5e6 m lose centimetres in float32).

Points are returned as the file stores them (no ``VIEWPOINT`` or CRS applied, as PCL and Open3D
do); every problem is an :class:`InputError` naming the file.
"""

from __future__ import annotations

import contextlib
import io
import re
import warnings
from collections.abc import Collection, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError

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
    if not path.is_file():
        raise InputError(path, "point-cloud file not found")
    classes = None if las_classes is None else _classes(path, suffix, las_classes)
    try:
        if path.stat().st_size == 0:
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

    @property
    def fixed(self) -> bool:
        return all(code is not None for _, code in self.props)


def _read_ply(path: Path) -> tuple[NDArray[np.float64], str]:
    raw = path.read_bytes()
    fmt, elements, start = _ply_header(path, raw)
    index = [e.name for e in elements].index("vertex")
    vertex, before = elements[index], elements[:index]
    names = [p for p, _ in vertex.props]
    if not vertex.fixed or not all(e.fixed for e in before):
        # Rows of varying length: Open3D (RPly) walks them.
        return _open3d_points(path, vertex.count), f"ply {fmt}"
    if fmt == "ascii":
        cols = [names.index(a) for a in _XYZ]
        skip = sum(e.count for e in before)  # one line per item of each earlier element
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
                elements[-1].props.append((words[4], None))
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

    size = path.stat().st_size
    parts: list[NDArray[np.float64]] = []
    present: set[int] = set()
    seen = 0
    try:
        with laspy.open(path) as reader:
            header = reader.header
            n = int(header.point_count)
            version = f"{header.version.major}.{header.version.minor}"
            fmt = f"{path.suffix.lower()[1:]} {version} point format {header.point_format.id}"
            if not header.are_points_compressed:
                step = int(header.point_format.size)
                need = int(header.offset_to_point_data) + n * step
                if size < need:
                    raise _Truncated(
                        f"{n} points of {step} bytes need {need} bytes, the file has {size}"
                    )
            for chunk in reader.chunk_iterator(LAS_CHUNK):
                seen += len(chunk)
                xyz = _xyz(chunk)
                if classes is not None:
                    codes = np.asarray(chunk.classification)
                    present.update(np.unique(codes).tolist())
                    xyz = xyz[np.isin(codes, classes)]
                parts.append(xyz)
    except _Truncated as exc:
        raise InputError(path, f"truncated LAS file: {exc}") from None
    except (laspy.errors.LaspyException, ValueError, RuntimeError, EOFError) as exc:
        # lazrs raises LazrsError (a RuntimeError) for corrupt or truncated LAZ data.
        raise InputError(path, f"cannot read as LAS/LAZ ({exc})") from None
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


class _Truncated(Exception):
    pass


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
        if not path.is_file():
            raise InputError(path, "point-cloud file not found")
        if path.stat().st_size == 0:
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
        with _las_source(where) as source, laspy.open(source) as reader:
            h = reader.header
            n = int(h.point_count)
            if not h.are_points_compressed:
                size = _size(source)
                need = int(h.offset_to_point_data) + n * int(h.point_format.size)
                if size < need:
                    raise InputError(
                        where,
                        f"truncated LAS file: {n} points of {h.point_format.size} bytes need "
                        f"{need} bytes, the file has {size}",
                    )
            version = f"{h.version.major}.{h.version.minor}"
            fmt = f"{url_suffix(where)[1:]} {version} point format {h.point_format.id}"
            mins = tuple(float(v) for v in h.mins)
            maxs = tuple(float(v) for v in h.maxs)
    except (laspy.errors.LaspyException, ValueError, RuntimeError, EOFError, OSError) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(where, f"cannot read as LAS/LAZ ({exc})") from None
    return LasInfo(where, n, mins, maxs, fmt)  # type: ignore[arg-type]  # 3-tuples


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
        with _las_source(where) as source, laspy.open(source) as reader:
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
    """Open3D's points for ``path``, which must hold ``expected`` of them."""
    import open3d

    utility = open3d.utility
    with utility.VerbosityContextManager(utility.VerbosityLevel.Error):
        cloud = open3d.io.read_point_cloud(
            path, remove_nan_points=False, remove_infinite_points=False
        )
    points = np.array(cloud.points, dtype=np.float64).reshape(-1, 3)
    if len(points) != expected:
        raise InputError(
            path, f"corrupt data: the header says {expected} points, Open3D decoded {len(points)}"
        )
    return points


def _stack(records: NDArray[np.void]) -> NDArray[np.float64]:
    out = np.empty((len(records), 3))
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
