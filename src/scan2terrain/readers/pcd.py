"""PCD files (``DATA ascii``, ``binary``, ``binary_compressed``) -> float64 points, and on request
the colours of an ``rgb`` or ``rgba`` field. Field names are PCL's lower-case ``x y z rgb``; a
field spelt in another case (``X Y Z``, as some writers do; CSV headers are read so too) is
taken where no lower-case one of that name exists (Open3D, for ``binary_compressed``, is given
the names in lower case).

The header is parsed and checked here and the data decoded with numpy (a structured dtype over
the bytes, ``numpy.loadtxt`` for ASCII), keeping float64 for double fields; Open3D decodes
``binary_compressed`` (LZF), once the header's sizes have been checked against the file.

Colour is PCL's packed convention: a 4-byte field ``rgb`` (``TYPE F``, a float32 whose bits are
the integer, or ``U``/``I``) or ``rgba`` holding ``0xAARRGGBB`` (little endian: bytes b, g, r,
a). In ``DATA ascii`` PCL writes an ``rgb`` float field as that integer (pcl/io/src/pcd_io.cpp,
``PCDWriter::writeASCII``: "Despite the float type, store the rgb field as uint32 because
several fully opaque color values are mapped to nan"), older writers as the float: a file
whose ``rgb`` values are all whole numbers 0..2^32-1 is read as integers, any other as float32
bits.
"""

from __future__ import annotations

import contextlib
import io
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError
from scan2terrain.readers._cloud_common import (
    XYZ,
    Decoded,
    attribute_name,
    attribute_names,
    decode_text,
    loadtxt,
    need_bytes,
    open3d_fields,
    open3d_points,
    stack,
)
from scan2terrain.readers._coordinates import check_coordinates, data_line

_PCD_TYPES = {
    ("F", 4): "f4",
    ("F", 8): "f8",
    ("I", 1): "i1",
    ("I", 2): "i2",
    ("I", 4): "i4",
    ("I", 8): "i8",
    ("U", 1): "u1",
    ("U", 2): "u2",
    ("U", 4): "u4",
    ("U", 8): "u8",
}
_PCD_KEYS = ("VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT")
#: Fields holding PCL's packed colour, the first present is read.
RGB_FIELDS = ("rgb", "rgba")


# PLR0915: the header's fields checked in the format's order.
def read_pcd(path: Path, *, colours: bool = False, attributes: bool = False) -> Decoded:  # noqa: PLR0915
    """x, y, z of every point of a PCD file (non-finite ones kept), their colours and what was
    read (``"pcd binary"``); for :func:`~scan2terrain.readers.cloudfile.read_cloud`.

    Colours (uint8 (N, 3) RGB) only when ``colours`` is asked for and the file has an ``rgb`` or
    ``rgba`` field (see the module's docstring); None otherwise. An ``rgb`` field that is not
    one 4-byte value per point is refused (InputError) when colours are asked for.

    With ``attributes``, every other field of COUNT 1 as its TYPE and SIZE say (``F 4`` float32,
    ``U 2`` uint16, ...), named by :func:`~._cloud_common.attribute_name`; a packed colour as
    ``red``, ``green``, ``blue`` (uint8; ``rgba`` also ``alpha``).
    """
    raw = path.read_bytes()
    head, start = _pcd_header(path, raw)
    names = head["FIELDS"]
    sizes, types = head.get("SIZE", []), head.get("TYPE", [])
    counts = head.get("COUNT", ["1"] * len(names))
    if not (len(names) == len(sizes) == len(types) == len(counts)):
        raise InputError(path, "PCD header: FIELDS, SIZE, TYPE and COUNT differ in length")
    width, height = _pcd_int(path, head, "WIDTH"), _pcd_int(path, head, "HEIGHT")
    n = _pcd_int(path, head, "POINTS") if "POINTS" in head else width * height
    if n != width * height:
        raise InputError(path, f"PCD header: POINTS {n} is not WIDTH x HEIGHT {width}x{height}")
    # Two fields of one name (PCL names its padding fields "_", any number of them) would make
    # the x, y or z read an accident of which one is taken.
    twice = next((n for i, n in enumerate(names) if n != "_" and n in names[:i]), None)
    if twice is not None:
        raise InputError(path, f"PCD header: field {twice!r} appears twice in FIELDS")
    where = {a: _field(path, names, a) for a in (*XYZ, *RGB_FIELDS)}
    missing = [a for a in XYZ if where[a] is None]
    if missing:
        raise InputError(path, f"PCD has no field {', '.join(missing)} (FIELDS {' '.join(names)})")
    try:
        size_l, count_l = [int(s) for s in sizes], [int(c) for c in counts]
    except ValueError:
        raise InputError(path, "PCD header: SIZE and COUNT must be integers") from None
    if min(size_l, default=1) < 1 or min(count_l, default=0) < 0:
        raise InputError(path, "PCD header: SIZE must be positive and COUNT not negative")
    offsets = np.concatenate([[0], np.cumsum(np.multiply(size_l, count_l))]).tolist()
    columns = np.concatenate([[0], np.cumsum(count_l)]).tolist()
    step = int(offsets[-1])
    fields: list[str] = []
    formats: list[str] = []
    at: list[int] = []
    cols: list[int] = []

    def add(name: str, code: str, i: int) -> None:
        fields.append(name)
        formats.append("<" + code)
        at.append(int(offsets[i]))
        cols.append(int(columns[i]))

    for axis in XYZ:
        i = where[axis]
        assert i is not None  # checked above
        code = _PCD_TYPES.get((types[i].upper(), size_l[i]))
        if code is None or count_l[i] != 1:
            raise InputError(
                path,
                f"PCD field {axis}: unsupported TYPE {types[i]} SIZE {sizes[i]} COUNT {counts[i]}",
            )
        add(axis, code, i)
    rgb = next((f for f in RGB_FIELDS if where[f] is not None), None)
    i_rgb = where[rgb] if rgb is not None else None
    if i_rgb is not None and (
        size_l[i_rgb] != 4 or count_l[i_rgb] != 1 or types[i_rgb].upper() not in ("F", "U", "I")
    ):
        if colours:
            raise InputError(
                path,
                f"PCD field {rgb}: TYPE {types[i_rgb]} SIZE {sizes[i_rgb]} COUNT "
                f"{counts[i_rgb]} is not PCL's packed colour (one 4-byte value)",
            )
        rgb = i_rgb = None  # an attribute like any other
    if rgb is not None and i_rgb is not None and (colours or attributes):
        add(rgb, "u4", i_rgb)  # the float's bits, for TYPE F
    else:
        rgb = None
    unread: list[str] = []
    extra: dict[str, str] = {}  # attribute name -> its field in ``fields``
    before = 0  # of them before the colour field
    if attributes:
        taken = {where[a] for a in XYZ} | {i_rgb}
        others = [i for i, name in enumerate(names) if name != "_" and i not in taken]
        for i, name in zip(others, attribute_names([names[i] for i in others]), strict=True):
            code = _PCD_TYPES.get((types[i].upper(), size_l[i]))
            if name is None or count_l[i] != 1 or code is None:
                why = f"COUNT {counts[i]}" if count_l[i] != 1 else f"TYPE {types[i]} {sizes[i]}"
                unread.append(f"{names[i]} ({'twice' if name is None else why})")
                continue
            extra[name] = f"_{len(fields)}"
            add(extra[name], code, i)
            before += i_rgb is not None and i < i_rgb
    kind = head["DATA"][0].lower() if head["DATA"] else ""
    fmt = f"pcd {kind}"
    if kind == "ascii":
        text = decode_text(path, raw[start:])
        table = loadtxt(path, io.StringIO(text), cols, delimiter=None, skiprows=0)
        if len(table) != n:
            cut = "truncated: " if len(table) < n else ""
            raise InputError(path, f"{cut}PCD header says {n} points, the data has {len(table)}")
        first = raw[:start].count(b"\n") + 1  # the data's first line

        def line(row: int) -> str:
            return f"line {data_line(io.StringIO(text), 0, row, first)}"

        check_coordinates(path, table[:, :3], line)
        packed = None if rgb is None else _ascii_packed(table[:, 3])
        values = {}
        with np.errstate(invalid="ignore", over="ignore"):
            for name, key in extra.items():
                k = fields.index(key)
                values[name] = table[:, k].astype(formats[k][1:])
        return _decoded(table[:, :3], packed, rgb, fmt, colours, values, unread, before)
    if kind == "binary":
        need_bytes(path, len(raw), start + n * step, f"{n} points of {step} bytes")
        dtype = np.dtype({"names": fields, "formats": formats, "offsets": at, "itemsize": step})
        rec = np.frombuffer(raw, dtype=dtype, count=n, offset=start)
        points = stack(rec)
        check_coordinates(path, points, _point)
        packed = None if rgb is None else rec[rgb]
        values = {k: rec[f].astype(rec[f].dtype.newbyteorder("=")) for k, f in extra.items()}
        return _decoded(points, packed, rgb, fmt, colours, values, unread, before)
    if kind == "binary_compressed":
        need_bytes(path, len(raw), start + 8, "the compressed block's sizes")
        packed_size, unpacked = (
            int(v) for v in np.frombuffer(raw, dtype="<u4", count=2, offset=start)
        )
        if unpacked != n * step:
            raise InputError(
                path,
                f"PCD compressed block unpacks to {unpacked} bytes, {n} points need {n * step}",
            )
        need_bytes(
            path, len(raw), start + 8 + packed_size, f"a compressed block of {packed_size} bytes"
        )
        used = {a: where[a] for a in (*XYZ, rgb) if a is not None}
        with _lower_case_fields(path, raw, start, names, used) as source:
            try:
                if attributes:
                    found = _open3d_decoded(path, source, n, colours, names, extra, unread, before)
                    check_coordinates(path, found.points, _point)
                    return found
                pts, got = open3d_points(source, n, colours=colours and rgb is not None)
            except InputError as exc:
                raise InputError(path, exc.problem) from exc
        check_coordinates(path, pts, _point)
        colour = None  # Open3D unpacks the field into bytes / 255
        if got is not None:
            colour = np.clip(np.rint(got), 0, 255).astype(np.uint8)
        return Decoded(pts, colour, fmt)
    raise InputError(path, f"PCD header: unknown DATA {' '.join(head['DATA'])!r}")


def _point(row: int) -> str:
    return f"point {row}"


def _decoded(
    points: NDArray[np.float64],
    packed: NDArray[Any] | None,
    rgb: str | None,
    fmt: str,
    colours: bool,
    values: dict[str, NDArray[Any]],
    unread: list[str],
    before: int,
) -> Decoded:
    """A :class:`Decoded` of the points, the packed colour (the colours, and with the other
    attributes as ``red``, ``green``, ``blue``, and ``alpha`` of an ``rgba``, after the first
    ``before`` of ``values``: in the file's order)."""
    attributes: dict[str, NDArray[Any]] = {}
    colour = None
    if packed is not None:
        colour = unpack_rgb(packed)
        for channel, name in enumerate(("red", "green", "blue")):
            attributes[name] = np.ascontiguousarray(colour[:, channel])
        if rgb == "rgba":
            attributes["alpha"] = (np.asarray(packed, dtype=np.uint32) >> 24).astype(np.uint8)
    return Decoded(
        np.ascontiguousarray(points), colour if colours else None, fmt,
        _in_order(values, attributes, before), None, tuple(unread),
    )  # fmt: skip


def _in_order(
    values: dict[str, NDArray[Any]], colour: dict[str, NDArray[Any]], before: int
) -> dict[str, NDArray[Any]]:
    """The attributes in the file's order: the first ``before`` values, the colour, the rest."""
    items = list(values.items())
    merged = dict(items[:before])
    merged.update(colour)
    for name, v in items[before:]:
        merged.setdefault(name, v)
    return merged


def _open3d_decoded(
    path: Path,
    source: Path,
    n: int,
    colours: bool,
    names: list[str],
    extra: dict[str, str],
    unread: list[str],
    before: int,
) -> Decoded:
    """A ``binary_compressed`` PCD's points and fields, decoded by Open3D's tensor reader (it
    keeps every field and its type; its colours are the packed ones, unpacked)."""
    found = open3d_fields(source, n)
    points = np.asarray(found.pop("positions"), dtype=np.float64)
    rgb = found.pop("colors", None)
    channels: dict[str, NDArray[Any]] = {}
    colour = None
    if rgb is not None:
        colour = np.asarray(rgb).astype(np.uint8) if rgb.dtype == np.uint8 else None
        if colour is not None:
            for channel, name in enumerate(("red", "green", "blue")):
                channels[name] = np.ascontiguousarray(colour[:, channel])
    attributes: dict[str, NDArray[Any]] = {}
    normals = found.pop("normals", None)
    lowered = {attribute_name(k): v for k, v in found.items()}
    if normals is not None:
        for axis, name in enumerate(("normal_x", "normal_y", "normal_z")):
            lowered[name] = np.ascontiguousarray(normals[:, axis])
    for name in extra:
        field_name = next((f for f in names if attribute_name(f) == name), name)
        value = lowered.get(name, found.get(field_name))
        if value is None or value.ndim != 1:
            unread.append(f"{field_name} (not decoded by Open3D)")
            continue
        attributes[name] = value
    return Decoded(points, colour if colours else None, "pcd binary_compressed",
                   _in_order(attributes, channels, before), None, tuple(unread))  # fmt: skip


@contextlib.contextmanager
def _lower_case_fields(
    path: Path, raw: bytes, start: int, names: list[str], used: dict[str, int | None]
) -> Iterator[Path]:
    """``path``, or where the fields used are spelt in another case (``X``, which Open3D does
    not know), a temporary copy whose FIELDS line spells them in lower case."""
    renamed = list(names)
    for name, i in used.items():
        if i is not None:
            renamed[i] = name
    if renamed == names:
        yield path
        return
    lines = raw[:start].split(b"\n")
    at = max(k for k, ln in enumerate(lines) if ln.strip().upper().startswith(b"FIELDS"))
    lines[at] = ("FIELDS " + " ".join(renamed)).encode("ascii")
    with tempfile.TemporaryDirectory(prefix="scan2terrain-pcd-") as folder:
        copy = Path(folder) / "fields.pcd"
        with copy.open("wb") as out:
            out.write(b"\n".join(lines))
            out.write(memoryview(raw)[start:])
        yield copy


def _field(path: Path, names: list[str], name: str) -> int | None:
    """The index of field ``name`` in FIELDS: the exact (lower-case) name, else the one field
    spelt so in another case (``X``, ``RGB``); None if there is none."""
    if name in names:
        return names.index(name)
    found = [i for i, n in enumerate(names) if n.lower() == name]
    if len(found) > 1:
        spelt = " and ".join(names[i] for i in found)
        raise InputError(path, f"PCD header: fields {spelt} are both {name!r}")
    return found[0] if found else None


def unpack_rgb(packed: NDArray[np.uint32]) -> NDArray[np.uint8]:
    """PCL's packed colours ``0x(AA)RRGGBB`` (N,) -> RGB uint8 (N, 3)."""
    packed = np.asarray(packed, dtype=np.uint32)
    out = np.empty((len(packed), 3), dtype=np.uint8)
    for channel, shift in enumerate((16, 8, 0)):  # three column copies
        out[:, channel] = (packed >> shift) & 0xFF
    return out


def _ascii_packed(values: NDArray[np.float64]) -> NDArray[np.uint32]:
    """Packed colours written as text: integers (PCL) or floats whose bits they are (older
    writers); see the module's docstring."""
    whole = np.isfinite(values) & (values == np.floor(values))
    if whole.all() and (values >= 0).all() and (values < 2.0**32).all():
        return values.astype(np.uint32)
    with np.errstate(invalid="ignore", over="ignore"):  # NaN/inf/huge: their float32 bits
        bits: NDArray[np.uint32] = values.astype(np.float32).view(np.uint32)
    return bits


def _pcd_header(path: Path, raw: bytes) -> tuple[dict[str, list[str]], int]:
    """Header keys -> values, and the byte offset where the data starts (after the DATA line)."""
    head: dict[str, list[str]] = {}
    pos = 0
    while pos < len(raw):
        end = raw.find(b"\n", pos)
        end = len(raw) if end < 0 else end
        try:
            line = raw[pos:end].decode("ascii").strip()
        except UnicodeDecodeError:
            line = "\ufffd"
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        key, *values = line.split()
        key = key.upper()
        if not head and key not in _PCD_KEYS:
            raise InputError(path, f"not a PCD file (it starts with {line[:40]!r})")
        head[key] = values
        if key == "DATA":
            if "FIELDS" not in head:
                raise InputError(path, "PCD header has no FIELDS line")
            return head, min(pos, len(raw))
    raise InputError(path, "not a PCD file (no DATA line in its header)")


def _pcd_int(path: Path, head: dict[str, list[str]], key: str) -> int:
    try:
        value = int(head[key][0])
    except (KeyError, IndexError, ValueError):
        raise InputError(path, f"PCD header: {key} is missing or not an integer") from None
    if value < 0:
        raise InputError(path, f"PCD header: {key} {value} is negative")
    return value
