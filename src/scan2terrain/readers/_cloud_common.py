"""What the PCD, PLY and XYZ-style readers share: numpy's text parser, byte-size checks, and
Open3D for the data numpy cannot decode without a loop.

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


def open3d_points(path: Path, expected: int) -> NDArray[np.float64]:
    """Open3D's points for ``path``, which must hold ``expected`` of them.

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
    return points


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
    """x, y, z columns of a text table as float64 (N, 3), through numpy's C parser."""
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
    return np.asarray(pts, dtype=np.float64).reshape(-1, 3)
