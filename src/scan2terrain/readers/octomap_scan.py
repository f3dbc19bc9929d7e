"""OctoMap's plain-text scan files (``scan.dat``, optionally ``.bz2``/``.gz``), as OctoMap's
``log2graph`` and ``ScanGraph::readPlainASCII`` read them.

Each ``NODE x y z roll pitch yaw`` line starts a scan taken at that sensor pose; the ``x y z``
lines after it are its points in the sensor frame. A file without NODE lines is one scan in the
map frame with the sensor at the origin (OctoMap's FR-079 ``scan.dat``).
"""

from __future__ import annotations

import bz2
import gzip
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError

SUFFIXES = (".dat", ".log", ".txt")
#: OctoMap's points are float32 (``point3d``): larger coordinates cannot be inserted.
_FLOAT32_MAX = float(np.finfo(np.float32).max)


@dataclass(frozen=True)
class PosedScan:
    """One scan: ``points`` float64 (N, 3) in the map frame, ``origin`` (3,) the sensor position."""

    points: NDArray[np.float64]
    origin: NDArray[np.float64]


def is_scan_file(path: Path) -> bool:
    name = path.name.lower()
    for packed in (".bz2", ".gz"):
        name = name.removesuffix(packed)
    return name.endswith(SUFFIXES)


def rotation(roll: float, pitch: float, yaw: float) -> NDArray[np.float64]:
    """OctoMap's pose6d rotation: yaw about z, then pitch about y, then roll about x."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def read_scans(path: Path) -> Iterator[PosedScan]:
    """Yield the scans of an OctoMap text scan file, one at a time, in the map frame."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "scan file not found")
    try:
        raw = path.read_bytes()
        if path.suffix == ".bz2":
            raw = bz2.decompress(raw)
        elif path.suffix == ".gz":
            raw = gzip.decompress(raw)
        text = raw.decode("ascii")
    except (OSError, EOFError, ValueError) as exc:
        raise InputError(path, f"cannot read as an OctoMap text scan file ({exc})") from None
    pose: tuple[float, ...] | None = None
    rows: list[str] = []
    first_line = 1
    count = 0
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        if stripped.upper().startswith("NODE"):
            if rows:
                yield _scan(path, rows, pose, first_line)
                count += 1
            pose = _pose(path, stripped, number)
            rows, first_line = [], number + 1
            continue
        rows.append(stripped)
    if rows:
        yield _scan(path, rows, pose, first_line)
        count += 1
    if count == 0:
        raise InputError(path, "no points in the scan file")


def _pose(path: Path, line: str, number: int) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in line.split()[1:])
    except ValueError:
        values = ()
    if len(values) != 6 or not all(math.isfinite(v) for v in values):
        raise InputError(path, f"line {number}: expected 'NODE x y z roll pitch yaw'")
    return values


def _scan(path: Path, rows: list[str], pose: tuple[float, ...] | None, first: int) -> PosedScan:
    try:
        pts = np.array([r.split() for r in rows], dtype=np.float64)
    except ValueError:
        bad = next(i for i, r in enumerate(rows) if len(r.split()) != 3 or not _numeric(r))
        raise InputError(
            path, f"line {first + bad}: expected 'x y z', got {rows[bad][:40]!r}"
        ) from None
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InputError(path, f"near line {first}: expected 3 numbers per point line")
    if pose is None:
        world, origin = pts, np.zeros(3)
    else:
        x, y, z, roll, pitch, yaw = pose
        with np.errstate(over="ignore", invalid="ignore"):  # checked just below
            world = pts @ rotation(roll, pitch, yaw).T + (x, y, z)
        origin = np.array([x, y, z])
    with np.errstate(invalid="ignore"):
        usable = (np.abs(world) <= _FLOAT32_MAX).all(axis=1)  # False for NaN and inf too
    if not usable.all():
        bad = int(np.argmin(usable))
        raise InputError(
            path,
            f"line {first + bad}: point {rows[bad][:40]!r} is not a finite float32 coordinate "
            "(OctoMap's point type) in the map frame",
        )
    return PosedScan(world, origin)


def _numeric(row: str) -> bool:
    try:
        [float(v) for v in row.split()]
    except ValueError:
        return False
    return True
