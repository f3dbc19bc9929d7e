"""Points (e.g. occupied voxel centres) to point-cloud files, for viewers and GIS tools.

* ``.ply``: binary little endian, one ``vertex`` element with ``property double x/y/z``. Doubles
  keep map coordinates exact (float32 loses centimetres at UTM magnitudes); PLY readers in Open3D,
  PCL, CloudCompare and MeshLab read them.
* ``.pcd``: PCL's format v0.7, ``FIELDS x y z``, ``SIZE 4 4 4``, ``TYPE F F F`` (float32, what
  PCL's ``PointXYZ`` holds), ``DATA binary`` (little endian, 12 bytes per point), an unorganised
  cloud (``HEIGHT 1``) with the identity ``VIEWPOINT 0 0 0 1 0 0 0``.
* ``.xyz``: text, one ``x y z`` line per point; ``.csv``: a ``x,y,z`` header, then one line per
  point. Numbers are Python's shortest repr, which reads back to the same float64.
* ``.las`` / ``.laz``: LAS 1.2, point format 0 (the one every LAS reader knows), written by laspy
  (LAZ compressed by its lazrs backend). Coordinates are int32 counts of millimetres (scale 0.001)
  from an offset of ``floor(min)`` per axis, so UTM coordinates survive to the millimetre; the
  header's creation date is left 0 (unknown) so the bytes depend on the points only.

Files are written under a temporary name in the target folder and renamed into place, and hold
nothing but the points (same points, same bytes).
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from scan2terrain.exporters._numbers import float_texts
from scan2terrain.fileio import atomic_write

FORMATS = (".ply", ".pcd", ".xyz", ".csv", ".las", ".laz")
#: LAS coordinate resolution, metres.
LAS_SCALE = 0.001
_INT32_MAX = 2**31 - 1
#: Byte offset of the LAS header's creation day-of-year and year (two uint16).
_LAS_DATE = slice(90, 94)
#: Points formatted per block when writing text.
_TEXT_BLOCK = 1 << 16


def write_points(path: Path, points: NDArray[np.float64]) -> None:
    """Write :func:`points_bytes` for ``path``'s extension to ``path``, atomically."""
    atomic_write(Path(path), points_bytes(points, Path(path).suffix))


def points_bytes(points: NDArray[np.float64], suffix: str) -> bytes:
    """``points`` float64 (N, 3), metres, as a point-cloud file of the type ``suffix`` names.

    Parameters
    ----------
    points : float64 array, shape (N, 3)
        Finite coordinates, metres, map frame.
    suffix : str
        One of :data:`FORMATS` (case-insensitive).

    Raises
    ------
    ValueError
        For another extension, ``points`` that are not finite (N, 3) numbers, or (LAS/LAZ)
        points spanning more than int32 millimetres (2147 km) on an axis.
    """
    if suffix.lower() not in FORMATS:
        raise ValueError(f"unsupported point cloud extension {suffix!r} (use {', '.join(FORMATS)})")
    suffix = suffix.lower()
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] != 3 or not np.issubdtype(points.dtype, np.number):
        raise ValueError(f"points must be a (N, 3) number array, got {points.dtype} {points.shape}")
    if not np.isfinite(points).all():
        raise ValueError("points must be finite (no NaN or inf)")
    n = points.shape[0]
    if suffix == ".ply":
        header = (
            "ply\nformat binary_little_endian 1.0\ncomment scan2terrain points, metres\n"
            f"element vertex {n}\nproperty double x\nproperty double y\nproperty double z\n"
            "end_header\n"
        )
        body = np.ascontiguousarray(points, dtype="<f8").tobytes()
    elif suffix == ".pcd":
        header = (
            "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z\n"
            "SIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
            f"WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n"
        )
        body = np.ascontiguousarray(points, dtype="<f4").tobytes()
    elif suffix in (".xyz", ".csv"):
        header = "x,y,z\n" if suffix == ".csv" else ""
        sep = "," if suffix == ".csv" else " "
        body = _text_rows(points.astype(np.float64), sep)
    else:
        return _las_bytes(points.astype(np.float64), compress=suffix == ".laz")
    return header.encode("ascii") + body


def _text_rows(points: NDArray[np.float64], sep: str) -> bytes:
    """``x<sep>y<sep>z`` lines, numbers as :func:`float_texts`. One %-format per block of
    points (C code, no loop per point)."""
    line = f"%s{sep}%s{sep}%s\n"
    blocks = []
    for start in range(0, len(points), _TEXT_BLOCK):  # bounds the temporary Python strings
        texts = float_texts(points[start : start + _TEXT_BLOCK])
        blocks.append(((line * (len(texts) // 3)) % tuple(texts)).encode("ascii"))
    return b"".join(blocks)


def _las_bytes(points: NDArray[np.float64], *, compress: bool) -> bytes:
    import laspy  # type: ignore[import-untyped]

    offsets = np.floor(points.min(axis=0)) if len(points) else np.zeros(3)
    if len(points) and ((points.max(axis=0) - offsets) / LAS_SCALE > _INT32_MAX - 1).any():
        span = points.max(axis=0) - points.min(axis=0)
        raise ValueError(
            f"points span {span.max():.0f} m, more than LAS can hold at {LAS_SCALE} m (2147 km)"
        )
    header = laspy.LasHeader(point_format=0, version="1.2")
    header.scales = np.full(3, LAS_SCALE)
    header.offsets = offsets
    header.generating_software = "scan2terrain"
    las = laspy.LasData(header)
    las.x, las.y, las.z = points[:, 0], points[:, 1], points[:, 2]
    out = io.BytesIO()
    las.write(out, do_compress=compress)
    data = bytearray(out.getvalue())
    data[_LAS_DATE] = bytes(4)  # laspy always stamps today's date; 0 = unknown
    return bytes(data)
