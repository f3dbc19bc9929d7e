"""What the cloud readers share: what a reader returns (:class:`Decoded`), the names and types of
point attributes (:func:`attribute_name`, :func:`narrowed`, :func:`colour_values`), numpy's text
parser, byte-size checks, the rule that turns a file's colour values into 8-bit RGB
(:func:`rgb8`), and Open3D for the data numpy cannot decode without a loop.

Open3D is not used for everything because on bad input it prints to the console and returns no
points, or (short ASCII PCD/PLY data, truncated binary PLY; Open3D 0.20) returns uninitialised
memory as points; so sizes are checked before it is called wherever the header allows, its point
count afterwards, and its import (~1.5 s) is paid only when needed.
"""

from __future__ import annotations

import contextlib
import io
import os
import sys
import tempfile
import threading
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError
from scan2terrain.types import POINT_ATTRIBUTES, LasLayout

XYZ = ("x", "y", "z")
_FD2_LOCK = threading.Lock()
#: Known attribute names without their underscores -> the name (``gpstime`` -> ``gps_time``).
_KNOWN = {k.replace("_", ""): k for k in POINT_ATTRIBUTES} | {"infrared": "nir"}


@dataclass(frozen=True)
class Decoded:
    """What a cloud reader decoded: x, y, z of every record (non-finite ones kept), the
    colours as 8-bit RGB (if asked for and present), what was read (``"pcd binary"``), and when
    asked for every other field as :attr:`~scan2terrain.types.Cloud.attributes`,
    :attr:`~scan2terrain.types.Cloud.las` and :attr:`~scan2terrain.types.Cloud.unread` hold
    them."""

    points: NDArray[np.float64]
    colours: NDArray[np.uint8] | None
    format: str
    attributes: dict[str, NDArray[Any]] = field(default_factory=dict)
    las: LasLayout | None = None
    unread: tuple[str, ...] = ()


def attribute_name(name: str) -> str:
    """The :data:`~scan2terrain.types.POINT_ATTRIBUTES` name a file's field name stands for,
    in any case, with or without underscores, CloudCompare's ``scalar_`` prefix or spaces
    (``Intensity``, ``GpsTime``, ``scalar_Classification``, ``Infrared``); other names are
    kept as they are."""
    key = name.strip().lower()
    key = key.removeprefix("scalar_").replace("_", "").replace(" ", "")
    return _KNOWN.get(key, name.strip())


def attribute_names(names: list[str]) -> list[str | None]:
    """:func:`attribute_name` of each field; where two fields would get one name the later keeps
    its own, and None where that too is taken (a field of one name twice)."""
    out: list[str | None] = []
    for name in names:
        known = attribute_name(name)
        if known in out:
            known = name.strip()
        out.append(None if known in out or known in XYZ else known)
    return out


def narrowed(name: str, values: NDArray[Any]) -> NDArray[Any]:
    """``values`` (a text column, float64) as the integer type its
    :data:`~scan2terrain.types.POINT_ATTRIBUTES` name has, when every value is a whole number
    of that type's range; otherwise as they are."""
    code = POINT_ATTRIBUTES.get(name)
    if code is None or np.dtype(code).kind == "f" or values.dtype.kind != "f":
        return values
    info = np.iinfo(np.dtype(code))
    if not len(values) or not np.isfinite(values).all():
        return values
    whole = bool((values == np.round(values)).all())
    if whole and values.min() >= info.min and values.max() <= info.max:
        return values.astype(code)
    return values


def colour_values(values: NDArray[Any], *, fractions: bool = False) -> NDArray[Any] | None:
    """A colour channel as an attribute: 8 bits (uint8) or 16 bits (uint16) as stored.

    Integers of 8 or 16 bits are kept; other integers and whole floats within 0..255 become
    uint8, within 0..65535 uint16; floats within 0..1 that are not all whole, or any floats
    within 0..1 when ``fractions`` (the format says so), are fractions: ``round(v * 255)``.
    None for values that are none of these (negative, NaN, larger)."""
    arr = np.asarray(values)
    if arr.dtype in (np.uint8, np.uint16):
        return arr
    if arr.size == 0:
        return arr.astype(np.uint8)
    if arr.dtype.kind == "f":
        if not np.isfinite(arr).all():
            return None
        whole = bool((arr == np.round(arr)).all())
        if arr.min() >= 0.0 and arr.max() <= 1.0 and (fractions or not whole):
            return np.round(arr * 255.0).astype(np.uint8)
        if not whole:
            return None
    elif arr.dtype.kind not in "iu":
        return None
    low, high = float(arr.min()), float(arr.max())
    if low < 0 or high > 65535:
        return None
    return arr.astype(np.uint8 if high <= 255 else np.uint16)


def open3d_points(
    path: Path, expected: int, *, colours: bool = False
) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
    """Open3D's points for ``path``, which must hold ``expected`` of them, and (``colours``)
    Open3D's colours times 255, float64 (N, 3), or None where it read none.

    Times 255 gives back what the file stores: Open3D divides PLY ``red/green/blue`` of any type
    by 255 and unpacks a PCD ``rgb``/``rgba`` into bytes / 255; the caller turns the values into
    8-bit RGB (:func:`rgb8`).

    A PLY that RPly (Open3D's PLY parser) fails to read still comes back with the header's
    number of points, the unread ones uninitialised: RPly's complaint, which it prints to file
    descriptor 2 and reports nowhere else, is the only sign, so it is captured and refused.
    """
    import open3d

    utility = open3d.utility
    try:
        with _fd2_lines() as printed, utility.VerbosityContextManager(utility.VerbosityLevel.Error):
            cloud = open3d.io.read_point_cloud(
                path, remove_nan_points=False, remove_infinite_points=False
            )
    except RuntimeError as exc:  # Open3D raises its own errors as RuntimeError
        raise InputError(path, f"corrupt data: Open3D cannot read it ({exc})") from exc
    complaints = [line for line in printed if line.startswith("RPly")]
    if complaints:
        raise InputError(path, f"corrupt or truncated data ({complaints[0]})")
    points = np.array(cloud.points, dtype=np.float64).reshape(-1, 3)
    if len(points) != expected:
        raise InputError(
            path, f"corrupt data: the header says {expected} points, Open3D decoded {len(points)}"
        )
    rgb = None
    if colours and cloud.has_colors():
        rgb = np.asarray(cloud.colors, dtype=np.float64).reshape(-1, 3) * 255.0
        if len(rgb) != expected:
            raise InputError(
                path, f"corrupt data: {expected} points, Open3D decoded {len(rgb)} colours"
            )
    return points, rgb


def open3d_fields(path: Path, expected: int) -> dict[str, NDArray[Any]]:
    """Every field of a point-cloud file as Open3D's tensor reader decodes it, in its own type:
    ``positions`` (N, 3), ``colors`` (N, 3), ``normals`` (N, 3), any other by its name, (N,)
    where it is one value a point; the file must hold ``expected`` points."""
    import open3d

    utility = open3d.utility
    try:
        with utility.VerbosityContextManager(utility.VerbosityLevel.Error):
            cloud = open3d.t.io.read_point_cloud(path)
    except RuntimeError as exc:  # Open3D raises its own errors as RuntimeError
        raise InputError(path, f"corrupt data: Open3D cannot read it ({exc})") from exc
    out: dict[str, NDArray[Any]] = {}
    for name in cloud.point:
        values = cloud.point[name].numpy()
        if len(values) != expected:
            raise InputError(
                path, f"corrupt data: the header says {expected} points, Open3D decoded "
                f"{len(values)} {name}",
            )  # fmt: skip
        out[name] = values[:, 0] if values.ndim == 2 and values.shape[1] == 1 else values
    if "positions" not in out:
        raise InputError(path, f"corrupt data: the header says {expected} points, Open3D decoded 0")
    return out


@contextlib.contextmanager
def _fd2_lines() -> Iterator[list[str]]:
    """The lines C code writes to file descriptor 2 meanwhile (RPly's errors), captured in a
    temporary file; whatever else was written there is passed on to it afterwards. Where fd 2
    cannot be duplicated nothing is captured."""
    lines: list[str] = []
    with _FD2_LOCK:  # one capture at a time: nested ones in threads would misroute fd 2
        try:
            saved = os.dup(2)
        except OSError:
            yield lines
            return
        with tempfile.TemporaryFile() as tmp:
            sys.stderr.flush()
            os.dup2(tmp.fileno(), 2)
            try:
                yield lines
            finally:
                os.dup2(saved, 2)
                os.close(saved)
                tmp.seek(0)
                lines += tmp.read().decode("utf-8", "replace").splitlines()
                other = [ln for ln in lines if not ln.startswith("RPly")]
                if other:
                    os.write(2, ("\n".join(other) + "\n").encode())


def stack(records: NDArray[np.void]) -> NDArray[np.float64]:
    """The x, y, z fields of structured records as float64 (N, 3)."""
    out = np.empty((len(records), 3))
    # A signalling NaN in the file raises the "invalid" flag as it is widened; NaN points are
    # dropped by the caller, so that is no warning to print.
    with np.errstate(invalid="ignore"):
        for axis, name in enumerate(XYZ):  # three column copies
            out[:, axis] = records[name]
    return out


def need_bytes(path: Path, have: int, need: int, what: str) -> None:
    """Refuse a file of ``have`` bytes where ``what`` needs ``need``."""
    if have < need:
        raise InputError(path, f"truncated: {what} need {need} bytes, the file has {have}")


def decode_text(path: Path, data: bytes) -> str:
    """``data`` as UTF-8 text; InputError where it is not."""
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise InputError(path, "not a text file where text was expected (not UTF-8)") from None


def loadtxt(
    path: Path,
    source: Path | io.StringIO,
    cols: list[int],
    *,
    delimiter: str | None,
    skiprows: int,
    max_rows: int | None = None,
    comments: str | None = "#",
) -> NDArray[np.float64]:
    """Columns ``cols`` of a text table as float64 (N, len(cols)), through numpy's C parser:
    x, y, z first, then any colour columns."""
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
        raise InputError(path, f"not a table of numbers: {exc} (data rows counted from 0)") from exc
    return np.asarray(pts, dtype=np.float64).reshape(-1, len(cols))


def rgb8(values: NDArray[np.number], *, fractions: bool = False) -> NDArray[np.uint8]:
    """A file's colour values, (N, 3) of any numeric dtype, as 8-bit RGB (N, 3) uint8.

    One rule for the whole array (a file's colours, never a row at a time), so that one file's
    colours are scaled alike:

    * floats all within 0..1 (``fractions``: the format says floats are 0..1, as PLY ``float``
      properties and Open3D's ``.xyzrgb`` do; otherwise only where some value is not a whole
      number) are fractions of full scale: ``round(v * 255)``;
    * otherwise the values are rounded and clipped to 0..65535: if every one is <= 255 they are
      8-bit values, used as they are; else 16-bit ones, of which the high byte is kept
      (``v >> 8``), as LAS defines its colours.

    NaN counts as 0. Vectorised; no copy beyond the result's.
    """
    arr = np.asarray(values)
    if arr.dtype.kind == "f":
        arr = np.nan_to_num(arr, nan=0.0, posinf=65535.0, neginf=0.0)
        unit = arr.size > 0 and arr.min() >= 0.0 and arr.max() <= 1.0
        if unit and (fractions or not np.array_equal(arr, np.round(arr))):
            return np.round(arr * 255.0).astype(np.uint8)
        arr = np.clip(np.round(arr), 0, 65535).astype(np.uint16)
    elif arr.dtype.kind in "iu" and arr.size:
        arr = np.clip(arr, 0, 65535).astype(np.uint16)
    elif arr.dtype.kind not in "iu":
        raise ValueError(f"values must be numbers, got dtype {arr.dtype}")
    if arr.size and int(arr.max()) > 255:
        return (arr >> 8).astype(np.uint8)
    return arr.astype(np.uint8)
