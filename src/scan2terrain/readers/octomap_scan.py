"""OctoMap's plain-text scan files (``scan.dat``, optionally ``.bz2``/``.gz``), as OctoMap's
``log2graph`` and ``ScanGraph::readPlainASCII`` read them.

Each ``NODE x y z roll pitch yaw`` line starts a scan taken at that sensor pose; the ``x y z``
lines after it are its points in the sensor frame. A file without NODE lines is one scan in the
map frame with the sensor at the origin (OctoMap's FR-079 ``scan.dat``).
"""

from __future__ import annotations

import bz2
import gzip
import io
import math
import re
import warnings
import zlib
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError
from scan2terrain.readers._files import regular_file
from scan2terrain.readers.poses import rpy_matrix
from scan2terrain.types import Scan

SUFFIXES = (".dat", ".log", ".txt")
#: Points one scan may hold (it is held in memory whole: 24 bytes a point, and more while it is
#: ray cast). OctoMap's scans hold about 100,000 (FR-079: 88,206); a file of 20 million "0 0 0"
#: lines took 5.7 GB.
MAX_SCAN_POINTS = 10_000_000
#: The longest line read: a point or NODE line is a few dozen bytes.
MAX_LINE_BYTES = 4096
#: OctoMap's points are float32 (``point3d``): larger coordinates cannot be inserted.
_FLOAT32_MAX = float(np.finfo(np.float32).max)


def is_scan_file(path: Path) -> bool:
    name = path.name.lower()
    for packed in (".bz2", ".gz"):
        name = name.removesuffix(packed)
    return name.endswith(SUFFIXES)


def read_scans(path: Path) -> Iterator[Scan]:
    """Yield the scans of an OctoMap text scan file, one at a time, in the map frame.

    The file is read as a stream (decompressed as it is read), ``_BLOCK`` bytes at a time: only
    the scan being read is held in memory, and a scan may hold at most
    :data:`MAX_SCAN_POINTS` points, a line at most :data:`MAX_LINE_BYTES` bytes.

    Raises
    ------
    InputError
        Naming the file (and the line): missing or not a regular file, not decompressible, not
        ASCII, a malformed NODE or point line, a point beyond float32, a scan over the limits,
        or no point at all.
    """
    path = Path(path)
    regular_file(path, "scan file")
    reader = _Scans(path)
    try:
        with _open(path) as f:
            yield from reader.feed(f)
    except (OSError, EOFError, ValueError, zlib.error) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(path, f"cannot read as an OctoMap text scan file ({exc})") from exc
    if reader.count == 0:
        raise InputError(path, "no points in the scan file")


def _open(path: Path) -> io.BufferedIOBase:
    if path.suffix == ".bz2":
        return bz2.BZ2File(path, "rb")
    if path.suffix == ".gz":
        return gzip.GzipFile(path, "rb")
    return path.open("rb")


#: Bytes read (after decompression) at a time.
_BLOCK = 1 << 20
#: A NODE line, whatever the case of the keyword (as ``stripped.upper().startswith("NODE")``).
_NODE = re.compile(rb"^[ \t\r\f\v]*node", re.IGNORECASE | re.MULTILINE)


class _Scans:
    """Cuts a stream of lines into scans: the points of each run of lines between NODE lines
    are parsed a block at a time (numpy's ``loadtxt``, which skips blank lines and ``#``
    comments as before), posed, checked and gathered until the scan ends."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.count = 0  # scans yielded
        self.pose: tuple[float, ...] | None = None
        self.parts: list[NDArray[np.float64]] = []
        self.points = 0  # in self.parts
        self.line = 1  # number of the next line to read

    def feed(self, f: io.BufferedIOBase) -> Iterator[Scan]:
        rest = b""
        while True:
            block = f.read(_BLOCK)
            data = rest + block
            cut = len(data) if not block else data.rfind(b"\n") + 1
            if len(data) - cut > MAX_LINE_BYTES:  # no line end in sight
                number = self.line + data.count(b"\n", 0, cut)
                raise InputError(
                    self.path,
                    f"line {number} is longer than {MAX_LINE_BYTES} bytes: not an OctoMap text "
                    "scan file",
                )
            yield from self._lines(data[:cut])
            rest = data[cut:]
            if not block:
                break
        if self.parts:
            yield self._scan()

    def _lines(self, text: bytes) -> Iterator[Scan]:
        """Whole lines: the points before each NODE line end a scan, the NODE starts the next."""
        at = 0
        for node in _NODE.finditer(text):
            self._points(text[at : node.start()])
            if self.parts:
                yield self._scan()
            end = text.find(b"\n", node.start())
            end = len(text) if end < 0 else end + 1
            line = text[node.start() : end].decode("ascii", "replace").strip()
            self.pose = _pose(self.path, line, self.line)
            self.line += 1 if end > node.start() and text[end - 1 : end] == b"\n" else 0
            at = end
        self._points(text[at:])

    def _points(self, text: bytes) -> None:
        """Point lines (and blank and comment lines), from line ``self.line`` on."""
        if not text:
            return
        first = self.line
        self.line += text.count(b"\n")
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)  # "input contained no data"
                pts = np.loadtxt(io.BytesIO(text), dtype=np.float64, ndmin=2, encoding="ascii")
        except (ValueError, UnicodeDecodeError):
            raise InputError(self.path, _bad_line(text, first)) from None
        if pts.size == 0:
            return
        if pts.shape[1] != 3:
            raise InputError(self.path, _bad_line(text, first))
        if self.points + len(pts) > MAX_SCAN_POINTS:
            over = first + _data_lines(text)[MAX_SCAN_POINTS - self.points][0]
            raise InputError(
                self.path,
                f"line {over:,}: more than {MAX_SCAN_POINTS:,} points in one scan (the limit "
                "MAX_SCAN_POINTS of scan2terrain.readers.octomap_scan); OctoMap's scans hold "
                "about 100,000: split it with NODE lines",
            )
        world = _posed(pts, self.pose)
        with np.errstate(invalid="ignore"):
            usable = (np.abs(world) <= _FLOAT32_MAX).all(axis=1)  # False for NaN and inf too
        if not usable.all():
            number, row = _data_lines(text)[int(np.argmin(usable))]
            raise InputError(
                self.path,
                f"line {first + number}: point {row[:40]!r} is not a finite float32 "
                "coordinate (OctoMap's point type) in the map frame",
            )
        self.parts.append(world)
        self.points += len(world)

    def _scan(self) -> Scan:
        points = self.parts[0] if len(self.parts) == 1 else np.concatenate(self.parts)
        if self.pose is None:  # points already in the map frame, the sensor at its origin
            origin, rotation = np.zeros(3), np.eye(3)
        else:
            origin, rotation = np.array(self.pose[:3]), rpy_matrix(*self.pose[3:])
        self.parts, self.points = [], 0
        self.count += 1
        return Scan(points, origin, stamp_ns=0, rotation=rotation)


def _posed(pts: NDArray[np.float64], pose: tuple[float, ...] | None) -> NDArray[np.float64]:
    if pose is None:
        return pts
    x, y, z, roll, pitch, yaw = pose
    with np.errstate(over="ignore", invalid="ignore"):  # checked by the caller
        world: NDArray[np.float64] = pts @ rpy_matrix(roll, pitch, yaw).T + (x, y, z)
    return world


def _data_lines(text: bytes) -> list[tuple[int, str]]:
    """(line offset, stripped text) of the point lines in ``text`` (not blank, no comment)."""
    rows = []
    for number, raw in enumerate(text.decode("ascii", "replace").split("\n")):
        row = raw.split("#", 1)[0].strip()
        if row:
            rows.append((number, row))
    return rows


def _bad_line(text: bytes, first: int) -> str:
    """Which line of ``text`` (line ``first`` on) is not three numbers, and why."""
    for number, row in _data_lines(text):
        if len(row.split()) != 3 or not _numeric(row) or not row.isascii():
            return f"line {first + number}: expected 'x y z', got {row[:40]!r}"
    return f"near line {first}: expected 3 numbers per point line"


def _pose(path: Path, line: str, number: int) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in line.split()[1:])
    except ValueError:
        values = ()
    if len(values) != 6 or not all(math.isfinite(v) for v in values):
        raise InputError(path, f"line {number}: expected 'NODE x y z roll pitch yaw'")
    return values


def _numeric(row: str) -> bool:
    try:
        [float(v) for v in row.split()]
    except ValueError:
        return False
    return True
