"""PLY files (ascii, binary of either byte order) -> float64 points, and on request the vertex
colours (``red``, ``green``, ``blue`` properties).

The header is parsed and checked here and the vertex data decoded with numpy (a structured
dtype over the bytes, ``numpy.loadtxt`` for ASCII), keeping float64 for double properties.
Open3D (RPly) reads files with list properties before or inside the vertex element (rows of
varying length), once every row of every element has been walked here (compiled,
:mod:`._ply_kernels`): each list count of its type and not negative, each list inside the data,
the rows ending where the data does; RPly's own complaints (two lines, or rows misread from a
wrong count) then concern only words that are not numbers. A header may not declare an element,
or a property of one element, twice (``x`` twice ran for minutes), nor hold control characters.
Coordinates must lie within :data:`~._limits.MAX_COORDINATE_M` of the origin. Every refusal is
one :class:`~scan2terrain.errors.InputError` naming the file, the row and the field.
"""

from __future__ import annotations

import io
import re
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
from scan2terrain.readers._limits import MAX_COORDINATE_M, within
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
    #: per property: (numpy code of a value, of a list's count or "", the count's PLY type)
    layout: list[tuple[str, str, str]] = field(default_factory=list)

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
        # Rows of varying length: walked here, then read by Open3D (RPly).
        _check_ply_rows(path, fmt, raw, start, [*before, vertex])
        _walk_rows(path, fmt, raw, start, elements)
        pts, values = open3d_points(path, vertex.count, colours=bool(rgb))
        _check_coordinates(path, pts)
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
    _check_coordinates(path, table)
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
    head = raw[:end]
    control = np.flatnonzero(np.isin(np.frombuffer(head, np.uint8), _CONTROL))
    if control.size:  # RPly and Python split words and lines differently at these
        at = int(control[0])
        raise InputError(path, f"PLY header: a control character 0x{head[at]:02x} at byte {at}")
    fmt = ""
    elements: list[_Element] = []
    for line in decode_text(path, head).split("\n")[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        try:
            if words[0] == "format":
                fmt = words[1]
            elif words[0] == "element":
                if any(e.name == words[1] for e in elements):
                    raise InputError(path, f"PLY header declares element {words[1]!r} twice")
                elements.append(_Element(words[1], int(words[2]), []))
            elif words[0] == "property":
                element = elements[-1]
                name = words[4] if words[1] == "list" else words[2]
                if any(p == name for p, _ in element.props):
                    raise InputError(
                        path,
                        f"PLY header: element {element.name} declares property {name!r} twice",
                    )
                if words[1] == "list":
                    length, value = _PLY_TYPES[words[2]], _PLY_TYPES[words[3]]
                    if np.dtype(length).kind not in "iu":
                        raise ValueError
                    element.props.append((name, None))
                    element.lists.append(length)
                    element.layout.append((value, length, words[2]))
                else:
                    element.props.append((name, _PLY_TYPES[words[1]]))
                    element.layout.append((_PLY_TYPES[words[1]], "", ""))
            else:
                raise ValueError
        except InputError:
            raise
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


#: Bytes a PLY header may not hold: control characters but tab, line feed and carriage return.
_CONTROL = np.array([b for b in range(32) if b not in b"\t\n\r"] + [127], dtype=np.uint8)


def _check_ply_rows(path: Path, fmt: str, raw: bytes, start: int, elements: list[_Element]) -> None:
    """Refuse PLY data too short for its elements' counts even with every list empty, before
    a row is walked."""
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


def _walk_rows(path: Path, fmt: str, raw: bytes, start: int, elements: list[_Element]) -> None:
    """Every row of every element inside the data, each list count of its type and >= 0, and
    the rows ending where the data does (but for white space), before RPly reads them: it reads
    rows past a wrong count as other rows, or keeps those it could not read uninitialised."""
    from scan2terrain.readers import _ply_kernels

    data = np.frombuffer(raw, np.uint8)
    pos = start
    for element in elements:
        codes = [np.dtype(value) for value, _, _ in element.layout]
        sizes = np.array([c.itemsize for c in codes], np.int64)
        count_sizes = np.array([np.dtype(c).itemsize if c else 0 for _, c, _ in element.layout],
                               np.int64)  # fmt: skip
        signed = np.array(
            [bool(c) and np.dtype(c).kind == "i" for _, c, _ in element.layout], dtype=bool
        )
        if fmt == "ascii":
            stop = _ply_kernels.walk_ascii(data, pos, element.count, count_sizes, signed)
        else:
            big = fmt == "binary_big_endian"
            stop = _ply_kernels.walk_binary(
                data, pos, element.count, sizes, count_sizes, signed, big
            )
        status, row, prop, end, count = (int(v) for v in stop)
        if status != _ply_kernels.FITS:
            raise InputError(path, _stop(element, raw, (status, row, prop, end, count)))
        pos = end
    rest = int(_ply_kernels.skip_space(data, pos))
    if rest < len(raw):
        raise InputError(
            path,
            f"the rows of its elements end at byte {pos}, {len(raw) - pos:,} bytes before the "
            "file does: a list or element count is wrong",
        )


def _stop(element: _Element, raw: bytes, stop: tuple[int, int, int, int, int]) -> str:
    """Why the walk of ``element`` over ``raw`` stopped (a walk's ``(status, row, prop, pos,
    count)``), in words."""
    from scan2terrain.readers import _ply_kernels

    status, row, prop, pos, count = stop
    name = element.props[prop][0]
    where = f"row {row} of element {element.name}"
    if status == _ply_kernels.TRUNCATED:
        return f"truncated: the data ends in {where}, at its property {name!r} (byte {pos})"
    if status == _ply_kernels.NEGATIVE:
        return f"{where}: its list {name!r} has a count of {count} (at byte {pos})"
    if status == _ply_kernels.PAST_END:
        return (
            f"{where}: its list {name!r} holds {count:,} values, past the end of the data "
            "(a wrong count, or a truncated file)"
        )
    kind = element.layout[prop][2]
    if status == _ply_kernels.OUT_OF_RANGE:
        return f"{where}: its list {name!r} count {count} is beyond its type {kind}"
    word = re.split(rb"[ \t\n\r]", raw[pos : pos + 20])[0].decode("utf-8", "replace")
    return f"{where}: its list {name!r} count {word!r} is not an integer"


def _check_coordinates(path: Path, points: NDArray[Any]) -> None:
    """Every finite coordinate within :data:`~._limits.MAX_COORDINATE_M` of the origin
    (non-finite ones are dropped later, with a note)."""
    with np.errstate(invalid="ignore"):
        far = np.abs(points[:, :3]) > MAX_COORDINATE_M
    if far.any():
        row, axis = np.unravel_index(int(np.argmax(far)), far.shape)
        value = float(points[row, axis])
        within(path, f"vertex {row}: {XYZ[axis]}", value, lo=0.0, hi=MAX_COORDINATE_M, unit="m")
