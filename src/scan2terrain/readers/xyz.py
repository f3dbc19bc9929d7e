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
from typing import Any

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError
from scan2terrain.readers._cloud_common import (
    XYZ,
    Decoded,
    attribute_names,
    colour_values,
    loadtxt,
    narrowed,
    rgb8,
)
from scan2terrain.readers._coordinates import check_coordinates, data_line

TEXT_SUFFIXES = (".xyz", ".xyzn", ".xyzrgb", ".pts", ".txt", ".csv")
#: Header names of the colour columns, either set.
RGB_NAMES = (("red", "green", "blue"), ("r", "g", "b"))

_HEADER_NAME = re.compile(r"^[\s\"'/#]*(.*?)[\s\"']*$")


def read_text(
    path: Path, suffix: str, *, colours: bool = False, attributes: bool = False
) -> Decoded:
    """x, y, z of every row of a text point file (non-finite ones kept), their colours and its
    kind, the ``suffix`` without its dot; for
    :func:`~scan2terrain.readers.cloudfile.read_cloud`.

    Colours (uint8 (N, 3)) only when ``colours`` is asked for and the file has known colour
    columns (see the module's docstring), scaled by
    :func:`~scan2terrain.readers._cloud_common.rgb8`; None otherwise.

    With ``attributes``, the colour columns by :func:`~._cloud_common.colour_values` and every
    other column a header names whose first row is a number, by
    :func:`~._cloud_common.attribute_name`, float64 or (a known name whose values all fit) its
    integer type (:func:`~._cloud_common.narrowed`); columns without a name are not read."""
    kind = suffix[1:]
    lines = _content_lines(path, 3)
    if not lines:
        raise InputError(path, "no points (only blank or comment lines)")
    (number, line), expected = lines[0], None
    rgb: list[int] = []  # the colour columns
    others: list[int] = []  # other named columns
    names: list[str] = []
    unread: list[str] = []
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
        if attributes:
            first = _split(lines[1][1], delimiter) if len(lines) > 1 else []
            for k in range(len(names)):
                if k in cols or k in rgb:
                    continue
                if k < len(first) and _is_number(first[k]):
                    others.append(k)
                else:
                    unread.append(f"{tokens[k].strip(chr(34) + chr(39))} (not numbers)")
    if not (colours or attributes):
        rgb = []
    try:
        table = loadtxt(path, path, cols + rgb + others, delimiter=delimiter, skiprows=skip)
    except InputError:
        if not others:
            raise
        unread += [f"{names[k]} (not numbers in every row)" for k in others]
        others = []
        table = loadtxt(path, path, cols + rgb, delimiter=delimiter, skiprows=skip)
    if expected is not None and len(table) != expected:
        raise InputError(path, f"the .pts file says {expected} points, has {len(table)}")
    points = np.ascontiguousarray(table[:, :3])
    check_coordinates(path, points, lambda row: f"line {data_line(path, skip, row)}")
    colour = None
    attrs: dict[str, NDArray[Any]] = {}
    if rgb:
        values = table[:, 3:6]
        colour = rgb8(values, fractions=kind == "xyzrgb") if colours else None
        depth = colour_values(values, fractions=kind == "xyzrgb") if attributes else None
        if depth is not None:
            attrs = {c: np.ascontiguousarray(depth[:, i]) for i, c in enumerate(RGB_NAMES[0])}
        elif attributes:
            unread.append("colour (not colours of 8 or 16 bits)")
    found = attribute_names([names[k] for k in others])
    for j, (k, name) in enumerate(zip(others, found, strict=True)):
        if name is None or name in attrs:
            unread.append(f"{names[k]} (twice)")
        else:
            attrs[name] = narrowed(name, np.ascontiguousarray(table[:, 3 + len(rgb) + j]))
    if rgb and len(attrs) > 3:  # in the file's order: the colour where its red is
        before = sum(k < rgb[0] for k, n in zip(others, found, strict=True) if n in attrs)
        items = list(attrs.items())
        attrs = dict(items[3 : 3 + before] + items[:3] + items[3 + before :])
    return Decoded(points, colour, kind, attrs, None, tuple(unread))


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
