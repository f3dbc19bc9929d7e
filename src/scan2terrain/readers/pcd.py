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

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError
from scan2terrain.readers._cloud_common import (
    XYZ,
    decode_text,
    loadtxt,
    need_bytes,
    open3d_points,
    stack,
)

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


def read_pcd(
    path: Path, *, colours: bool = False
) -> tuple[NDArray[np.float64], NDArray[np.uint8] | None, str]:
    """x, y, z of every point of a PCD file (non-finite ones kept), their colours and what was
    read (``"pcd binary"``); for :func:`~scan2terrain.readers.cloudfile.read_cloud`.

    Colours (uint8 (N, 3) RGB) only when ``colours`` is asked for and the file has an ``rgb`` or
    ``rgba`` field (see the module's docstring); None otherwise. An ``rgb`` field that is not
    one 4-byte value per point is refused (InputError) when colours are asked for.
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
    formats, at, cols = [], [], []
    for axis in XYZ:
        i = where[axis]
        assert i is not None  # checked above
        code = _PCD_TYPES.get((types[i].upper(), size_l[i]))
        if code is None or count_l[i] != 1:
            raise InputError(
                path,
                f"PCD field {axis}: unsupported TYPE {types[i]} SIZE {sizes[i]} COUNT {counts[i]}",
            )
        formats.append("<" + code)
        at.append(int(offsets[i]))
        cols.append(int(columns[i]))
    rgb = next((f for f in RGB_FIELDS if where[f] is not None), None) if colours else None
    if rgb is not None:
        i = where[rgb]
        assert i is not None
        if size_l[i] != 4 or count_l[i] != 1 or types[i].upper() not in ("F", "U", "I"):
            raise InputError(
                path,
                f"PCD field {rgb}: TYPE {types[i]} SIZE {sizes[i]} COUNT {counts[i]} is not "
                "PCL's packed colour (one 4-byte value)",
            )
        at.append(int(offsets[i]))
        cols.append(int(columns[i]))
        formats.append("<u4")  # the float's bits, for TYPE F
    fields = [*XYZ, rgb] if rgb is not None else list(XYZ)
    kind = head["DATA"][0].lower() if head["DATA"] else ""
    if kind == "ascii":
        text = decode_text(path, raw[start:])
        table = loadtxt(path, io.StringIO(text), cols, delimiter=None, skiprows=0)
        if len(table) != n:
            cut = "truncated: " if len(table) < n else ""
            raise InputError(path, f"{cut}PCD header says {n} points, the data has {len(table)}")
        if rgb is None:
            return table, None, "pcd ascii"
        return np.ascontiguousarray(table[:, :3]), _ascii_rgb(table[:, 3]), "pcd ascii"
    if kind == "binary":
        need_bytes(path, len(raw), start + n * step, f"{n} points of {step} bytes")
        dtype = np.dtype({"names": fields, "formats": formats, "offsets": at, "itemsize": step})
        rec = np.frombuffer(raw, dtype=dtype, count=n, offset=start)
        colour = None if rgb is None else unpack_rgb(rec[rgb])
        return stack(rec), colour, "pcd binary"
    if kind == "binary_compressed":
        need_bytes(path, len(raw), start + 8, "the compressed block's sizes")
        packed, unpacked = (int(v) for v in np.frombuffer(raw, dtype="<u4", count=2, offset=start))
        if unpacked != n * step:
            raise InputError(
                path,
                f"PCD compressed block unpacks to {unpacked} bytes, {n} points need {n * step}",
            )
        need_bytes(path, len(raw), start + 8 + packed, f"a compressed block of {packed} bytes")
        used = [a for a in (*XYZ, rgb) if a is not None]
        with _lower_case_fields(path, raw, start, names, {a: where[a] for a in used}) as source:
            try:
                pts, values = open3d_points(source, n, colours=rgb is not None)
            except InputError as exc:
                raise InputError(path, exc.problem) from exc
        colour = None  # Open3D unpacks the field into bytes / 255
        if values is not None:
            colour = np.clip(np.rint(values), 0, 255).astype(np.uint8)
        return pts, colour, "pcd binary_compressed"
    raise InputError(path, f"PCD header: unknown DATA {' '.join(head['DATA'])!r}")


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


def _ascii_rgb(values: NDArray[np.float64]) -> NDArray[np.uint8]:
    """Packed colours written as text: integers (PCL) or floats whose bits they are (older
    writers); see the module's docstring."""
    whole = np.isfinite(values) & (values == np.floor(values))
    if whole.all() and (values >= 0).all() and (values < 2.0**32).all():
        return unpack_rgb(values.astype(np.uint32))
    with np.errstate(invalid="ignore", over="ignore"):  # NaN/inf/huge: their float32 bits
        bits = values.astype(np.float32).view(np.uint32)
    return unpack_rgb(bits)


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
