"""Points (e.g. occupied voxel centres) to PLY or PCD files, for viewers like CloudCompare/Open3D.

* ``.ply``: binary little endian, one ``vertex`` element with ``property double x/y/z``. Doubles
  keep map coordinates exact (float32 loses centimetres at UTM magnitudes); PLY readers in Open3D,
  PCL, CloudCompare and MeshLab read them.
* ``.pcd``: PCL's format v0.7, ``FIELDS x y z``, ``SIZE 4 4 4``, ``TYPE F F F`` (float32, what
  PCL's ``PointXYZ`` holds), ``DATA binary`` (little endian, 12 bytes per point), an unorganised
  cloud (``HEIGHT 1``) with the identity ``VIEWPOINT 0 0 0 1 0 0 0``.

Files are written under a temporary name in the target folder and renamed into place, and hold
nothing but the points (same points, same bytes).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from scan2terrain.fileio import atomic_write

FORMATS = (".ply", ".pcd")


def write_points(path: Path, points: NDArray[np.float64]) -> None:
    """Write :func:`points_bytes` for ``path``'s extension to ``path``, atomically."""
    atomic_write(Path(path), points_bytes(points, Path(path).suffix))


def points_bytes(points: NDArray[np.float64], suffix: str) -> bytes:
    """``points`` float64 (N, 3), metres, as a PLY or PCD file (``suffix`` ".ply" or ".pcd").

    Raises
    ------
    ValueError
        For another extension, or ``points`` that are not finite (N, 3) numbers.
    """
    if suffix.lower() not in FORMATS:
        raise ValueError(f"unsupported point cloud extension {suffix!r} (use .ply or .pcd)")
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
    else:
        header = (
            "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z\n"
            "SIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
            f"WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n"
        )
        body = np.ascontiguousarray(points, dtype="<f4").tobytes()
    return header.encode("ascii") + body
