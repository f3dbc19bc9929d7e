"""LAS/LAZ header and LAZ chunk-table checks against the file's size, the format and the physical
world, from the raw bytes.

laspy reads VLRs by a count and lazrs allocates a chunk table by another, and a corrupt count
made them take all memory or abort the process (a Rust allocation failure is not an exception);
so :func:`check_las_layout` runs before either reads. It also refuses scales, offsets and bounds
no survey has (``_limits.py``) and a LASzip VLR whose items do not describe the header's point
format. A Rust panic in lazrs (pyo3's ``PanicException``, a ``BaseException``) is recognised by
:func:`is_panic`.
"""

from __future__ import annotations

import math
import re
import struct
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

from scan2terrain.errors import InputError
from scan2terrain.readers._limits import (
    MAX_COORDINATE_M,
    MAX_SPACING_DEG,
    MAX_SPACING_M,
    MIN_SPACING_DEG,
    MIN_SPACING_M,
    exact_after_scaling,
    within,
)

# LAS 1.0-1.4 "public header block" and LAZ (LASzip) layout: the laszip VLR, then at the start
# of the point data an int64 offset to the chunk table (-1 or 0: the writer could not seek back
# and put it in the file's last 8 bytes), and there uint32 version 0, uint32 number of chunks and
# the arithmetic-coded entries (byte counts; point counts too for variable-size chunks).
_LAS_HEADER_MIN = 227  # LAS 1.0-1.2
_LAS14_HEADER = 375
_VLR_HEADER = 54
_EVLR_HEADER = 60
_LASZIP_VLR = (b"laszip encoded", 22204)  # user id, record id
_LASZIP_FIXED = 34  # payload bytes before its item records (6 bytes each)
_VARIABLE_CHUNKS = 0xFFFFFFFF
_CHUNKED = (2, 3)  # the laszip VLR's compressor: pointwise chunked, layered chunked
#: Points a byte of LAZ data can hold at most. LASzip packs about 150 identical points into a
#: byte; a header claiming hundreds of times more is corrupt, and would be planned by.
_LAZ_POINTS_PER_BYTE = 1 << 16
#: The most points a fixed-size LAZ chunk may hold beyond the file's own point count. LASzip
#: writes 50,000 (files smaller than a chunk keep that size); lazrs allocates a whole chunk of
#: points for the last one, so two corrupt bytes of the size (2^31 points) made it abort the
#: process (a Rust allocation failure, SIGABRT) where 73 GB could not be had.
_LAZ_MAX_CHUNK = 1 << 22

# LASzip's items (type, bytes) of each point format, in the order it writes them (LASzip's
# laszip.cpp, setup()); the extra bytes of a longer record follow as one more item.
_POINT10, _GPSTIME11, _RGB12, _WAVEPACKET13 = (6, 20), (7, 8), (8, 6), (9, 29)
_POINT14, _RGB14, _RGBNIR14, _WAVEPACKET14 = (10, 30), (11, 6), (12, 8), (13, 29)
_LASZIP_ITEMS = {
    0: (_POINT10,),
    1: (_POINT10, _GPSTIME11),
    2: (_POINT10, _RGB12),
    3: (_POINT10, _GPSTIME11, _RGB12),
    4: (_POINT10, _GPSTIME11, _WAVEPACKET13),
    5: (_POINT10, _GPSTIME11, _RGB12, _WAVEPACKET13),
    6: (_POINT14,),
    7: (_POINT14, _RGB14),
    8: (_POINT14, _RGBNIR14),
    9: (_POINT14, _WAVEPACKET14),
    10: (_POINT14, _RGBNIR14, _WAVEPACKET14),
}
#: Point formats 0-5 are compressed pointwise (compressor 1, or 2 in chunks; items of version 1
#: or 2; extra bytes as BYTE, type 0), 6-10 in layered chunks (compressor 3; versions 3 or 4;
#: extra bytes as BYTE14, type 14). The arithmetic coder (0) is the only one.
_POINTWISE = ((1, 2), (1, 2), 0)
_LAYERED = ((3,), (3, 4), 14)


def check_las_layout(
    f: BinaryIO, size: int, where: Path | str, *, decode: tuple[int, int | None] | None
) -> bool:
    """Refuse a LAS/LAZ file whose header counts and offsets (and LAZ chunk table) do not fit
    in its ``size`` bytes, reading a few raw bytes from ``f`` (left at an arbitrary position).
    True for a LAZ file of variable-size chunks (COPC's), which lazrs cannot seek into: it
    takes a point's place in its chunk as its index modulo the chunk size, 2^32 - 1 there
    (laz-rs 0.12, ParLasZipDecompressor.seek), and read other points or zeros.

    Done before laspy reads the header (it reads VLRs and EVLRs by the header's counts and
    lengths) and before lazrs decodes (it allocates the chunk table by its count: 2^32 chunks
    made it abort the process). ``decode``: the points ``[start, stop)`` (stop None: to the
    end) about to be decoded, whose LAZ chunks' layer sizes are checked too; None: none. A file
    that is no LAS file at all is left to laspy to name.
    """
    head = _read_at(f, 0, _LAS14_HEADER)
    if len(head) < _LAS_HEADER_MIN or not head.startswith(b"LASF"):
        return False
    header_size, start, n_vlrs, format_id, record, count = struct.unpack_from("<HIIBHI", head, 94)
    _check_scales(head, where)
    first_evlr = n_evlrs = 0
    if head[25] >= 4 and len(head) >= _LAS14_HEADER:  # LAS 1.4: 64-bit count, EVLRs
        first_evlr, n_evlrs, count = struct.unpack_from("<QIQ", head, 235)
    if start > size:
        raise InputError(
            where, f"truncated LAS file: its points start at byte {start}, the file has {size}"
        )
    if header_size <= start and n_vlrs * _VLR_HEADER > start - header_size:
        raise InputError(
            where,
            f"corrupt LAS header: {n_vlrs:,} VLRs cannot fit in the {start - header_size} bytes "
            "between the header and the points",
        )
    _check_coordinates(head, count, where, lambda: _crs_kind(f, header_size, start, n_vlrs))
    if n_evlrs:
        _check_evlrs(f, size, first_evlr, n_evlrs, where)
    if format_id & 0xC0 != 0x80:  # not compressed (laspy's rule: bit 7 set, bit 6 clear)
        need = start + count * record
        if size < need:
            raise InputError(
                where,
                f"truncated LAS file: {count} points of {record} bytes need {need} bytes, "
                f"the file has {size}",
            )
        return False
    if count and header_size <= start:
        laszip = _laszip_payload(_read_at(f, header_size, start - header_size), n_vlrs)
        if laszip is not None:
            _check_laz(
                f, size, laszip, start=start, record=record, count=count, where=where,
                decode=decode, point_format=format_id & 0x3F,
            )  # fmt: skip
            return bool(struct.unpack_from("<I", laszip, 12)[0] == _VARIABLE_CHUNKS)
    return False


def _check_scales(head: bytes, where: Path | str) -> None:
    """Refuse scale factors that are not positive and finite (0 put every point at the offset,
    a negative one mirrored the cloud, both read without a word) and non-finite offsets."""
    scales = struct.unpack_from("<3d", head, 131)
    offsets = struct.unpack_from("<3d", head, 155)
    if not all(math.isfinite(v) and v > 0 for v in scales):
        raise InputError(
            where,
            f"corrupt LAS header: scale factors ({', '.join(f'{v:g}' for v in scales)}) must be "
            "positive and finite",
        )
    if not all(math.isfinite(v) for v in offsets):
        raise InputError(
            where,
            f"corrupt LAS header: offsets ({', '.join(f'{v:g}' for v in offsets)}) must be finite",
        )


#: The LAS header's names of the axes' numbers, as the specification spells them.
_AXES = ("X", "Y", "Z")
#: An int32 coordinate's reach from its offset, in steps of its scale.
_INT32_STEPS = 2.0**31


def _check_coordinates(
    head: bytes, count: int, where: Path | str, crs_kind: Callable[[], str | None]
) -> None:
    """Refuse scales, offsets and bounds the physical world has no use for (``_limits.py``),
    and offsets that float64 cannot hold to within their scale's step at the int32 range.

    Scales are metres (MIN_SPACING_M..MAX_SPACING_M); x and y scales are degrees of arc
    (MIN_SPACING_DEG..MAX_SPACING_DEG) in a geographic CRS. ``crs_kind`` ("geographic",
    "projected" or None: no CRS record) is asked only for an x or y scale outside the range
    both units allow; a file that names no CRS is taken to be in degrees when its header's x
    and y bounds lie within +-360 and +-90 (geographic LAS without a CRS record exists). Z is
    metres (or feet) in every CRS. Offsets and the bounds (the streamed path plans its tiles,
    and both paths their resolution, by them) lie within MAX_COORDINATE_M, min <= max."""
    scales = struct.unpack_from("<3d", head, 131)
    offsets = struct.unpack_from("<3d", head, 155)
    bounds = struct.unpack_from("<6d", head, 179)  # max X, min X, max Y, min Y, max Z, min Z
    highs, lows = bounds[0::2], bounds[1::2]
    for axis, name in enumerate(_AXES):
        unit = "m"
        lo, hi = MIN_SPACING_M, MAX_SPACING_M
        if axis < 2 and not MIN_SPACING_M <= scales[axis] <= MAX_SPACING_DEG:
            kind = crs_kind()
            degrees = kind == "geographic" or (
                kind is None
                and all(abs(v) <= 360.0 for v in (lows[0], highs[0]))
                and all(abs(v) <= 90.0 for v in (lows[1], highs[1]))
            )
            if degrees:
                unit, lo, hi = "deg", MIN_SPACING_DEG, MAX_SPACING_DEG
        within(where, f"{name} scale factor", scales[axis], lo=lo, hi=hi, unit=unit)
        within(where, f"{name} offset", offsets[axis], lo=0.0, hi=MAX_COORDINATE_M, unit=unit)
        exact_after_scaling(where, name, scales[axis], offsets[axis], _INT32_STEPS * scales[axis])
        if count:
            for bound, value in (("Max", highs[axis]), ("Min", lows[axis])):
                within(where, f"{bound} {name}", value, lo=0.0, hi=MAX_COORDINATE_M, unit=unit)
            if lows[axis] > highs[axis]:
                raise InputError(
                    where,
                    f"Min {name} = {lows[axis]:.6g} {unit} is above Max {name} = "
                    f"{highs[axis]:.6g} {unit}: the header's bounds are corrupt",
                )


#: GeoTIFF keys (LAS 1.0-1.4) and OGC WKT (LAS 1.4) records of a LAS file's CRS.
_GEOKEYS = (b"LASF_Projection", 34735)
_WKT = (b"LASF_Projection", 2112)
#: GTModelTypeGeoKey and its values; ProjectedCSTypeGeoKey; GeographicTypeGeoKey.
_MODEL_TYPE, _PROJECTED, _GEOGRAPHIC, _GEOCENTRIC = 1024, 1, 2, 3
_PROJECTED_KEY, _GEOGRAPHIC_KEY = 3072, 2048
#: The first CRS keyword of a WKT (1 or 2) names its kind: a projected CRS names its base
#: geographic one only inside its own brackets, a compound one its horizontal CRS first.
_WKT_KIND = re.compile(
    rb"\b(PROJCS|PROJCRS|PROJECTEDCRS|GEOCCS|GEOGCS|GEOGCRS|GEOGRAPHICCRS|GEODCRS|GEODETICCRS)\s*\["
)


def _crs_kind(f: BinaryIO, header_size: int, start: int, n: int) -> str | None:
    """The kind of the file's CRS: "geographic", "projected" (geocentric too: metres) or None
    (no CRS record among the header's ``n`` VLRs, or none readable; one in an EVLR of LAS 1.4
    is not looked for), from its GeoTIFF keys or WKT (the VLRs' count checked to fit before the
    points)."""
    pos = header_size
    kinds = []
    for _ in range(n):  # a loop over the header's few VLRs
        raw = _read_at(f, pos, _VLR_HEADER)
        if len(raw) < _VLR_HEADER or pos + _VLR_HEADER > start:
            break
        user, record_id, length = struct.unpack_from("<16sHH", raw, 2)
        key = (user.split(b"\0")[0], record_id)
        if key in (_GEOKEYS, _WKT):
            data = _read_at(f, pos + _VLR_HEADER, length)
            kinds.append(_geokeys_kind(data) if key == _GEOKEYS else _wkt_kind(data))
        pos += _VLR_HEADER + length
    if "geographic" in kinds:
        return "geographic"
    return "projected" if "projected" in kinds else None


def _geokeys_kind(data: bytes) -> str | None:
    """A GeoKeyDirectoryTag's model type: its header (4 uint16, the last the number of keys),
    then keys of 4 uint16 (id, location, count, value)."""
    if len(data) < 8:
        return None
    n = min(struct.unpack_from("<H", data, 6)[0], len(data) // 8 - 1)
    keys = {}
    for i in range(n):  # a loop over a few dozen keys
        key, location, _, value = struct.unpack_from("<4H", data, 8 + 8 * i)
        if location == 0:  # the value is in the key itself
            keys[key] = value
    model = keys.get(_MODEL_TYPE)
    geographic_only = _GEOGRAPHIC_KEY in keys and _PROJECTED_KEY not in keys
    if model == _GEOGRAPHIC or (model is None and geographic_only):
        return "geographic"
    if model in (_PROJECTED, _GEOCENTRIC) or _PROJECTED_KEY in keys:
        return "projected"
    return None


def _wkt_kind(data: bytes) -> str | None:
    found = _WKT_KIND.search(data.upper())
    if found is None:
        return None
    word = found.group(1)
    return "projected" if word.startswith((b"PROJ", b"GEOCCS")) else "geographic"


def _check_evlrs(f: BinaryIO, size: int, first: int, n: int, where: Path | str) -> None:
    if first + n * _EVLR_HEADER > size:
        raise InputError(
            where,
            f"corrupt LAS header: {n:,} extended VLRs from byte {first} cannot fit in the file "
            f"({size} bytes)",
        )
    pos = first
    for _ in range(n):  # a loop over the file's few EVLRs, each 60 bytes at least
        raw = _read_at(f, pos, _EVLR_HEADER)
        pos += _EVLR_HEADER + (struct.unpack_from("<Q", raw, 20)[0] if len(raw) == 60 else size)
        if pos > size:
            raise InputError(
                where, f"truncated LAS file: its extended VLRs run past the end ({size} bytes)"
            )


def _laszip_payload(vlrs: bytes, n: int) -> bytes | None:
    """The laszip VLR's data among the ``n`` VLRs in ``vlrs``, or None (laspy refuses then)."""
    pos = 0
    for _ in range(n):  # a loop over the header's few VLRs
        if pos + _VLR_HEADER > len(vlrs):
            return None
        user, record_id, length = struct.unpack_from("<16sHH", vlrs, pos + 2)
        if (user.split(b"\0")[0], record_id) == _LASZIP_VLR:  # laspy's reading of the id
            return vlrs[pos + _VLR_HEADER : pos + _VLR_HEADER + length]
        pos += _VLR_HEADER + length
    return None


def _check_laz(  # noqa: PLR0913 (the header fields the chunk table is checked against)
    f: BinaryIO,
    size: int,
    laszip: bytes,
    *,
    start: int,
    record: int,
    count: int,
    where: Path | str,
    decode: tuple[int, int | None] | None,
    point_format: int,
) -> None:
    """The laszip VLR against the header's point format (:func:`_check_laszip_vlr`), the chunk
    table against the header's point count and the file's size (LAZ, count > 0), and the layer
    sizes of the chunks holding the points to ``decode``."""

    def corrupt(problem: str) -> InputError:
        return InputError(where, f"corrupt LAZ file: {problem}")

    if len(laszip) < _LASZIP_FIXED:
        raise corrupt(f"its laszip VLR has {len(laszip)} bytes, fewer than {_LASZIP_FIXED}")
    chunk_size = struct.unpack_from("<I", laszip, 12)[0]
    n_items = struct.unpack_from("<H", laszip, 32)[0]
    if len(laszip) < _LASZIP_FIXED + 6 * n_items:
        raise corrupt(f"its laszip VLR lists {n_items} items in {len(laszip)} bytes")
    item_size = sum(
        struct.unpack_from("<H", laszip, _LASZIP_FIXED + 6 * i + 2)[0] for i in range(n_items)
    )
    if item_size != record:
        raise corrupt(
            f"its laszip VLR describes {item_size}-byte points, the header {record}-byte ones"
        )
    _check_laszip_vlr(
        laszip, n_items, point_format=point_format, record=record, count=count, where=where
    )
    if struct.unpack_from("<H", laszip, 0)[0] not in _CHUNKED:
        return  # pointwise LAZ (LASzip 1.x) has no chunk table; lazrs refuses other values
    if chunk_size == 0:
        raise corrupt("its laszip VLR has a chunk size of 0 points")
    data_start = start + 8
    if size < data_start:
        raise InputError(
            where,
            f"truncated LAZ file: it ends at byte {size}, before its compressed points start "
            f"(byte {data_start})",
        )
    table = struct.unpack("<q", _read_at(f, start, 8))[0]
    if table <= start:  # the writer could not seek back: the offset ends the file
        table = struct.unpack("<q", _read_at(f, size - 8, 8))[0]
    if table <= start:
        raise InputError(
            where, "truncated or corrupt LAZ file: it has no chunk table (an unfinished write?)"
        )
    if not data_start <= table <= size - 8:
        raise InputError(
            where,
            f"truncated or corrupt LAZ file: its chunk table offset {table} lies outside the "
            f"compressed data (bytes {data_start}..{size})",
        )
    data = table - data_start
    version, chunks = struct.unpack("<II", _read_at(f, table, 8))
    if version != 0:
        raise corrupt(f"unknown chunk table version {version} (LASzip writes 0)")
    if chunk_size != _VARIABLE_CHUNKS:
        expected = -(-count // chunk_size)
        if chunks != expected:
            raise corrupt(
                f"its chunk table lists {chunks:,} chunks, {count:,} points in chunks of "
                f"{chunk_size:,} make {expected:,}"
            )
    elif not 1 <= chunks <= count:
        raise corrupt(f"its chunk table lists {chunks:,} chunks for {count:,} points")
    if chunks * item_size > data:  # each chunk starts with a raw point
        raise corrupt(f"{chunks:,} chunks cannot fit in {data:,} bytes of compressed points")
    if count > data * _LAZ_POINTS_PER_BYTE:
        raise corrupt(
            f"the header says {count:,} points, more than {data:,} bytes of LAZ data can hold"
        )
    entries = _laz_chunk_table(f, start, laszip, where)
    if sum(b for _, b in entries) != data:
        raise corrupt(
            f"its chunk table's byte counts add up to {sum(b for _, b in entries):,}, the "
            f"compressed points take {data:,}"
        )
    if chunk_size == _VARIABLE_CHUNKS and sum(p for p, _ in entries) != count:
        raise corrupt(
            f"its chunk table's point counts add up to {sum(p for p, _ in entries):,}, the "
            f"header says {count:,}"
        )
    layers = _layer_count(laszip, n_items)
    if chunk_size == _VARIABLE_CHUNKS and decode is not None:
        decode = (0, decode[1])  # read from the start, never sought into (check_las_layout)
    if layers and decode is not None:
        _check_layers(
            f,
            entries,
            data_start=data_start,
            record=record,
            layers=layers,
            decode=decode,
            corrupt=corrupt,
        )


def _check_laszip_vlr(
    laszip: bytes, n_items: int, *, point_format: int, record: int, count: int, where: Path | str
) -> None:
    """Refuse a laszip VLR (its ``n_items`` item records in bounds, their bytes adding up to the
    header's ``record`` length) that LASzip would not have written for the header's point
    format: its compressor, coder, items (type, size and version, in LASzip's order, the extra
    bytes last) and, for fixed-size chunks, a chunk size of 1 to ``max(count,
    _LAZ_MAX_CHUNK)`` points. lazrs decodes by these: an item of another type or version
    decoded another field's bytes silently (a wrong type of the same size) or failed inside
    its threads, and a chunk size of 2^31 points made it allocate 73 GB and abort."""
    compressor, coder = struct.unpack_from("<HH", laszip, 0)
    chunk_size = struct.unpack_from("<I", laszip, 12)[0]
    if point_format not in _LASZIP_ITEMS:
        return  # laspy refuses the point format itself
    compressors, versions, extra = _POINTWISE if point_format <= 5 else _LAYERED
    if compressor not in compressors:
        raise InputError(
            where,
            f"laszip VLR compressor = {compressor} is not LASzip's for point format "
            f"{point_format} ({' or '.join(map(str, compressors))})",
        )
    if coder != 0:
        raise InputError(where, f"laszip VLR coder = {coder} is not LASzip's (0, arithmetic)")
    items = list(_LASZIP_ITEMS[point_format])
    base = sum(size for _, size in items)
    if record > base:
        items.append((extra, record - base))
    for i in range(max(n_items, len(items))):  # a loop over a few items
        got = struct.unpack_from("<HHH", laszip, _LASZIP_FIXED + 6 * i) if i < n_items else None
        want = items[i] if i < len(items) else None
        if got is not None and want is not None and got[:2] == want and got[2] in versions:
            continue
        needs = (
            f"type {want[0]} ({want[1]} bytes, version {' or '.join(map(str, versions))})"
            if want is not None
            else "no more items"
        )
        name = f"laszip VLR item {i + 1}"
        value = "missing" if got is None else f"type {got[0]} ({got[1]} bytes, version {got[2]})"
        raise InputError(
            where,
            f"{name} = {value}: point format {point_format} of {record}-byte records needs "
            f"{needs} there",
        )
    most = max(count, _LAZ_MAX_CHUNK)
    fixed = compressor in _CHUNKED and chunk_size != _VARIABLE_CHUNKS
    if fixed and not 1 <= chunk_size <= most:
        raise InputError(
            where,
            f"laszip VLR chunk size = {chunk_size} points makes no sense: a chunk holds 1 to "
            f"{most:,} points (the file has {count:,})",
        )


#: Layers per item of a LASzip layered chunk (point formats 6-10, item version 3), by item type:
#: POINT14 (10) 9 (x/y/returns, z, classification, flags, intensity, scan angle, user data,
#: point source, GPS time), RGB14 (11) 1, RGBNIR14 (12) 2, WAVEPACKET14 (13) 1; BYTE14 (14)
#: has one per byte.
_LAYERS = {10: 9, 11: 1, 12: 2, 13: 1}
_BYTE14 = 14


def _layer_count(laszip: bytes, n_items: int) -> int:
    """Layer sizes at the start of each chunk (after its raw first point and point count); 0
    for pointwise chunks (and items lazrs does not decode layered, which it refuses)."""
    layers = 0
    for i in range(n_items):
        kind, item_size, version = struct.unpack_from("<HHH", laszip, _LASZIP_FIXED + 6 * i)
        if version != 3:
            return 0
        layers += item_size if kind == _BYTE14 else _LAYERS.get(kind, 0)
    return layers


def _check_layers(
    f: BinaryIO,
    entries: list[tuple[int, int]],
    *,
    data_start: int,
    record: int,
    layers: int,
    decode: tuple[int, int | None],
    corrupt: Callable[[str], InputError],
) -> None:
    """Each layered chunk holding points of ``decode`` starts with a raw point, a point count
    and ``layers`` uint32 layer sizes, which lazrs allocates by (4 GB for a corrupt one, which
    aborts the process where that much cannot be had): they must fit in the chunk. A read of a
    few dozen bytes per chunk, one chunk per 50,000 points (LASzip's default)."""
    first, stop = decode
    header = record + 4 + 4 * layers
    pos, done = data_start, 0  # chunk i starts at pos, after `done` points
    for i, (points, nbytes) in enumerate(entries):  # a loop over chunks, not points
        if (stop is None or done < stop) and done + points > first:
            raw = _read_at(f, pos + record + 4, 4 * layers)
            if len(raw) < 4 * layers:
                raise corrupt(f"chunk {i} is cut short")
            claimed = sum(struct.unpack(f"<{layers}I", raw))
            if header + claimed > nbytes:
                raise corrupt(f"chunk {i} ({nbytes:,} bytes) has layers of {claimed:,} bytes")
        pos += nbytes
        done += points


def _laz_chunk_table(
    f: BinaryIO, start: int, laszip: bytes, where: Path | str
) -> list[tuple[int, int]]:
    """(points, bytes) per chunk, read by lazrs (its number of chunks already checked)."""
    import lazrs  # type: ignore[import-untyped]

    f.seek(start)
    try:
        entries = lazrs.read_chunk_table(f, lazrs.LazVlr(laszip))
    except lazrs.LazrsError as exc:
        raise InputError(where, f"corrupt LAZ file: cannot read its chunk table ({exc})") from exc
    except BaseException as exc:
        if not is_panic(exc):
            raise
        raise panic_error(where, exc) from exc
    return [(int(p), int(b)) for p, b in entries]


def _read_at(f: BinaryIO, offset: int, n: int) -> bytes:
    f.seek(offset)
    return bytes(f.read(n))


def is_panic(exc: BaseException) -> bool:
    """A Rust panic in lazrs: pyo3's PanicException, a BaseException that ``except Exception``
    misses (its class lives in pyo3's runtime module, so it is known by name)."""
    return type(exc).__name__ == "PanicException"


def panic_error(where: Path | str, exc: BaseException) -> InputError:
    """The refusal of a file that made lazrs panic."""
    return InputError(where, f"corrupt LAZ data (lazrs failed: {exc})")
