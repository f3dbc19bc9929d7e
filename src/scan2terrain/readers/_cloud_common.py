"""What the PCD, PLY and XYZ-style readers share: numpy's text parser, byte-size checks, the rule
that turns a file's colour values into 8-bit RGB (:func:`rgb8`), and Open3D for the data numpy
cannot decode without a loop.

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
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError

XYZ = ("x", "y", "z")
_FD2_LOCK = threading.Lock()


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
