"""sensor_msgs/PointCloud2 messages -> numpy points, without a Python loop per point.

A PointCloud2 is a table of ``height x width`` records of ``point_step`` bytes each, rows
``row_step`` bytes apart (rows may carry padding); ``fields`` say where each named value sits in a
record. The message's bytes are mapped as a strided numpy structured array (one record per point,
``strides=(row_step, point_step)``), which reads padded rows and unused bytes in place; only the
requested fields are then gathered. This is what ROS 2's ``sensor_msgs_py.point_cloud2`` does,
without depending on a ROS installation.

Works on the message objects rosbags deserialises (``data`` a uint8 numpy array) and on any object
with the same attributes (``data`` may also be ``bytes``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError
from scan2terrain.readers._limits import MAX_COORDINATE_M

#: sensor_msgs/PointField datatypes -> numpy type codes (byte order added per message).
DATATYPES: dict[int, str] = {
    1: "i1",  # INT8
    2: "u1",  # UINT8
    3: "i2",  # INT16
    4: "u2",  # UINT16
    5: "i4",  # INT32
    6: "u4",  # UINT32
    7: "f4",  # FLOAT32
    8: "f8",  # FLOAT64
}

_XYZ = ("x", "y", "z")
#: The largest point_step a numpy dtype can have.
_MAX_POINT_STEP = 2**31 - 1


def pointcloud2_xyz(msg: Any) -> NDArray[np.float64]:
    """The finite points of a PointCloud2, in its ``header.frame_id`` frame.

    Parameters
    ----------
    msg : sensor_msgs/msg/PointCloud2
        As rosbags deserialises it, or any object with ``height``, ``width``, ``fields`` (each
        with ``name``, ``offset``, ``datatype``, ``count``), ``is_bigendian``, ``point_step``,
        ``row_step`` and ``data``.

    Returns
    -------
    float64 array, shape (N, 3)
        x, y, z in metres, row-major over an organised cloud (row 0 first); points with any
        non-finite coordinate are dropped. An empty cloud gives shape (0, 3) whatever its fields.

    Raises
    ------
    InputError
        Without x, y or z fields; two fields of one name; a field with an unknown datatype, a
        count other than 1, or not fitting in ``point_step``; ``row_step`` shorter than a row;
        ``data`` shorter than the declared points; a finite coordinate beyond
        ``MAX_COORDINATE_M`` (readers/_limits.py).
    """
    if int(msg.height) * int(msg.width) == 0:
        return np.zeros((0, 3))
    records = _records(msg, _XYZ)
    xyz = np.empty((records.size, 3))
    # A signalling NaN raises the "invalid" flag as it is widened; it is dropped below.
    with np.errstate(invalid="ignore"):
        for axis, name in enumerate(_XYZ):  # three strided gathers, not a loop over points
            xyz[:, axis] = records[name].reshape(-1)
    # Hot path (every scan of a bag): numpy's per-row reductions over 3 columns (`all(axis=1)`)
    # and 2-D boolean indexing each cost ~10x a flat pass. A sum is finite only if every term
    # is (inf and NaN never turn finite), so one flat sum clears a dense cloud without a mask
    # or a copy; a non-finite sum (a NaN point, or float64 values overflowing) takes the exact
    # path.
    with np.errstate(over="ignore", invalid="ignore"):  # inf - inf, huge float64: expected
        total = xyz.sum()
    if not np.isfinite(total):
        finite = np.isfinite(xyz)
        xyz = np.compress(finite[:, 0] & finite[:, 1] & finite[:, 2], xyz, axis=0)
    _check_reach(xyz)
    return xyz


def _check_reach(xyz: NDArray[np.float64]) -> None:
    """Refuse a finite coordinate beyond MAX_COORDINATE_M (a cloud flagged big-endian whose
    floats are little-endian reads as 3e38 m): two reductions, the point found only then."""
    if len(xyz) == 0 or max(float(xyz.max()), -float(xyz.min())) <= MAX_COORDINATE_M:
        return
    row, axis = divmod(int(np.flatnonzero(np.abs(xyz) > MAX_COORDINATE_M)[0]), 3)
    raise InputError(
        None,
        f"PointCloud2 point {row}: {_XYZ[axis]} = {xyz[row, axis]:.6g} m makes no sense: its "
        f"size must be within {MAX_COORDINATE_M:g} m",
    )


def pointcloud2_fields(msg: Any, names: Sequence[str]) -> dict[str, NDArray[Any]]:
    """Values of the named fields, row for row with :func:`pointcloud2_xyz`.

    Parameters
    ----------
    msg : sensor_msgs/msg/PointCloud2
        As for :func:`pointcloud2_xyz`.
    names : sequence of str
        Field names, e.g. ``("intensity", "ring")``.

    Returns
    -------
    dict of name -> array
        Each in the field's own type (native byte order), shape (N,), or (N, count) for fields
        with ``count > 1``; row i belongs to point i of ``pointcloud2_xyz(msg)`` (points with a
        non-finite coordinate are dropped here too).

    Raises
    ------
    InputError
        As :func:`pointcloud2_xyz`, and for a missing named field.
    """
    wanted = tuple(dict.fromkeys((*_XYZ, *names)))
    records = _records(msg, wanted).reshape(-1)
    if records.size == 0:
        keep = np.zeros(0, dtype=bool)
    else:
        keep = np.ones(records.size, dtype=bool)
        for name in _XYZ:
            keep &= np.isfinite(records[name])
    out: dict[str, NDArray[Any]] = {}
    for name in names:
        column = records[name][keep]
        out[name] = column.astype(column.dtype.newbyteorder("="))
    return out


def _records(msg: Any, names: Sequence[str]) -> NDArray[np.void]:
    """The message's points as a structured array (height, width) holding ``names`` only: a view
    of ``msg.data`` (strided over row padding), not a copy."""
    height, width = int(msg.height), int(msg.width)
    point_step, row_step = int(msg.point_step), int(msg.row_step)
    if height < 0 or width < 0:
        raise InputError(None, f"PointCloud2 has a negative size {height} x {width}")
    if point_step > _MAX_POINT_STEP:  # numpy's dtypes are at most 2^31 - 1 bytes
        raise InputError(None, f"PointCloud2 point_step {point_step} is not a point's size")
    dtype = _dtype(msg, names, point_step)
    if height * width == 0:
        return np.zeros((height, width), dtype=dtype)
    row_bytes = width * point_step
    if height == 1:
        # One row: row_step is irrelevant (some drivers leave it 0).
        row_step = row_bytes
    elif row_step < row_bytes:
        raise InputError(
            None,
            f"PointCloud2 row_step {row_step} is shorter than a row "
            f"({width} points x {point_step} bytes = {row_bytes})",
        )
    data = _as_bytes(msg.data)
    need = (height - 1) * row_step + row_bytes
    if data.size < need:
        raise InputError(
            None,
            f"PointCloud2 data holds {data.size} bytes, but {height} x {width} points of "
            f"{point_step} bytes (row_step {row_step}) need {need}",
        )
    records: NDArray[np.void] = np.ndarray(
        (height, width), dtype=dtype, buffer=data, offset=0, strides=(row_step, point_step)
    )
    return records


def _dtype(msg: Any, names: Sequence[str], point_step: int) -> np.dtype[np.void]:
    """A structured dtype of ``point_step`` bytes holding the named fields at their offsets."""
    fields = list(msg.fields)
    found: dict[str, Any] = {}
    seen: set[str] = set()
    for field in fields:  # a handful of fields, not points
        name = str(field.name)
        # Two fields of one name: which one is x (or intensity) would be an accident. PCL's
        # padding fields are all named "_".
        if name in seen and name != "_":
            raise InputError(None, f"PointCloud2 has two fields named {name!r}")
        seen.add(name)
        if name in names:
            found[name] = field
    missing = [n for n in names if n not in found]
    if missing:
        have = ", ".join(str(f.name) for f in fields) or "none"
        raise InputError(
            None, f"PointCloud2 has no field {', '.join(missing)} (its fields: {have})"
        )
    order = ">" if bool(msg.is_bigendian) else "<"
    formats: list[np.dtype[Any]] = []
    offsets: list[int] = []
    for name in names:
        field = found[name]
        code = DATATYPES.get(int(field.datatype))
        if code is None:
            raise InputError(
                None,
                f"PointCloud2 field {name!r} has unknown datatype {field.datatype} "
                "(sensor_msgs/PointField knows 1..8)",
            )
        # count 0 occurs in the wild and means one value, as in PCL's conversions.
        count = max(int(field.count), 1)
        if count > 1 and name in _XYZ:
            raise InputError(None, f"PointCloud2 field {name!r} has count {count}, expected 1")
        fmt = np.dtype(order + code) if count == 1 else np.dtype((order + code, (count,)))
        offset = int(field.offset)
        if offset < 0 or offset + fmt.itemsize > point_step:
            raise InputError(
                None,
                f"PointCloud2 field {name!r} (bytes {offset}..{offset + fmt.itemsize}) does not "
                f"fit in point_step {point_step}",
            )
        formats.append(fmt)
        offsets.append(offset)
    return np.dtype(
        {"names": list(names), "formats": formats, "offsets": offsets, "itemsize": point_step}
    )


def _as_bytes(data: Any) -> NDArray[np.uint8]:
    if isinstance(data, (bytes, bytearray, memoryview)):
        return np.frombuffer(data, dtype=np.uint8)
    return np.ascontiguousarray(data, dtype=np.uint8)
