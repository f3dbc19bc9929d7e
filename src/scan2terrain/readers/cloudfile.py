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
do); every problem is an :class:`InputError` naming the file. On request (``attributes=True``,
for ``convert``) every other per-point field comes too, named as LAS names it where it is one of
LAS's, and a LAS file's point format, scales, offsets and records (its CRS).

Colours are read only when asked for (``read_cloud(..., colours=True)``: they cost memory and
time), as 8-bit RGB aligned with the points, from LAS point formats with colour (2, 3, 5, 7, 8,
10), PLY ``red/green/blue``, PCD ``rgb``/``rgba`` (PCL's packing) and text files whose colour
columns are known; how each format's values become 8 bits is told in its reader.
"""

from __future__ import annotations

from collections.abc import Collection
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError
from scan2terrain.readers._files import regular_file
from scan2terrain.readers.las import LAS_SUFFIXES, class_codes, read_las
from scan2terrain.readers.pcd import read_pcd
from scan2terrain.readers.ply import read_ply
from scan2terrain.readers.xyz import TEXT_SUFFIXES, read_text
from scan2terrain.types import Cloud

__all__ = ["SUFFIXES", "Cloud", "merge_clouds", "read_cloud"]

SUFFIXES = (".pcd", ".ply", *LAS_SUFFIXES, *TEXT_SUFFIXES)


def read_cloud(
    path: Path | str,
    *,
    las_classes: Collection[int] | None = None,
    colours: bool = False,
    attributes: bool = False,
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
    attributes : bool, default False
        Also read every other per-point field (:attr:`Cloud.attributes`: intensity,
        classification, return numbers, GPS time, colour as stored, ...) and a LAS file's point
        format, scales, offsets and records, its CRS among them (:attr:`Cloud.las`), for
        ``convert``.

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
            got = read_pcd(path, colours=colours, attributes=attributes)
        elif suffix == ".ply":
            got = read_ply(path, colours=colours, attributes=attributes)
        elif suffix in LAS_SUFFIXES:
            got = read_las(path, classes, colours=colours, attributes=attributes)
        else:
            got = read_text(path, suffix, colours=colours, attributes=attributes)
    except OSError as exc:
        raise InputError(path, f"cannot read the file ({exc.strerror or exc})") from exc
    raw = got.points
    finite: NDArray[np.bool_] = np.asarray(np.isfinite(raw).all(axis=1))
    if not finite.any():
        detail = "no points" if len(raw) == 0 else f"all {len(raw)} points are NaN or infinite"
        raise InputError(path, f"no finite point in the cloud ({detail})")
    rgb = None if got.colours is None else np.ascontiguousarray(got.colours, dtype=np.uint8)
    cloud = Cloud(
        np.ascontiguousarray(raw, dtype=np.float64), path, got.format, len(raw), rgb,
        got.attributes, got.las, got.unread,
    )  # fmt: skip
    return cloud if finite.all() else cloud.take(finite)


def merge_clouds(clouds: list[Cloud]) -> tuple[Cloud, list[str]]:
    """Several files' clouds as one, in order, and what of them could not be kept, in words.

    The attributes every cloud has are kept (concatenated, in numpy's common type), the others
    are not; a LAS layout (point format, scales, offsets, records: the CRS) is kept where every
    cloud has the same records, as the first cloud's (a LAS writer checks that the points lie
    on its scales). One cloud is returned as it is.
    """
    if len(clouds) == 1:
        return clouds[0], []
    notes = []
    first = clouds[0]
    names = [k for k in first.attributes if all(k in c.attributes for c in clouds)]
    dropped = sorted({k for c in clouds for k in c.attributes} - set(names))
    if dropped:
        notes.append(f"not in every file, not kept: {', '.join(dropped)}")
    layouts = [c.las for c in clouds]
    las = first.las
    if las is not None and not all(o is not None and o.vlrs == las.vlrs for o in layouts):
        las = None
    if las is None and any(o is not None and o.vlrs for o in layouts):
        notes.append("the files' LAS records (the CRS) differ: none kept")
    colours = None
    if all(c.colours is not None for c in clouds):
        colours = np.concatenate([c.colours for c in clouds if c.colours is not None])
    merged = Cloud(
        points=np.concatenate([c.points for c in clouds]),
        path=first.path,
        format=", ".join(dict.fromkeys(c.format for c in clouds)),
        records=sum(c.records for c in clouds),
        colours=colours,
        attributes={k: np.concatenate([c.attributes[k] for c in clouds]) for k in names},
        las=las,
        unread=tuple(dict.fromkeys(u for c in clouds for u in c.unread)),
    )
    return merged, notes
