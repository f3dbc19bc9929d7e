"""LAS and LAZ files -> float64 points, whole (:func:`read_las`, with the points' colours and
every other dimension, point format, scales, offsets and records on request) or streamed by
point range (:func:`iter_las`), and their headers alone (:func:`las_info`); a path or a URL.

A local uncompressed LAS file with a regular header is read without laspy (``_las_plain.py``:
the same points); the rest by laspy (LAZ through lazrs, its chunks decoded on every core), read
chunk by chunk. Coordinates are the scaled float64 ``x, y, z`` (UTM eastings ~5e6 m lose
centimetres in float32), computed by ``_las_kernels.py``. Before either reads, a file's header
and (LAZ) chunk table are checked against the file's size (``_las_layout.py``), and a Rust panic
in lazrs is refused like any corrupt file.
"""

from __future__ import annotations

import contextlib
import logging
import sys
from collections.abc import Collection, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError
from scan2terrain.fileio import is_url, url_path
from scan2terrain.readers._cloud_common import Decoded
from scan2terrain.readers._files import regular_file
from scan2terrain.readers._las_layout import check_las_layout, is_panic, panic_error
from scan2terrain.readers._las_plain import PlainLas, plain_header, read_records
from scan2terrain.readers._limits import MAX_COORDINATE_M, within
from scan2terrain.types import LasLayout, LasVlr

LAS_SUFFIXES = (".las", ".laz")
#: LAS points decoded per chunk (about 50 MB of LAS records at most).
LAS_CHUNK = 1_000_000
# laspy logs a backend it could not build (a corrupt LAZ) before raising; library code never
# prints, and without a handler Python's last resort would print it to stderr.
logging.getLogger("laspy").addHandler(logging.NullHandler())


def class_codes(path: Path | str, suffix: str, las_classes: Collection[int]) -> NDArray[np.int64]:
    """The requested LAS classification codes, sorted and unique; InputError for a file that
    is not LAS/LAZ (``suffix``), ValueError for codes outside 0..255."""
    if suffix not in LAS_SUFFIXES:
        raise InputError(path, "LAS classes can only be selected in .las/.laz files")
    classes = np.array(sorted({int(c) for c in las_classes}), dtype=np.int64)
    if classes.size == 0 or classes.min() < 0 or classes.max() > 255:
        raise ValueError(f"las_classes must be LAS class codes 0..255, got {las_classes!r}")
    return classes


def read_las(
    path: Path,
    classes: NDArray[np.int64] | None,
    *,
    colours: bool = False,
    attributes: bool = False,
) -> Decoded:
    """All points of a local LAS/LAZ file (of ``classes`` only, when given), their colours and
    what was read (``"laz 1.2 point format 3"``); for
    :func:`~scan2terrain.readers.cloudfile.read_cloud`.

    Colours (uint8 (N, 3) RGB) only when ``colours`` is asked for and the point format has them
    (formats 2, 3, 5, 7, 8 and 10); None otherwise. LAS stores 16-bit colour, but many writers
    store 8-bit values unscaled: if every colour value of the file (all its points, whichever
    classes are kept) is <= 255 the values are used as they are, else their high byte is kept.

    With ``attributes``, every dimension of the point format but X, Y, Z as stored (laspy's
    names and types: bit fields as uint8, extra bytes scaled), and the file's
    :class:`~scan2terrain.types.LasLayout` (point format, scales, offsets, records).
    Arrays are allocated once for the header's point count and filled chunk by chunk.
    """
    import laspy  # type: ignore[import-untyped]

    peak = 0  # the largest colour value of any point read
    present: set[int] = set()
    seen = kept = 0
    columns: dict[str, NDArray[Any]] = {}
    unread: list[str] = []
    layout = None
    with path.open("rb") as raw:
        check_las_layout(raw, path.stat().st_size, path, decode=(0, None))
        plain = None if colours or attributes else plain_header(raw)
    if plain is not None:
        return _read_plain(path, plain, classes)
    try:
        with laspy.open(path) as reader:
            header = reader.header
            n = int(header.point_count)
            version = f"{header.version.major}.{header.version.minor}"
            fmt = f"{path.suffix.lower()[1:]} {version} point format {header.point_format.id}"
            dims = list(header.point_format.dimension_names)
            coloured = (colours or attributes) and "red" in dims
            names = [d for d in dims if d not in ("X", "Y", "Z")] if attributes else []
            if coloured and not attributes:
                names = ["red", "green", "blue"]
            points = np.empty((n, 3), dtype=np.float64)
            for chunk in reader.chunk_iterator(LAS_CHUNK):
                m = len(chunk)
                if seen + m > n:  # pragma: no cover - laspy reads the header's count
                    break
                seen += m
                keep = None
                if classes is not None:
                    codes = np.asarray(chunk.classification)
                    present.update(np.unique(codes).tolist())
                    keep = np.isin(codes, classes)
                    m = int(np.count_nonzero(keep))
                first = seen - len(chunk)  # the chunk's first point in the file
                if keep is None:
                    _xyz(chunk, out=points[kept : kept + m], where=path, first=first)
                else:
                    points[kept : kept + m] = _xyz(chunk, where=path, first=first)[keep]
                for name in names:
                    values = np.asarray(chunk[name])
                    if name in ("red", "green", "blue") and len(values):
                        peak = max(peak, int(values.max()))
                    if values.ndim != 1:
                        if name not in unread:
                            unread.append(name)
                        continue
                    if name not in columns:
                        columns[name] = np.empty(n, dtype=values.dtype)
                    columns[name][kept : kept + m] = values if keep is None else values[keep]
                kept += m
            if attributes:
                layout = _layout(header)
    except (laspy.errors.LaspyException, ValueError, RuntimeError, EOFError) as exc:
        if isinstance(exc, InputError):
            raise
        # lazrs raises LazrsError (a RuntimeError) for corrupt or truncated LAZ data.
        raise InputError(path, f"cannot read as LAS/LAZ ({exc})") from exc
    except BaseException as exc:
        if not is_panic(exc):
            raise
        raise panic_error(path, exc) from exc
    if seen != n:
        raise InputError(path, f"truncated LAS file: the header says {n} points, read {seen}")
    if classes is not None and kept == 0 and seen > 0:
        raise InputError(
            path,
            f"no point of class {', '.join(map(str, classes.tolist()))} "
            f"(classes present: {', '.join(map(str, sorted(present)))})",
        )
    small = kept < n // 2  # copied out of the arrays sized for every point
    points = points[:kept].copy() if small else points[:kept]
    for name in list(columns):
        if name in unread:
            del columns[name]
        else:
            columns[name] = columns[name][:kept].copy() if small else columns[name][:kept]
    colour = None
    if coloured and colours:
        rgb16 = np.stack([columns[c] for c in ("red", "green", "blue")], axis=1)
        colour = (rgb16 if peak <= 255 else rgb16 >> 8).astype(np.uint8)
    if not attributes:
        columns = {}
    unread_why = tuple(f"{u} (an array per point)" for u in unread)
    return Decoded(points, colour, fmt, columns, layout, unread_why)


def _read_plain(path: Path, las: PlainLas, classes: NDArray[np.int64] | None) -> Decoded:
    """:func:`read_las`'s points of an uncompressed LAS file with a regular header, without
    laspy (``_las_plain.py``): the same points, in the same order."""
    fmt = f"{path.suffix.lower()[1:]} {las.version} point format {las.point_format}"
    n = las.count
    points = np.empty((n, 3), dtype=np.float64)
    wanted = np.zeros(256, dtype=np.bool_)
    present = np.zeros(256, dtype=np.int64)
    if classes is not None:
        wanted[classes] = True
    seen = kept = 0
    try:
        with path.open("rb") as f:
            for records in read_records(f, las, path, 0, n, LAS_CHUNK):
                m = len(records)
                if classes is None:
                    _scaled(records, las.scales, las.offsets, out=points[kept : kept + m],
                            where=path, first=seen)  # fmt: skip
                else:
                    codes = las.classes(records)
                    present += np.bincount(codes, minlength=256)
                    keep = wanted[codes]
                    m = int(np.count_nonzero(keep))
                    xyz = _scaled(records, las.scales, las.offsets, where=path, first=seen)
                    points[kept : kept + m] = xyz[keep]
                seen += len(records)
                kept += m
    except OSError as exc:
        raise InputError(path, f"cannot read as LAS/LAZ ({exc})") from exc
    if classes is not None and kept == 0 and seen > 0:
        raise InputError(
            path,
            f"no point of class {', '.join(map(str, classes.tolist()))} "
            f"(classes present: {', '.join(map(str, np.flatnonzero(present).tolist()))})",
        )
    points = points[:kept].copy() if kept < n // 2 else points[:kept]
    return Decoded(points, None, fmt)


#: Records laspy writes itself: LASzip's, and the description of the extra bytes.
_WRITER_VLRS = {("laszip encoded", 22204), ("LASF_Spec", 4)}


def _layout(header: Any) -> LasLayout:
    """A laspy header's point format, scales, offsets and records."""
    records = []
    for extended, vlrs in ((False, header.vlrs), (True, header.evlrs or [])):
        for v in vlrs:
            if (v.user_id, v.record_id) in _WRITER_VLRS:
                continue
            data = v.record_data_bytes()
            records.append(LasVlr(v.user_id, v.record_id, v.description, bytes(data), extended))
    day = header.creation_date
    return LasLayout(
        version=f"{header.version.major}.{header.version.minor}",
        point_format=int(header.point_format.id),
        scales=tuple(float(v) for v in header.scales),  # type: ignore[arg-type]  # 3 axes
        offsets=tuple(float(v) for v in header.offsets),  # type: ignore[arg-type]
        vlrs=tuple(records),
        global_encoding=int(header.global_encoding.value),
        system_identifier=str(header.system_identifier),
        file_source_id=int(header.file_source_id),
        creation=(0, 0) if day is None else (day.timetuple().tm_yday, day.year),
    )


@dataclass(frozen=True)
class LasInfo:
    """A LAS/LAZ header: point count and bounds (the file's units) without reading points."""

    path: Path | str  #: a local path, or a URL as given
    points: int
    mins: tuple[float, float, float]
    maxs: tuple[float, float, float]
    format: str
    #: A LAZ file of variable-size chunks (COPC's): read from its start, never from a point
    #: within (:func:`iter_las` skips to one by reading up to it; lazrs's seek gets it wrong).
    variable_chunks: bool = False


def url_suffix(name: Path | str) -> str:
    """The lower-case extension of a path or URL."""
    return url_path(name).suffix.lower()


@contextlib.contextmanager
def _las_source(name: Path | str) -> Iterator[Any]:
    """What ``laspy.open`` reads: a local path, or a file object fsspec opens for a URL (any
    protocol fsspec has: http(s) with aiohttp, s3 with s3fs, ...)."""
    if not is_url(name):
        path = Path(name)
        if regular_file(path, "point-cloud file") == 0:
            raise InputError(path, "empty file")
        yield path
        return
    url = str(name)
    try:
        import fsspec  # type: ignore[import-untyped]
    except ImportError:
        raise InputError(url, "URLs need fsspec: pip install 'scan2terrain[dask]'") from None
    try:
        with fsspec.open(url, "rb") as f:
            yield f
    except (FileNotFoundError, ImportError, ValueError) as exc:
        raise InputError(url, f"cannot open the URL ({type(exc).__name__}: {exc})") from exc


def _read_error(exc: BaseException) -> bool:
    """An error of reading a file laspy or lazrs could not read (laspy's own errors are only
    raised once it is imported: a plain LAS file is read without it)."""
    if isinstance(exc, (ValueError, RuntimeError, EOFError, OSError)):
        return True
    laspy = sys.modules.get("laspy")
    return laspy is not None and isinstance(exc, laspy.errors.LaspyException)


def las_info(path: Path | str) -> LasInfo:
    """The header of a LAS/LAZ file (a path, or a URL fsspec can open). Raises InputError for a
    missing, empty, foreign or truncated (uncompressed: shorter than its header's points need)
    file."""
    where: Path | str = path if is_url(path) else Path(path)
    try:
        with _las_source(where) as source, _checked(source, where) as (variable, plain):
            if plain is not None:
                fmt = f"{url_suffix(where)[1:]} {plain.version} point format {plain.point_format}"
                return LasInfo(where, plain.count, plain.mins, plain.maxs, fmt)
            import laspy

            with laspy.open(source) as reader:
                h = reader.header
                n = int(h.point_count)
                version = f"{h.version.major}.{h.version.minor}"
                fmt = f"{url_suffix(where)[1:]} {version} point format {h.point_format.id}"
                mins = tuple(float(v) for v in h.mins)
                maxs = tuple(float(v) for v in h.maxs)
    except Exception as exc:
        if isinstance(exc, InputError) or not _read_error(exc):
            raise
        raise InputError(where, f"cannot read as LAS/LAZ ({exc})") from exc
    except BaseException as exc:
        if not is_panic(exc):
            raise
        raise panic_error(where, exc) from exc
    return LasInfo(where, n, mins, maxs, fmt, variable)  # type: ignore[arg-type]  # 3-tuples


@contextlib.contextmanager
def _checked(
    source: Any, where: Path | str, decode: tuple[int, int | None] | None = None
) -> Iterator[tuple[bool, PlainLas | None]]:
    """:func:`check_las_layout` on a path or a seekable file object (left at its start),
    giving whether the file is a LAZ of variable-size chunks and, for a local uncompressed LAS
    file with a regular header, that header (``_las_plain.py``: read without laspy); an
    unseekable stream is not checked (the PanicException backstop still applies; False)."""
    variable = False
    plain = None
    if isinstance(source, Path):
        with source.open("rb") as f:
            variable = check_las_layout(f, source.stat().st_size, where, decode=decode)
            plain = plain_header(f)
    elif source.seekable():
        variable = check_las_layout(source, _size(source), where, decode=decode)
        source.seek(0)
    yield variable, plain


def _size(source: Any) -> int:
    if isinstance(source, Path):
        return source.stat().st_size
    size = getattr(source, "size", None)
    if size is None:
        here = source.tell()
        size = source.seek(0, 2)
        source.seek(here)
    return int(size)


def iter_las(
    path: Path | str,
    *,
    start: int = 0,
    count: int | None = None,
    step: int = LAS_CHUNK,
    las_classes: Collection[int] | None = None,
    origin: NDArray[np.float64] | None = None,
) -> Iterator[NDArray[np.float64]]:
    """Points ``[start, start + count)`` of a LAS/LAZ file (``count`` None: to the end), ``step``
    at a time, as float64 (n, 3) in the file's units (``X * scale + offset``, as laspy computes
    them) less ``origin``, of the requested classes only. Non-finite points are not possible in
    LAS. Raises InputError naming the file for unreadable or truncated data. A local
    uncompressed file is read without laspy (``_las_plain.py``), LAZ by laspy and lazrs (its
    chunks decoded on every core)."""
    where: Path | str = path if is_url(path) else Path(path)
    suffix = url_suffix(where)
    classes = None if las_classes is None else class_codes(where, suffix, las_classes)
    want = -1
    seen = 0
    try:
        stop = None if count is None else start + count
        with (
            _las_source(where) as source,
            _checked(source, where, (start, stop)) as (variable, plain),
        ):
            if plain is not None:
                want = plain.count - start if count is None else min(count, plain.count - start)
                with Path(source).open("rb") as f:
                    for records in read_records(f, plain, where, start, start + want, step):
                        xyz = _scaled(records, plain.scales, plain.offsets, origin,
                                      where=where, first=start + seen)  # fmt: skip
                        seen += len(records)
                        if classes is not None:
                            xyz = xyz[np.isin(plain.classes(records), classes)]
                        yield xyz
            else:
                import laspy

                with laspy.open(source) as reader:
                    total = int(reader.header.point_count)
                    want = total - start if count is None else min(count, total - start)
                    if start and variable:
                        _read_past(reader, start, step)
                    elif start:
                        reader.seek(start)
                    while seen < want:
                        chunk = reader.read_points(min(step, want - seen))
                        if len(chunk) == 0:
                            break
                        xyz = _xyz(chunk, origin, where=where, first=start + seen)
                        seen += len(chunk)
                        if classes is not None:
                            xyz = xyz[np.isin(np.asarray(chunk.classification), classes)]
                        yield xyz
    except Exception as exc:
        if isinstance(exc, InputError) or not _read_error(exc):
            raise
        raise InputError(where, f"cannot read as LAS/LAZ ({exc})") from exc
    except BaseException as exc:  # GeneratorExit at a yield is re-raised as it is
        if not is_panic(exc):
            raise
        raise panic_error(where, exc) from exc
    if seen != want:
        raise InputError(
            where, f"truncated LAS file: expected points {start}..{start + want}, read {seen}"
        )


def _read_past(reader: Any, n: int, step: int) -> None:
    """Decode and drop the first ``n`` points of a LAZ of variable-size chunks, ``step`` at a
    time: lazrs seeks into such a file wrongly (see ``check_las_layout``). The streamed path
    plans such a file as one piece, so this runs only for callers that start elsewhere."""
    done = 0
    while done < n:
        got = len(reader.read_points(min(step, n - done)))
        if got == 0:
            return  # the caller finds the file truncated
        done += got


def _xyz(
    points: Any,
    origin: NDArray[np.float64] | None = None,
    out: NDArray[np.float64] | None = None,
    *,
    where: Path | str,
    first: int,
) -> NDArray[np.float64]:
    """(n, 3) float64 coordinates of a laspy ScaleAwarePointRecord (:func:`_scaled`)."""
    arr = points.array
    return _scaled(
        arr, np.asarray(points.scales), np.asarray(points.offsets), origin, out,
        where=where, first=first,
    )  # fmt: skip


def _scaled(
    records: NDArray[Any],
    scales: NDArray[np.float64],
    offsets: NDArray[np.float64],
    origin: NDArray[np.float64] | None = None,
    out: NDArray[np.float64] | None = None,
    *,
    where: Path | str,
    first: int,
) -> NDArray[np.float64]:
    """(n, 3) float64 coordinates of LAS records (fields X, Y, Z), exactly as laspy scales
    them (``X * scale + offset``), less ``origin`` (metres, default none); into ``out`` (C-
    contiguous (n, 3)) when given. InputError naming ``where`` and the point (``first`` is the
    index of the records' first point in the file) for a coordinate beyond
    MAX_COORDINATE_M."""
    from scan2terrain.readers._las_kernels import scaled_xyz

    if out is None:
        out = np.empty((len(records), 3), dtype=np.float64)
    scales = np.asarray(scales, dtype=np.float64)
    offsets = np.asarray(offsets, dtype=np.float64)
    shift = np.zeros(3) if origin is None else np.asarray(origin, dtype=np.float64)
    scaled_xyz(records["X"], records["Y"], records["Z"], scales, offsets, shift, out)
    # Only where the header lets an int32 reach beyond the limit (a scale of 0.5 m or more;
    # _las_layout has checked the offsets) is there a point to look for: usual files pay nothing.
    for axis in np.flatnonzero(np.abs(offsets) + 2.0**31 * scales > MAX_COORDINATE_M):
        far = np.flatnonzero(np.abs(out[:, axis] + shift[axis]) > MAX_COORDINATE_M)
        if len(far):
            value = float(out[far[0], axis] + shift[axis])
            name = f"point {first + int(far[0])}: {'XYZ'[axis]}"
            within(where, name, value, lo=0.0, hi=MAX_COORDINATE_M, unit="m")
    return out
