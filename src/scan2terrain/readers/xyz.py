"""XYZ-style text and CSV point files (``.xyz .xyzn .xyzrgb .pts .txt .csv``) -> float64 points.

``numpy.loadtxt`` (its C parser, no loop per row). A header line picks the x/y/z columns by name
(``x``, ``X``, ``"X"``, ``//X``, in any order); without one the first three columns are x, y, z.
Open3D skips unreadable lines silently and reads neither ``.txt`` nor ``.csv``.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError
from scan2terrain.readers._cloud_common import XYZ, loadtxt

TEXT_SUFFIXES = (".xyz", ".xyzn", ".xyzrgb", ".pts", ".txt", ".csv")

_HEADER_NAME = re.compile(r"^[\s\"'/#]*(.*?)[\s\"']*$")


def read_text(path: Path, suffix: str) -> tuple[NDArray[np.float64], str]:
    """x, y, z of every row of a text point file (non-finite ones kept) and its kind, the
    ``suffix`` without its dot; for :func:`~scan2terrain.readers.cloudfile.read_cloud`."""
    kind = suffix[1:]
    lines = _content_lines(path, 2)
    if not lines:
        raise InputError(path, "no points (only blank or comment lines)")
    (number, line), expected = lines[0], None
    delimiter = _delimiter(line)
    tokens = _split(line, delimiter)
    if kind == "pts" and len(tokens) == 1 and tokens[0].isdigit():
        # Leica-style .pts: a count line, then the points.
        expected = int(tokens[0])
        if len(lines) < 2:
            raise InputError(path, f"truncated: the .pts file says {expected} points, has none")
        number, line = lines[1]
        delimiter = _delimiter(line)
        tokens = _split(line, delimiter)
    if all(_is_number(t) for t in tokens):
        if len(tokens) < 3:
            raise InputError(path, f"line {number}: {len(tokens)} numbers, expected x y z")
        cols, skip = [0, 1, 2], number - 1
    else:
        names = [_HEADER_NAME.sub(r"\1", t).lower() for t in tokens]
        if not all(names.count(a) == 1 for a in XYZ):
            raise InputError(
                path,
                f"line {number} ({line.strip()[:60]!r}) is neither numbers nor a header naming "
                "one x, one y and one z column",
            )
        cols, skip = [names.index(a) for a in XYZ], number
    pts = loadtxt(path, path, cols, delimiter=delimiter, skiprows=skip)
    if expected is not None and len(pts) != expected:
        raise InputError(path, f"the .pts file says {expected} points, has {len(pts)}")
    return pts, kind


def _content_lines(path: Path, wanted: int) -> list[tuple[int, str]]:
    """The first ``wanted`` lines that are neither blank nor ``#`` comments, with their 1-based
    numbers (a loop over a few header lines, not over points)."""
    found: list[tuple[int, str]] = []
    try:
        with path.open(encoding="utf-8", newline=None) as text:
            for number, line in enumerate(text, start=1):
                stripped = line.strip()
                if stripped and not stripped.startswith("#"):
                    found.append((number, stripped))
                    if len(found) == wanted:
                        break
    except UnicodeDecodeError:
        raise InputError(path, "not a text file (not UTF-8)") from None
    return found


def _delimiter(line: str) -> str | None:
    for candidate in (",", ";"):
        if candidate in line:
            return candidate
    return None  # any whitespace


def _split(line: str, delimiter: str | None) -> list[str]:
    return [t.strip() for t in line.split(delimiter)]


def _is_number(token: str) -> bool:
    try:
        float(token.strip("\"'"))
    except ValueError:
        return False
    return True
