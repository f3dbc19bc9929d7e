"""The records of a CARMEN log, parsed and checked: for :mod:`scan2terrain.readers.carmen`.

A CARMEN log is text, one record per line: its type, its fields, then ``ipc_timestamp host
logger_timestamp`` (CARMEN's ``writelog.c``; the formats below are those of its
``readlog.c``). Read here:

* ``FLASER n r_1 .. r_n x y theta odom_x odom_y odom_theta ...`` (front laser) and ``RLASER``
  (rear): ``x y theta`` is the laser's pose, ``odom_*`` the robot's odometry at the scan. The
  beams' geometry is not in the record: PARAM ``laser_front_laser_fov`` /
  ``laser_front_laser_resolution`` (degrees; ``laser_rear_laser_*`` for the rear) when the log
  has them, else CARMEN's own guess from the count (``carmen_laser_guess_angle_increment``:
  1 degree for 180/181 beams, 0.5 for 360/361, 0.25 for 400/401, else 180 degrees over n - 1
  steps), first beam at -fov/2 (-90 degrees without the PARAM, as CARMEN reads them).
* ``ROBOTLASER1`` (front) / ``ROBOTLASER2`` (rear): ``laser_type start_angle fov resolution
  max_range accuracy remission_mode n r_1 .. r_n m rem_1 .. rem_m laser_x laser_y laser_theta
  robot_x robot_y robot_theta tv rv forward_safety side_safety turn_axis ...`` (radians,
  metres); remissions are checked and not used.
* ``ODOM x y theta tv rv accel ...``.
* ``PARAM name value ...``: the first value of each name is kept.

Every other record type (SYNC, TRUEPOS, NMEA..., RAWLASER without a pose) is counted and skipped;
comment lines (``#``) and blank lines are skipped. Choices:

* **Streamed, once.** The file is decompressed as it is read (``.gz``, ``.bz2``, by magic
  bytes), line by line: the text is never held whole, only the parsed arrays (ranges as
  float32, about two thirds of the text's size). A line's numbers are converted together by
  numpy; there is no loop over readings.
* **Checked, one line each.** A line cut short, a field that is not a number, a count that does
  not match the fields, a non-finite or negative reading, a non-finite pose or timestamp,
  absurd geometry (no beams, more than :data:`MAX_BEAMS`, a field of view over 360 degrees, a
  maximum range over :data:`MAX_RANGE_LIMIT`), binary data, a line over :data:`MAX_LINE_BYTES`,
  a compressed stream that is cut short or damaged, or a decompressed size over the zstd bags'
  budget (:data:`~scan2terrain.readers._bag_source.MAX_ZSTD_RATIO`): one
  :class:`~scan2terrain.errors.InputError` naming the file and the line.
* **Times** are ``ipc_timestamp`` (UNIX seconds), converted to integer nanoseconds from the
  digits (not through a float: the Freiburg benchmark's relation files name scans by these
  stamps). Stamps are kept as logged; a record stamped earlier than one above it is counted
  (:attr:`Log.backward`), and a step back of more than :data:`MAX_BACKWARD_S` is refused: that
  is a clock step, or two logs joined, and ordering such records by time would interleave two
  stretches of the run.
"""

from __future__ import annotations

import bz2
import gzip
import io
import math
import re
import zlib
from collections import Counter
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError
from scan2terrain.readers._bag_source import MAX_ZSTD_RATIO, MIN_ZSTD_BUDGET

#: Laser records -> the laser they come from.
LASER_SIDES = {"FLASER": "front", "RLASER": "rear", "ROBOTLASER1": "front", "ROBOTLASER2": "rear"}
#: Beams of one scan: more is not a 2D laser scanner (``n`` is also what is allocated).
MAX_BEAMS = 100_000
#: metres: a maximum range beyond this is not a 2D laser scanner's.
MAX_RANGE_LIMIT = 1000.0
#: A line longer than this (bytes) is refused before it is split.
MAX_LINE_BYTES = 4 << 20
#: Bytes decompressed at a time.
BLOCK_BYTES = 1 << 20
#: seconds: a record stamped this much earlier than a record above it is refused.
MAX_BACKWARD_S = 10.0
_TRAILER = 3  # ipc_timestamp host logger_timestamp
_STAMP = re.compile(rb"(\d+)(?:\.(\d*))?")
_NAME = re.compile(rb"[A-Za-z][A-Za-z0-9_]*")
#: Bytes a record line may hold: printable ASCII and whitespace.
_TEXT = bytes(range(0x20, 0x7F)) + b"\t\r\n\f\v"
_MAGIC_GZIP = b"\x1f\x8b"
_MAGIC_BZ2 = b"BZh"


# --- what a log holds ------------------------------------------------------------------------


@dataclass(frozen=True)
class Lasers:
    """The records of one laser record type, in line order.

    Attributes
    ----------
    kind : str
        ``FLASER``, ``RLASER``, ``ROBOTLASER1`` or ``ROBOTLASER2``.
    lines : int64 (K,)
        Line number of each record (1-based).
    stamps_ns : int64 (K,)
        ``ipc_timestamp``, UNIX nanoseconds.
    offsets : int64 (K + 1,)
        Record k's readings are ``ranges[offsets[k]:offsets[k + 1]]``.
    ranges : float32 (sum of counts,)
        Metres, as logged.
    laser_poses, odom_poses : float64 (K, 3)
        x, y (metres), theta (radians) of the laser and of the robot (odometry).
    config : float64 (K, 5)
        ROBOTLASER records: laser_type, start_angle, fov, angular_resolution, maximum_range;
        NaN for FLASER / RLASER (the geometry comes from the PARAMs).
    """

    kind: str
    lines: NDArray[np.int64]
    stamps_ns: NDArray[np.int64]
    offsets: NDArray[np.int64]
    ranges: NDArray[np.float32]
    laser_poses: NDArray[np.float64]
    odom_poses: NDArray[np.float64]
    config: NDArray[np.float64]

    def __len__(self) -> int:
        return len(self.stamps_ns)

    @property
    def counts(self) -> NDArray[np.int64]:
        """Readings per record."""
        return np.diff(self.offsets)


@dataclass(frozen=True)
class Odom:
    """The ODOM records: ``lines`` (K,), ``stamps_ns`` (K,), ``poses`` (K, 3) x y theta."""

    lines: NDArray[np.int64]
    stamps_ns: NDArray[np.int64]
    poses: NDArray[np.float64]

    def __len__(self) -> int:
        return len(self.stamps_ns)


@dataclass(frozen=True)
class Log:
    """A parsed CARMEN log.

    Attributes
    ----------
    lasers : dict of str to Lasers
        Per laser record type present (``FLASER``...), in the order of their first line.
    odom : Odom or None
        The ODOM records, when there are some.
    params : dict of str to tuple of (str, int)
        PARAM name -> (its first value, its line).
    skipped : dict of str to int
        Records of other types, per type.
    lines : int
        Lines in the log.
    backward : dict of str to (int, float)
        Per record type (laser types, ODOM) whose timestamps step back: how many records are
        stamped earlier than a record of their type above them, and the largest step back in
        seconds. Types are compared apart: a log interleaves records from several clocks.
    """

    lasers: dict[str, Lasers]
    odom: Odom | None
    params: dict[str, tuple[str, int]]
    skipped: dict[str, int]
    lines: int
    backward: dict[str, tuple[int, float]] = field(default_factory=dict)

    def param(self, path: Path, name: str) -> float | None:
        """A PARAM's value as a finite number, or None when the log does not set it.

        Raises
        ------
        InputError
            The value is not a finite number (naming its line).
        """
        found = self.params.get(name)
        if found is None:
            return None
        value, line = found
        try:
            number = float(value)
        except ValueError:
            number = math.nan
        if not math.isfinite(number):
            raise InputError(path, f"line {line}: PARAM {name} {value!r} is not a finite number")
        return number


# --- reading the text ------------------------------------------------------------------------


def compression(path: Path) -> str | None:
    """``gzip`` or ``bz2`` from a file's first bytes, else None."""
    with path.open("rb") as f:
        head = f.read(3)
    if head.startswith(_MAGIC_GZIP):
        return "gzip"
    if head.startswith(_MAGIC_BZ2):
        return "bz2"
    return None


def open_text(path: Path) -> io.BufferedIOBase:
    """The log's bytes, decompressed as they are read."""
    kind = compression(path)
    if kind == "gzip":
        return gzip.open(path, "rb")
    if kind == "bz2":
        return bz2.open(path, "rb")
    return path.open("rb")


def _blocks(f: io.BufferedIOBase) -> Iterator[bytes]:
    """The stream's bytes, at most :data:`BLOCK_BYTES` at a time (what one read of the file
    gives: a cut-short stream fails after the blocks before the cut), the next block read (and
    decompressed: bz2 and zlib release the GIL) in a thread while this one is parsed."""
    with ThreadPoolExecutor(max_workers=1) as reader:
        ahead = reader.submit(f.read1, BLOCK_BYTES)
        while block := ahead.result():
            ahead = reader.submit(f.read1, BLOCK_BYTES)
            yield block


def _lines(path: Path) -> Iterator[tuple[int, bytes]]:
    """``(line number, line)`` of the decompressed text, checked for size as it goes."""
    kind = compression(path)
    budget = max(MIN_ZSTD_BUDGET, MAX_ZSTD_RATIO * path.stat().st_size) if kind else None
    total = 0
    number = 0
    carry = b""
    try:
        with open_text(path) as f:
            for block in _blocks(f):
                total += len(block)
                if budget is not None and total > budget:
                    raise InputError(
                        path,
                        f"decompresses to more than {budget:,} bytes, {MAX_ZSTD_RATIO} times its "
                        "size: a decompression bomb? If the file is trusted, decompress it and "
                        "give the result",
                    )
                lines = (carry + block).split(b"\n")
                carry = lines.pop()
                if len(carry) > MAX_LINE_BYTES:
                    raise InputError(
                        path,
                        f"line {number + len(lines) + 1} is longer than {MAX_LINE_BYTES:,} bytes: "
                        "not a CARMEN log",
                    )
                for line in lines:
                    number += 1
                    yield number, line
    except (EOFError, OSError, zlib.error) as exc:
        what = {"gzip": "gzip", "bz2": "bzip2"}.get(kind or "", "")
        problem = "cut short" if isinstance(exc, EOFError) else f"damaged ({exc})"
        where = f"after line {number}" if number else "at its start"
        raise InputError(
            path, f"the {what} stream is {problem} {where}" if what else f"cannot be read ({exc})"
        ) from exc
    if carry:
        yield number + 1, carry


# --- one line ---------------------------------------------------------------------------------


class _Line:
    """One record line being parsed: its number, fields, and errors that name them."""

    __slots__ = ("fields", "kind", "number", "path")

    def __init__(self, path: Path, number: int, fields: list[bytes]) -> None:
        self.path, self.number, self.fields = path, number, fields
        self.kind = fields[0].decode()

    def error(self, problem: str) -> InputError:
        return InputError(self.path, f"line {self.number}: {self.kind} {problem}")

    def count(self, at: int, what: str) -> int:
        """The integer field ``at`` (a count of ``what``), checked."""
        if at >= len(self.fields):
            raise self.error(f"is cut short (no count of {what})")
        token = self.fields[at]
        if not token.isdigit():
            raise self.error(f"count of {what} {token.decode(errors='replace')!r} is not a count")
        n = int(token)
        if n > MAX_BEAMS:
            raise self.error(f"says {n:,} {what}: more than {MAX_BEAMS:,}, not a 2D laser scan")
        return n

    def expect(self, size: int, layout: str) -> None:
        if len(self.fields) != size:
            short = "is cut short: " if len(self.fields) < size else ""
            raise self.error(f"{short}has {len(self.fields)} fields, expected {size} ({layout})")

    def numbers(self, start: int, stop: int) -> NDArray[np.float64]:
        """Fields ``start:stop`` as float64, every one a number."""
        part = self.fields[start:stop]
        try:
            return np.array(part, dtype=np.float64)
        except ValueError:
            for k, token in enumerate(part):
                try:
                    float(token)
                except ValueError:
                    text = token.decode(errors="replace")
                    raise self.error(f"field {start + k + 1} {text!r} is not a number") from None
            raise  # pragma: no cover - numpy and float agree on what a number is

    def stamp(self, at: int) -> int:
        """``ipc_timestamp`` (field ``at``) in nanoseconds, from its digits."""
        token = self.fields[at]
        match = _STAMP.fullmatch(token)
        if match is not None:
            frac = (match.group(2) or b"")[:9].ljust(9, b"0")
            return int(match.group(1)) * 1_000_000_000 + int(frac)
        try:
            value = float(token)
        except ValueError:
            value = math.nan
        if not (math.isfinite(value) and 0 <= value < 1e11):
            raise self.error(
                f"ipc_timestamp {token.decode(errors='replace')!r} is not a time in seconds"
            )
        return round(value * 1e9)

    def finite(self, values: NDArray[np.float64], what: str) -> None:
        if not np.isfinite(values).all():
            raise self.error(f"has a {what} that is not finite")


class _Builder:
    """A laser record type's records as they are read."""

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self.lines: list[int] = []
        self.stamps: list[int] = []
        self.counts: list[int] = []
        self.ranges: list[NDArray[np.float32]] = []
        self.poses: list[NDArray[np.float64]] = []  # laser x y theta, odometry x y theta
        self.config: list[NDArray[np.float64]] = []

    def add(
        self,
        line: _Line,
        ranges: NDArray[np.float64],
        poses: NDArray[np.float64],
        stamp: int,
        config: NDArray[np.float64],
    ) -> None:
        line.finite(poses, "pose value")
        with np.errstate(invalid="ignore"):
            bad = ~(ranges >= 0) | ~np.isfinite(ranges)
        if bad.any():
            k = int(np.argmax(bad))
            raise line.error(f"reading {k + 1} is {float(ranges[k])!r}: not a range (finite, >= 0)")
        self.lines.append(line.number)
        self.stamps.append(stamp)
        self.counts.append(ranges.size)
        self.ranges.append(ranges.astype(np.float32))
        self.poses.append(poses)
        self.config.append(config)

    def build(self) -> Lasers:
        poses = np.array(self.poses, dtype=np.float64).reshape(-1, 6)
        return Lasers(
            kind=self.kind,
            lines=np.array(self.lines, dtype=np.int64),
            stamps_ns=np.array(self.stamps, dtype=np.int64),
            offsets=np.concatenate([[0], np.cumsum(self.counts, dtype=np.int64)]),
            ranges=np.concatenate(self.ranges) if self.ranges else np.zeros(0, np.float32),
            laser_poses=np.ascontiguousarray(poses[:, :3]),
            odom_poses=np.ascontiguousarray(poses[:, 3:]),
            config=np.array(self.config, dtype=np.float64).reshape(-1, 5),
        )


_NO_CONFIG = np.full(5, np.nan)


def _old_laser(line: _Line, builder: _Builder) -> None:
    """``FLASER`` / ``RLASER``: n, n ranges, laser pose, odometry pose, trailer."""
    n = line.count(1, "readings")
    if n == 0:
        raise line.error("has no readings (count 0)")
    line.expect(
        2 + n + 6 + _TRAILER,
        f"the count, {n} readings, 6 pose values, ipc_timestamp host logger_timestamp",
    )
    values = line.numbers(2, 2 + n + 6)
    builder.add(line, values[:n], values[n:], line.stamp(2 + n + 6), _NO_CONFIG)


def _robot_laser(line: _Line, builder: _Builder) -> None:
    """``ROBOTLASER1/2``: config, n ranges, m remissions, laser pose, robot pose, 5 more."""
    n = line.count(8, "readings")
    if n == 0:
        raise line.error("has no readings (count 0)")
    m = line.count(9 + n, "remissions")
    layout = (
        f"7 config values, the count, {n} readings, the count, {m} remissions, 6 pose values, "
        "tv rv forward_safety side_safety turn_axis, ipc_timestamp host logger_timestamp"
    )
    line.expect(1 + 7 + 1 + n + 1 + m + 6 + 5 + _TRAILER, layout)
    config = line.numbers(1, 8)
    line.finite(config, "configuration value")
    _laser_type, start, fov, res, max_range = config[:5]
    if abs(start) > 2 * math.pi:
        raise line.error(f"start_angle {start} rad is beyond a full turn")
    if not 0 < fov <= 2 * math.pi + 1e-6:
        raise line.error(f"field of view {fov} rad is not in (0, 2 pi]")
    if not 0 < res <= 2 * math.pi or (n - 1) * res > 2 * math.pi + res:
        raise line.error(f"angular resolution {res} rad over {n} readings is not a 2D scan")
    if not 0 < max_range <= MAX_RANGE_LIMIT:
        raise line.error(f"maximum range {max_range} m is not in (0, {MAX_RANGE_LIMIT:g}]")
    ranges = line.numbers(9, 9 + n)
    rest = line.numbers(10 + n, 10 + n + m + 11)
    line.finite(rest[:m], "remission")
    stamp = line.stamp(10 + n + m + 11)
    builder.add(line, ranges, rest[m : m + 6], stamp, config[:5])


def read_records(path: Path) -> Log:
    """Every record of a CARMEN log (see the module docstring).

    Raises
    ------
    InputError
        Damaged input (one line naming the file and the line), a log with no line, or a log
        with no laser record.
    """
    builders: dict[str, _Builder] = {}
    odom_lines: list[int] = []
    odom_stamps: list[int] = []
    odom_poses: list[NDArray[np.float64]] = []
    params: dict[str, tuple[str, int]] = {}
    skipped: Counter[str] = Counter()
    number = 0
    for number, raw in _lines(path):
        text = raw.lstrip()
        if not text or text.startswith(b"#"):
            continue
        if bad := raw.translate(None, _TEXT):
            raise InputError(
                path, f"line {number} holds binary data (byte 0x{bad[0]:02x}): not a CARMEN log"
            )
        fields = text.split()
        if not _NAME.fullmatch(fields[0]):
            word = fields[0][:20].decode(errors="replace")
            raise InputError(path, f"line {number}: {word!r} is not a CARMEN record type")
        kind = fields[0].decode()
        if kind in LASER_SIDES:
            line = _Line(path, number, fields)
            builder = builders.setdefault(kind, _Builder(kind))
            if kind.startswith("ROBOTLASER"):
                _robot_laser(line, builder)
            else:
                _old_laser(line, builder)
        elif kind == "ODOM":
            line = _Line(path, number, fields)
            line.expect(1 + 6 + _TRAILER, "x y theta tv rv accel ipc_timestamp host logger_time")
            values = line.numbers(1, 7)
            line.finite(values, "value")
            odom_lines.append(number)
            odom_stamps.append(line.stamp(7))
            odom_poses.append(values[:3])
        elif kind == "PARAM":
            if len(fields) >= 3:
                params.setdefault(fields[1].decode(), (fields[2].decode(), number))
            skipped[kind] += 1
        else:
            skipped[kind] += 1
    if number == 0:
        raise InputError(path, "the log is empty")
    if not builders:
        held = ", ".join(f"{k} {v}" for k, v in sorted(skipped.items()))
        if odom_lines:
            held = f"ODOM {len(odom_lines)}" + (f", {held}" if held else "")
        raise InputError(
            path,
            "no laser records (FLASER, RLASER, ROBOTLASER1, ROBOTLASER2): nothing to map; "
            f"the log holds {held or 'comments only'}",
        )
    streams = {k: (b.lines, b.stamps) for k, b in builders.items()}
    streams["ODOM"] = (odom_lines, odom_stamps)
    backward = {
        k: b
        for k, (lines, stamps) in streams.items()
        if (b := _backward(path, k, lines, stamps))[0]
    }
    odom = None
    if odom_lines:
        odom = Odom(
            np.array(odom_lines, dtype=np.int64),
            np.array(odom_stamps, dtype=np.int64),
            np.array(odom_poses, dtype=np.float64).reshape(-1, 3),
        )
    lasers = {k: b.build() for k, b in builders.items()}
    return Log(lasers, odom, params, dict(sorted(skipped.items())), number, backward)


def _backward(path: Path, kind: str, lines: list[int], stamps: list[int]) -> tuple[int, float]:
    """How many records of one type are stamped before a record of it above them, and the
    largest step back in seconds; a step back over :data:`MAX_BACKWARD_S` is refused."""
    t = np.array(stamps, dtype=np.int64)
    if t.size < 2:
        return 0, 0.0
    back = np.maximum.accumulate(t)[:-1] - t[1:]
    worst = int(np.argmax(back))
    largest = float(back[worst]) / 1e9
    if largest > MAX_BACKWARD_S:
        line = lines[worst + 1]
        raise InputError(
            path,
            f"line {line}: the {kind} timestamp goes {largest:.3f} s back (more than "
            f"{MAX_BACKWARD_S:g} s: a clock step, or two logs joined?); split the log there",
        )
    return int((back > 0).sum()), max(largest, 0.0)


# --- beam geometry ----------------------------------------------------------------------------

#: metres: CARMEN's maximum range for FLASER / RLASER records (``readlog.c``).
DEFAULT_RANGE_MAX = 80.0
#: metres: a SICK LMS / PLS (laser_type 0, 1; FLASER and RLASER are SICKs to CARMEN) reports
#: its error codes as 8183-8191 cm: readings from here up are no return (dazzle, no echo).
SICK_CODES = 81.83
#: A FLASER / RLASER log without ``robot_*_laser_max`` whose largest reading, below
#: :data:`DEFAULT_RANGE_MAX`, is this share of all its readings or more was capped at it: that
#: value is the log's no-return code (50.0 m on every ninetieth reading of the ACES log).
SATURATED_SHARE = 0.001
#: ... and at least this many readings (a short log's largest reading is no code).
SATURATED_MIN = 100


@dataclass(frozen=True)
class Geometry:
    """Per record of one laser: beam angles and range limits.

    Attributes
    ----------
    angle_min, angle_increment : float64 (K,)
        Radians: reading i at ``angle_min + i * angle_increment`` in the laser frame.
    range_max : float64 (K,)
        Metres: readings at or beyond it are no return (they clear, as a ROS LaserScan's do).
    spacing, limit : str
        Where the angles and the maximum range come from, for the plan's notes.
    """

    angle_min: NDArray[np.float64]
    angle_increment: NDArray[np.float64]
    range_max: NDArray[np.float64]
    spacing: str
    limit: str


def _guess_increment(n: NDArray[np.float64]) -> NDArray[np.float64]:
    """CARMEN's ``carmen_laser_guess_angle_increment``: radians between readings by count."""
    degrees = np.select(
        [np.isin(n, (180, 181)), np.isin(n, (360, 361)), np.isin(n, (400, 401))],
        [1.0, 0.5, 0.25],
        np.nan,
    )
    return np.where(np.isnan(degrees), math.pi / np.maximum(n - 1, 1), np.radians(degrees))


def geometry(path: Path, log: Log, lasers: Lasers) -> Geometry:
    """The beams of every record of ``lasers`` (see the module docstring).

    Raises
    ------
    InputError
        A PARAM that is not a number or is absurd (a field of view over 360 degrees...).
    """
    n = lasers.counts.astype(np.float64)
    k = len(lasers)
    if lasers.kind.startswith("ROBOTLASER"):
        c = lasers.config
        sick = np.isin(c[:, 0], (0, 1))
        given = c[:, 4]
        spacing = "from each record"
        limit = "each record's maximum range"
        angle_min, increment = c[:, 1].copy(), c[:, 3].copy()
    else:
        side = "front" if LASER_SIDES[lasers.kind] == "front" else "rear"
        fov = _param(path, log, f"laser_{side}_laser_fov", 360.0)
        res = _param(path, log, f"laser_{side}_laser_resolution", 360.0)
        if res is not None:
            increment = np.full(k, math.radians(res))
            spacing = f"PARAM laser_{side}_laser_resolution {res:g} deg"
        elif fov is not None:
            increment = math.radians(fov) / np.maximum(n - 1, 1)
            spacing = f"PARAM laser_{side}_laser_fov {fov:g} deg over each record's readings"
        else:
            increment = _guess_increment(n)
            spacing = "CARMEN's spacing for the count"
        start = -math.radians(fov) / 2 if fov is not None else -math.pi / 2
        if fov is not None:
            spacing += f", from {math.degrees(start):g} deg"
        angle_min = np.full(k, start)
        wide = (n - 1) * increment > 2 * math.pi + increment
        if wide.any():
            j = int(np.argmax(wide))
            raise InputError(
                path,
                f"line {lasers.lines[j]}: {lasers.kind} of {int(n[j])} readings "
                f"{math.degrees(increment[j]):g} deg apart spans more than 360 deg",
            )
        sick = np.ones(k, dtype=bool)
        name = f"robot_{side}_laser_max"
        top = _param(path, log, name, None, limit=MAX_RANGE_LIMIT)
        if top is not None:
            given = np.full(k, top)
            limit = f"PARAM {name}"
        else:
            given = np.full(k, DEFAULT_RANGE_MAX)
            limit = f"CARMEN's default, no PARAM {name}"
            r = lasers.ranges
            largest = float(r.max()) if r.size else 0.0
            at_top = int(np.count_nonzero(r == r.dtype.type(largest)))
            if largest < DEFAULT_RANGE_MAX and at_top >= max(
                SATURATED_MIN, SATURATED_SHARE * r.size
            ):
                given = np.full(k, largest)
                limit = (
                    f"no PARAM {name}; the log's largest reading, {at_top:,} times "
                    f"({at_top / r.size:.1%} of the readings): its no-return value"
                )
    capped = sick & (given > SICK_CODES)
    range_max = np.where(capped, SICK_CODES, given)
    if capped.any():
        limit += f"; {SICK_CODES} m and up are a SICK's error codes"
    return Geometry(angle_min, increment, range_max, spacing, limit)


def _param(
    path: Path, log: Log, name: str, degrees: float | None, *, limit: float | None = None
) -> float | None:
    """A positive PARAM (at most ``degrees`` for an angle, ``limit`` metres for a range)."""
    value = log.param(path, name)
    if value is None:
        return None
    top = degrees if degrees is not None else limit
    if not 0 < value <= (top if top is not None else math.inf):
        _, line = log.params[name]
        unit = "deg" if degrees is not None else "m"
        raise InputError(path, f"line {line}: PARAM {name} {value:g} is not in (0, {top:g}] {unit}")
    return value
