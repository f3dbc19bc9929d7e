"""Point-cloud files -> float64 points: PCD, PLY, XYZ-style text, CSV, LAS and LAZ.

:func:`read_cloud` picks the reader by the file's extension; which library reads what, and why,
is told in each reader's module:

* ``.pcd`` (``DATA ascii`` / ``binary`` / ``binary_compressed``): :mod:`.pcd`;
* ``.ply`` (ascii, binary of either byte order): :mod:`.ply`;
* ``.xyz .xyzn .xyzrgb .pts .txt .csv``: :mod:`.xyz`;
* ``.las .laz``: :mod:`.las` (which also streams point ranges and reads headers, from a path or
  a URL), its header and chunk table checked first by ``_las_layout.py``.

PCD and PLY are decoded with numpy where it can without a loop per point, and by Open3D
otherwise (``_cloud_common.py``: what the numpy-based readers share).

Points are returned as the file stores them (no ``VIEWPOINT`` or CRS applied, as PCL and Open3D
do); every problem is an :class:`InputError` naming the file.

Colours are read only when asked for (``read_cloud(..., colours=True)``: they cost memory and
time), as 8-bit RGB aligned with the points, from LAS point formats with colour (2, 3, 5, 7, 8,
10), PLY ``red/green/blue``, PCD ``rgb``/``rgba`` (PCL's packing) and text files whose colour
columns are known; how each format's values become 8 bits is told in its reader.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError
from scan2terrain.readers._files import regular_file
from scan2terrain.readers.las import LAS_SUFFIXES, class_codes, read_las
from scan2terrain.readers.pcd import read_pcd
from scan2terrain.readers.ply import read_ply
from scan2terrain.readers.xyz import TEXT_SUFFIXES, read_text

SUFFIXES = (".pcd", ".ply", *LAS_SUFFIXES, *TEXT_SUFFIXES)


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
    colours : uint8 array, shape (N, 3), or None
        Red, green, blue (0..255) of each point, row for row with ``points``; None unless
        colours were asked for and the file has them.
    """

    points: NDArray[np.float64]
    path: Path
    format: str
    records: int
    colours: NDArray[np.uint8] | None = None


def read_cloud(
    path: Path | str, *, las_classes: Collection[int] | None = None, colours: bool = False
) -> Cloud:
    """Read the points of a point-cloud file, chosen by its extension (case-insensitive).

    Parameters
    ----------
    path : Path or str
        A ``.pcd``, ``.ply``, ``.las``, ``.laz``, ``.xyz``, ``.xyzn``, ``.xyzrgb``, ``.pts``,
        ``.txt`` or ``.csv`` file.
    las_classes : collection of int, optional
        Keep only LAS points of these classification codes (e.g. ``(2,)``, ground). LAS/LAZ
        only.
    colours : bool, default False
        Also read the points' colours, where the file has them (:attr:`Cloud.colours`; None
        where it has none). LAS/LAZ: 16-bit values, used as they are if every one in the file
        is <= 255 (many writers store 8-bit colour unscaled), else their high byte. PLY:
        ``uchar`` as stored, ``ushort`` by the LAS rule, ``float``/``double`` 0..1 times 255.
        PCD: ``rgb``/``rgba`` unpacked as PCL packs them. Text: only known colour columns (a
        header naming red/green/blue or r/g/b; ``.xyzrgb`` columns 4-6, 0..1; a 7-column
        ``.pts``, columns 5-7).

    Returns
    -------
    Cloud
        The finite points, float64 (N, 3), N >= 1, and their colours if asked for.

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
    classes = None if las_classes is None else class_codes(path, suffix, las_classes)
    try:
        if size == 0:
            raise InputError(path, "empty file")
        if suffix == ".pcd":
            raw, rgb, fmt = read_pcd(path, colours=colours)
        elif suffix == ".ply":
            raw, rgb, fmt = read_ply(path, colours=colours)
        elif suffix in LAS_SUFFIXES:
            raw, rgb, fmt = read_las(path, classes, colours=colours)
        else:
            raw, rgb, fmt = read_text(path, suffix, colours=colours)
    except OSError as exc:
        raise InputError(path, f"cannot read the file ({exc.strerror or exc})") from exc
    finite = np.isfinite(raw).all(axis=1)
    everywhere = bool(finite.all())
    points = raw if everywhere else raw[finite]
    if len(points) == 0:
        detail = "no points" if len(raw) == 0 else f"all {len(raw)} points are NaN or infinite"
        raise InputError(path, f"no finite point in the cloud ({detail})")
    if rgb is not None:
        rgb = np.ascontiguousarray(rgb if everywhere else rgb[finite], dtype=np.uint8)
    return Cloud(np.ascontiguousarray(points, dtype=np.float64), path, fmt, len(raw), rgb)
