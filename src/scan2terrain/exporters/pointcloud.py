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

A whole :class:`~scan2terrain.types.Cloud` (``convert``) keeps what each format can hold of it
(:func:`cloud_bytes`), and says what it cannot (:attr:`CloudBytes.lost`):

* ``.pcd``: ``x y z`` as ``F 4`` where every coordinate is a float32 (a PCL cloud), else ``F 8``;
  each attribute a field of its own type, but ``intensity`` ``F 4`` (PCL's ``PointXYZI``; exact
  for LAS's 16 bits) and colour packed as PCL does (``rgb`` ``F 4``, ``0xFFRRGGBB``; ``rgba``
  ``U 4`` with an ``alpha``), 8 bits: 16-bit colour keeps its high byte. No CRS.
* ``.ply``: ``x y z`` ``float`` or ``double`` by the same rule; each attribute a vertex property
  of its own type (``uchar`` colour, ``ushort`` for 16 bits); 64-bit integers as ``double``.
  No CRS.
* ``.csv``: a header of the names, then the numbers (shortest repr, integers as integers). No
  CRS.
* ``.xyz``: points only.
* ``.las`` / ``.laz``: see ``_las.py`` (point format, scales, offsets, records and CRS kept).
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from scan2terrain.exporters._las import INT32_MAX, LAS_DATE, LAS_SCALE, las_bytes
from scan2terrain.exporters._numbers import float_texts
from scan2terrain.fileio import atomic_write
from scan2terrain.types import COLOUR_ATTRIBUTES, Cloud

FORMATS = (".ply", ".pcd", ".xyz", ".csv", ".las", ".laz")
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
    if len(points) and ((points.max(axis=0) - offsets) / LAS_SCALE > INT32_MAX - 1).any():
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
    data[LAS_DATE] = bytes(4)  # laspy always stamps today's date; 0 = unknown
    return bytes(data)


# --- whole clouds (convert) --------------------------------------------------------------------


class CloudBytes(NamedTuple):
    data: bytes | bytearray
    lost: tuple[str, ...]  #: what the format could not hold of the cloud, in words


#: PCD/PLY type names of numpy's types.
_PCD_TYPES = {"f": "F", "u": "U", "i": "I"}
_PLY_TYPES = {
    "u1": "uchar", "i1": "char", "u2": "ushort", "i2": "short", "u4": "uint", "i4": "int",
    "f4": "float", "f8": "double",
}  # fmt: skip


def write_cloud(path: Path, cloud: Cloud) -> tuple[str, ...]:
    """Write :func:`cloud_bytes` for ``path``'s extension to ``path``, atomically; what the
    format could not hold."""
    out = cloud_bytes(cloud, Path(path).suffix)
    atomic_write(Path(path), out.data)
    return out.lost


def cloud_bytes(cloud: Cloud, suffix: str) -> CloudBytes:
    """A cloud, its attributes and (LAS) its layout and CRS, as a point-cloud file of the type
    ``suffix`` names (one of :data:`FORMATS`, any case): what the module's docstring says each
    keeps, and what it could not hold.

    Raises
    ------
    ValueError
        For another extension, or (LAS/LAZ) points spanning more than int32 millimetres.
    """
    suffix = suffix.lower()
    if suffix not in FORMATS:
        raise ValueError(f"unsupported point cloud extension {suffix!r} (use {', '.join(FORMATS)})")
    if suffix in (".las", ".laz"):
        las = las_bytes(cloud, compress=suffix == ".laz")
        return CloudBytes(las.data, las.lost)
    lost = _records_lost(cloud)
    attrs = {k: np.asarray(v) for k, v in cloud.attributes.items() if np.ndim(v) == 1}
    if suffix == ".xyz":
        if attrs:
            names = ", ".join(_grouped_names(attrs))
            lost.insert(0, f"{names} (.xyz is x y z only: .csv, .ply and .pcd keep them)")
        return CloudBytes(points_bytes(cloud.points, suffix), tuple(lost))
    if suffix == ".csv":
        return CloudBytes(_csv_bytes(cloud.points, attrs), tuple(lost))
    double = not np.array_equal(cloud.points.astype(np.float32), cloud.points)
    write = _pcd_bytes if suffix == ".pcd" else _ply_bytes
    data, more = write(cloud.points, attrs, double)
    return CloudBytes(data, (*more, *lost))


def _records_lost(cloud: Cloud) -> list[str]:
    """A LAS cloud's records, which only LAS holds."""
    if cloud.las is None:
        return []
    lost = []
    crs, others = len(cloud.las.crs), len(cloud.las.vlrs) - len(cloud.las.crs)
    if crs:
        lost.append(f"the CRS ({crs} LAS record{'s' * (crs > 1)})")
    if others:
        lost.append(f"{others} other LAS record{'s' * (others > 1)}")
    if cloud.las.global_encoding & 1 and "gps_time" in cloud.attributes:
        lost.append("that gps_time is adjusted standard GPS time (LAS global encoding)")
    return lost


def _grouped_names(attrs: dict[str, Any]) -> list[str]:
    names = list(attrs)
    if all(c in names for c in COLOUR_ATTRIBUTES):
        at = names.index("red")
        names = [n for n in names if n not in COLOUR_ATTRIBUTES]
        names.insert(at, "red/green/blue")
    return names


def _colours(attrs: dict[str, NDArray[Any]]) -> NDArray[Any] | None:
    """The three colour attributes as one (N, 3) array, if all three are integers."""
    if not all(c in attrs for c in COLOUR_ATTRIBUTES):
        return None
    rgb = np.stack([attrs[c] for c in COLOUR_ATTRIBUTES], axis=1)
    return rgb if rgb.dtype.kind in "iu" else None


def _pcd_bytes(
    points: NDArray[np.float64], attrs: dict[str, NDArray[Any]], double: bool
) -> tuple[bytearray, list[str]]:
    lost: list[str] = []
    xyz = "<f8" if double else "<f4"
    fields: list[tuple[str, str]] = [("x", xyz), ("y", xyz), ("z", xyz)]  # name, numpy code
    values: dict[str, NDArray[Any]] = {}
    rgb = _colours(attrs)
    alpha = attrs.get("alpha")
    packed_at = -1
    if rgb is not None:
        if len(rgb) and rgb.max() > 255:
            lost.append("16-bit colour (PCD packs 8 bits: the high byte kept)")
            rgb = rgb >> 8
        rgb = rgb.astype(np.uint32)
        packs_alpha = alpha is not None and alpha.dtype == np.uint8
        a = alpha.astype(np.uint32) if packs_alpha and alpha is not None else np.uint32(255)
        values["rgba" if packs_alpha else "rgb"] = (
            a << 24 | rgb[:, 0] << 16 | rgb[:, 1] << 8 | rgb[:, 2]
        )
        packed_at = list(attrs).index("red")
    for k, (name, given) in enumerate(attrs.items()):
        v = given
        if k == packed_at:
            packed = "rgba" if "rgba" in values else "rgb"
            fields.append((packed, "<u4"))
        if name in COLOUR_ATTRIBUTES and packed_at >= 0:
            continue
        if name == "alpha" and "rgba" in values:
            continue
        if name == "intensity" and v.dtype.kind in "iu" and _exact(v, np.float32):
            v = v.astype(np.float32)  # PCL's PointXYZI
        code = v.dtype.str[1:] if v.dtype.kind in "fiu" else "f8"
        if v.dtype.kind == "f" and v.dtype.itemsize not in (4, 8):
            code = "f4"
        fields.append((name, "<" + code))
        values[name] = v
    types = " ".join("F" if n == "rgb" else _PCD_TYPES[np.dtype(c).kind] for n, c in fields)
    sizes = " ".join(str(np.dtype(c).itemsize) for _, c in fields)
    n = len(points)
    header = (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n"
        f"FIELDS {' '.join(name for name, _ in fields)}\nSIZE {sizes}\nTYPE {types}\n"
        f"COUNT {' '.join('1' * len(fields))}\n"
        f"WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n"
    ).encode("ascii")
    return _packed_rows(header, points, fields, values), lost


def _ply_bytes(
    points: NDArray[np.float64], attrs: dict[str, NDArray[Any]], double: bool
) -> tuple[bytearray, list[str]]:
    lost: list[str] = []
    xyz = "<f8" if double else "<f4"
    fields: list[tuple[str, str]] = [("x", xyz), ("y", xyz), ("z", xyz)]
    values: dict[str, NDArray[Any]] = {}
    rgb = _colours(attrs)
    eight = rgb is not None and (not len(rgb) or rgb.max() <= 255)
    for name, given in attrs.items():
        v = given
        if name in COLOUR_ATTRIBUTES and rgb is not None:
            v = v.astype(np.uint8 if eight else np.uint16)
        code = v.dtype.str[1:]
        if code not in _PLY_TYPES:
            if v.dtype.kind in "iu" and not _exact(v, np.float64):
                lost.append(f"{name} (64-bit integers beyond 2^53)")
                continue
            code = "f8"
        fields.append((name, "<" + code))
        values[name] = v
    props = "".join(f"property {_PLY_TYPES[c[1:]]} {name}\n" for name, c in fields)
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment scan2terrain points\n"
        f"element vertex {len(points)}\n{props}end_header\n"
    ).encode("ascii")
    return _packed_rows(header, points, fields, values), lost


def _packed_rows(
    header: bytes,
    points: NDArray[np.float64],
    fields: list[tuple[str, str]],
    values: dict[str, NDArray[Any]],
) -> bytearray:
    """``header`` and one packed record per point (``fields``: x, y, z then ``values``), in one
    buffer: the records are filled in place, column by column."""
    dtype = np.dtype(fields)
    out = bytearray(len(header) + len(points) * dtype.itemsize)
    out[: len(header)] = header
    rows = np.frombuffer(out, dtype=dtype, offset=len(header))
    for axis, name in enumerate("xyz"):
        rows[name] = points[:, axis]
    for name, v in values.items():
        rows[name] = v
    return out


def _exact(values: NDArray[Any], dtype: type[np.floating[Any]]) -> bool:
    return bool(np.array_equal(values.astype(dtype), values))


def _csv_bytes(points: NDArray[np.float64], attrs: dict[str, NDArray[Any]]) -> bytes:
    """A header of the names, then x, y, z and the attributes per line: floats as
    :func:`float_texts`, integers as integers."""
    names = ["x", "y", "z", *attrs]
    columns = [points[:, 0], points[:, 1], points[:, 2], *attrs.values()]
    line = ",".join("%d" if np.asarray(c).dtype.kind in "iu" else "%s" for c in columns) + "\n"
    blocks = [(",".join(names) + "\n").encode("ascii")]
    for start in range(0, len(points), _TEXT_BLOCK):  # bounds the temporary Python objects
        stop = min(start + _TEXT_BLOCK, len(points))
        table = np.empty((stop - start, len(columns)), dtype=object)
        for k, c in enumerate(columns):
            part = np.asarray(c[start:stop])
            table[:, k] = part.tolist() if part.dtype.kind in "iu" else float_texts(part)
        blocks.append(((line * len(table)) % tuple(table.ravel().tolist())).encode("ascii"))
    return b"".join(blocks)
