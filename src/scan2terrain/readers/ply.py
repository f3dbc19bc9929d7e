"""PLY files (ascii, binary of either byte order) -> float64 points, and on request the vertex
colours (``red``, ``green``, ``blue`` properties).

The header is parsed and checked here and the vertex data decoded with numpy (a structured
dtype over the bytes, ``numpy.loadtxt`` for ASCII), keeping float64 for double properties.
Open3D (RPly) reads files with list properties before or inside the vertex element (rows of
varying length), once the data has been checked to be long enough for the header's counts.
"""

from __future__ import annotations

import io
from dataclasses import dataclass, field
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
    decode_text,
    loadtxt,
    need_bytes,
    open3d_points,
    rgb8,
    stack,
)
from scan2terrain.types import COLOUR_ATTRIBUTES

_PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
#: The vertex properties that hold a colour (the names Open3D, CloudCompare, PCL and MeshLab
#: write, and a cloud's colour attributes).
RGB = COLOUR_ATTRIBUTES


@dataclass(frozen=True)
class _Element:
    name: str
    count: int
    props: list[tuple[str, str | None]]  # (name, numpy code), None for a list property
    lists: list[str] = field(default_factory=list)  # numpy code of each list's length

    @property
    def fixed(self) -> bool:
        return all(code is not None for _, code in self.props)

    @property
    def min_row(self) -> int:
        """Bytes of a binary row whose lists are all empty."""
        return _row_size(self) + sum(np.dtype(code).itemsize for code in self.lists)


def read_ply(path: Path, *, colours: bool = False, attributes: bool = False) -> Decoded:
    """x, y, z of every vertex of a PLY file (non-finite ones kept), their colours and what was
    read (``"ply ascii"``); for :func:`~scan2terrain.readers.cloudfile.read_cloud`.

    Colours (uint8 (N, 3), only when ``colours`` is asked for and the vertices have numeric
    ``red``, ``green`` and ``blue`` properties; None otherwise) are scaled by
    :func:`~scan2terrain.readers._cloud_common.rgb8`: ``uchar`` as stored, ``ushort`` too if
    every value is <= 255 and else their high byte, ``float``/``double`` 0..1 times 255.

    With ``attributes``, every other numeric vertex property in its own type, named by
    :func:`~._cloud_common.attribute_name` (CloudCompare's ``scalar_intensity`` is
    ``intensity``); colour by :func:`~._cloud_common.colour_values`.
    """
    raw = path.read_bytes()
    fmt, elements, start = _ply_header(path, raw)
    index = [e.name for e in elements].index("vertex")
    vertex, before = elements[index], elements[:index]
    names = [p for p, _ in vertex.props]
    codes = dict(vertex.props)
    has_rgb = all(codes.get(c) is not None for c in RGB)
    rgb = RGB if (colours or attributes) and has_rgb else ()
    floats = any(np.dtype(str(codes[c])).kind == "f" for c in rgb)
    others = [n for n in names if n not in (*XYZ, *rgb)] if attributes else []
    unread = [f"{n} (a list)" for n in others if codes[n] is None]
    others = [n for n in others if codes[n] is not None]
    if not vertex.fixed or not all(e.fixed for e in before):
        # Rows of varying length: Open3D (RPly) walks them.
        _check_ply_rows(path, fmt, raw, start, [*before, vertex])
        pts, values = open3d_points(path, vertex.count, colours=bool(rgb))
        rgb_o3d = None
        if values is not None:  # Open3D's value / 255 * 255: integers only to a rounding
            rgb_o3d = rgb8(values if floats else np.rint(values), fractions=floats)
        unread += [f"{n} (not decoded by Open3D)" for n in others]
        kept = {}
        if rgb_o3d is not None and attributes:
            kept = {c: np.ascontiguousarray(rgb_o3d[:, i]) for i, c in enumerate(RGB)}
        return Decoded(pts, rgb_o3d if colours else None, f"ply {fmt}", kept, None, tuple(unread))
    wanted = [*XYZ, *rgb, *others]
    if fmt == "ascii":
        cols = [names.index(a) for a in wanted]
        skip = sum(e.count for e in before)  # one line per item of each earlier element
        lines = raw.count(b"\n", start) + (not raw.endswith(b"\n"))
        if lines < skip + vertex.count:  # before numpy sizes its table by the header's count
            after = f" after {skip} rows of earlier elements" if skip else ""
            raise InputError(
                path,
                f"truncated: PLY header says {vertex.count} vertices, the data has "
                f"{max(lines - skip, 0)} lines{after}",
            )
        text = decode_text(path, raw[start:])
        table = loadtxt(
            path,
            io.StringIO(text),
            cols,
            delimiter=None,
            skiprows=skip,
            max_rows=vertex.count,
            comments=None,
        )
        if len(table) != vertex.count:
            raise InputError(
                path,
                f"truncated: PLY header says {vertex.count} vertices, the data has {len(table)}",
            )
        with np.errstate(invalid="ignore", over="ignore"):
            columns = {  # colours as parsed (float64), for rgb8 as before
                a: table[:, k] if a in rgb else table[:, k].astype(str(codes[a]))
                for k, a in enumerate(wanted)
                if k >= 3
            }
    else:
        order = "<" if fmt == "binary_little_endian" else ">"
        offset = start + sum(e.count * _row_size(e) for e in before)
        step = _row_size(vertex)
        sizes = np.cumsum([0] + [np.dtype(code).itemsize for _, code in vertex.props]).tolist()
        dtype = np.dtype(
            {
                "names": wanted,
                "formats": [order + str(codes[a]) for a in wanted],
                "offsets": [int(sizes[names.index(a)]) for a in wanted],
                "itemsize": step,
            }
        )
        need_bytes(
            path, len(raw), offset + vertex.count * step, f"{vertex.count} vertices of {step} bytes"
        )
        records = np.frombuffer(raw, dtype=dtype, count=vertex.count, offset=offset)
        table = stack(records)
        columns = {a: records[a].astype(records[a].dtype.newbyteorder("=")) for a in wanted[3:]}
    colour: NDArray[np.uint8] | None = None
    attrs: dict[str, NDArray[Any]] = {}
    if rgb:
        stacked = np.stack([columns.pop(c) for c in rgb], axis=1)
        colour = rgb8(stacked, fractions=floats)
        depth = colour_values(stacked, fractions=floats) if attributes else None
        if depth is not None:
            attrs = {c: np.ascontiguousarray(depth[:, i]) for i, c in enumerate(RGB)}
        elif attributes:
            unread.append("red, green, blue (not colours of 8 or 16 bits)")
    for name, key in zip(attribute_names(others), others, strict=True):
        if name is None or name in attrs:
            unread.append(f"{key} (twice)")
        else:
            attrs[name] = columns[key]
    if rgb:  # in the file's order: the colour where its red is
        at = sum(names.index(k) < names.index("red") for k in others)
        items = list(attrs.items())
        attrs = dict(items[3 : 3 + at] + items[:3] + items[3 + at :])
    return Decoded(
        np.ascontiguousarray(table[:, :3]), colour if colours else None, f"ply {fmt}", attrs,
        None, tuple(unread),
    )  # fmt: skip


def _ply_header(path: Path, raw: bytes) -> tuple[str, list[_Element], int]:
    if not raw.startswith((b"ply\n", b"ply\r\n")):
        raise InputError(path, "not a PLY file (it does not start with 'ply')")
    end = raw.find(b"end_header")
    if end < 0:
        raise InputError(path, "PLY header has no end_header line")
    newline = raw.find(b"\n", end)
    start = len(raw) if newline < 0 else newline + 1
    fmt = ""
    elements: list[_Element] = []
    for line in decode_text(path, raw[:end]).splitlines()[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        try:
            if words[0] == "format":
                fmt = words[1]
            elif words[0] == "element":
                elements.append(_Element(words[1], int(words[2]), []))
            elif words[0] == "property" and words[1] == "list":
                length, _ = _PLY_TYPES[words[2]], _PLY_TYPES[words[3]]
                if np.dtype(length).kind not in "iu":
                    raise ValueError
                elements[-1].props.append((words[4], None))
                elements[-1].lists.append(length)
            elif words[0] == "property":
                elements[-1].props.append((words[2], _PLY_TYPES[words[1]]))
            else:
                raise ValueError
        except (IndexError, ValueError, KeyError):
            raise InputError(path, f"PLY header: cannot read the line {line[:60]!r}") from None
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise InputError(path, f"PLY header: unknown format {fmt!r}")
    vertices = [e for e in elements if e.name == "vertex"]
    if not vertices:
        raise InputError(path, "PLY has no vertex element")
    props = dict(vertices[0].props)
    missing = [a for a in XYZ if a not in props]
    if missing:
        raise InputError(path, f"PLY vertex element has no property {', '.join(missing)}")
    if any(props[a] is None for a in XYZ):
        raise InputError(path, "PLY vertex x/y/z must be numbers, not lists")
    if any(e.count < 0 for e in elements):
        raise InputError(path, "PLY header: negative element count")
    return fmt, elements, start


def _row_size(element: _Element) -> int:
    return sum(np.dtype(code).itemsize for _, code in element.props if code is not None)


def _check_ply_rows(path: Path, fmt: str, raw: bytes, start: int, elements: list[_Element]) -> None:
    """Refuse PLY data too short for its elements' counts even with every list empty, before
    Open3D (RPly) reads it: it keeps the rows it could not read as uninitialised points."""
    if fmt == "ascii":  # one number per property, at least (a list's length)
        need = sum(e.count * len(e.props) for e in elements)
        have, unit = _count_words(raw, start), "numbers"
    else:
        need = sum(e.count * e.min_row for e in elements)
        have, unit = len(raw) - start, "bytes"
    if have < need:
        raise InputError(
            path,
            f"truncated: the PLY header's {elements[-1].count} vertices need at least {need} "
            f"{unit} of data, the file has {have}",
        )


def _count_words(data: bytes, start: int) -> int:
    """Whitespace-separated words in ``data[start:]`` (numpy over the bytes, no Python loop)."""
    view = np.frombuffer(data, dtype=np.uint8, offset=start)
    space = np.isin(view, np.frombuffer(b" \t\n\r\v\f", dtype=np.uint8))
    starts = np.count_nonzero(space[:-1] & ~space[1:])
    return int(starts) + int(view.size > 0 and not space[0])
