"""XYZ-style text and CSV point files (``.xyz .xyzn .xyzrgb .pts .txt .csv``) -> float64 points,
and on request their colours.

``numpy.loadtxt`` (its C parser, no loop per row). A header line picks the x/y/z columns by name
(``x``, ``X``, ``"X"``, ``//X``, in any order); without one the first three columns are x, y, z.
Open3D skips unreadable lines silently and reads neither ``.txt`` nor ``.csv``.

Colours come only from columns whose meaning is known: a header naming one ``red``, ``green``
and ``blue`` column (or ``r``, ``g``, ``b``; any case, as LAS-to-text exports and CloudCompare
write them); without a header, columns 4-6 of ``.xyzrgb`` (Open3D's layout: x y z r g b, 0..1)
and columns 5-7 of a ``.pts`` of seven columns (Leica's: x y z intensity r g b, 0..255). Any
other file has no colour (None): a fourth to sixth number may as well be a normal or an
intensity.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError
from scan2terrain.readers._cloud_common import XYZ, loadtxt, rgb8

TEXT_SUFFIXES = (".xyz", ".xyzn", ".xyzrgb", ".pts", ".txt", ".csv")
#: Header names of the colour columns, either set.
RGB_NAMES = (("red", "green", "blue"), ("r", "g", "b"))

_HEADER_NAME = re.compile(r"^[\s\"'/#]*(.*?)[\s\"']*$")


def read_text(
    path: Path, suffix: str, *, colours: bool = False
) -> tuple[NDArray[np.float64], NDArray[np.uint8] | None, str]:
    """x, y, z of every row of a text point file (non-finite ones kept), their colours and its
    kind, the ``suffix`` without its dot; for
    :func:`~scan2terrain.readers.cloudfile.read_cloud`.

    Colours (uint8 (N, 3)) only when ``colours`` is asked for and the file has known colour
    columns (see the module's docstring), scaled by
    :func:`~scan2terrain.readers._cloud_common.rgb8`; None otherwise."""
    kind = suffix[1:]
    lines = _content_lines(path, 2)
    if not lines:
        raise InputError(path, "no points (only blank or comment lines)")
    (number, line), expected = lines[0], None
    rgb: list[int] = []  # the colour columns
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
        if kind == "xyzrgb" and len(tokens) >= 6:
            rgb = [3, 4, 5]
        elif kind == "pts" and len(tokens) == 7:
            rgb = [4, 5, 6]
    else:
        names = [_HEADER_NAME.sub(r"\1", t).lower() for t in tokens]
        if not all(names.count(a) == 1 for a in XYZ):
            raise InputError(
                path,
                f"line {number} ({line.strip()[:60]!r}) is neither numbers nor a header naming "
                "one x, one y and one z column",
            )
        cols, skip = [names.index(a) for a in XYZ], number
        known = next((c for c in RGB_NAMES if all(names.count(n) == 1 for n in c)), None)
        if known is not None:
            rgb = [names.index(n) for n in known]
    if not colours:
        rgb = []
    table = loadtxt(path, path, cols + rgb, delimiter=delimiter, skiprows=skip)
    if expected is not None and len(table) != expected:
        raise InputError(path, f"the .pts file says {expected} points, has {len(table)}")
    if not rgb:
        return table, None, kind
    colour = rgb8(table[:, 3:], fractions=kind == "xyzrgb")
    return np.ascontiguousarray(table[:, :3]), colour, kind


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
