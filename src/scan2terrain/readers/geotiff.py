"""Single-band GeoTIFF files with tifffile (no GDAL): the band's samples, its tags, and the
georeference they hold, parsed as GDAL parses them.

* Georeference: ``ModelPixelScaleTag`` (33550) + one ``ModelTiepointTag`` (33922), or an
  axis-aligned ``ModelTransformationTag`` (34264); ``RasterPixelIsPoint`` (GeoKey 1025) moves the
  raster half a pixel as GDAL does. Rotated or sheared rasters and ground control points are
  refused (``gdalwarp`` them first).
* CRS from the ``GeoKeyDirectoryTag`` (34735): ``GTModelTypeGeoKey`` 1 = projected (linear units
  from ``ProjLinearUnitsGeoKey``: metre, foot, US survey foot, kilometre), 2 = geographic (angular
  units from ``GeogAngularUnitsGeoKey``, degrees by default). A pixel scale without GeoKeys that
  say projected or geographic is an incomplete georeference (:func:`incomplete_georeference`).
  ``GDAL_NODATA`` (42113, ASCII) and GDAL's per-band scale and offset (``GDAL_METADATA``) are
  read here too.
* Before decoding, only a regular file is opened, and its numbers must make sense against the
  file and TIFF's rules (issue 28): a SampleFormat of numbers (1, 2 or 3) with a BitsPerSample
  it has (8/16/32/64 bits for integers, 16/32/64 for floating point), at least 2 x 2 samples,
  as many strips or tiles as the raster needs, each inside the file and clear of the header,
  the directory and the tags' values, and uncompressed ones exactly as long as their samples.
  Compressed strips and tiles (Deflate, LZMA, PackBits, LZW, ZSTD) are decoded here, each
  checked to decode to exactly its samples' bytes: raw samples read as PackBits decode to any
  length, which tifffile cuts or pads silently. Whatever tifffile or imagecodecs raise on a
  corrupt file (``zlib.error``, a ``TypeError`` from a tag of another type,
  ``NotImplementedError``) is an :class:`InputError`.
* Samples: one band of any integer or floating-point type (int16, uint16, int32, float32,
  float64 ...). Colour, palette and multi-band TIFFs are refused. Uncompressed, Deflate, LZMA
  and PackBits data and the integer predictor decode with tifffile alone; LZW, ZSTD, JPEG and
  the floating-point predictor need the optional ``imagecodecs`` package, and a file that needs
  it says so.
"""

from __future__ import annotations

import functools
import logging
import math
import os
import re
import struct
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError
from scan2terrain.readers._files import raised_in, regular_file

TAG_PIXEL_SCALE = 33550
TAG_TIEPOINT = 33922
TAG_TRANSFORMATION = 34264
TAG_GEOKEYS = 34735
TAG_GEO_DOUBLES = 34736
TAG_GEO_ASCII = 34737
TAG_GDAL_METADATA = 42112
TAG_GDAL_NODATA = 42113

KEY_MODEL_TYPE = 1024
KEY_RASTER_TYPE = 1025
KEY_CITATION = 1026
KEY_GEOG_CITATION = 2049
KEY_GEOG_ANGULAR_UNITS = 2054
KEY_SEMI_MAJOR = 2057
KEY_SEMI_MINOR = 2058
KEY_INV_FLATTENING = 2059
KEY_PROJECTED_CS = 3072
KEY_PROJ_LINEAR_UNITS = 3076
KEY_VERTICAL_UNITS = 4099

MODEL_PROJECTED = 1
MODEL_GEOGRAPHIC = 2
RASTER_PIXEL_IS_POINT = 2

#: SampleFormat -> (what its samples are, the BitsPerSample a DEM's samples of it may have).
SAMPLE_FORMATS = {
    1: ("unsigned integer", (8, 16, 32, 64)),
    2: ("signed integer", (8, 16, 32, 64)),
    3: ("floating point", (16, 32, 64)),
}
_OTHER_FORMATS = {4: "void", 5: "complex integer", 6: "complex floating point"}
#: Compressions whose strips and tiles decode to bytes, decoded and checked here: LZW, Deflate
#: (both codes), PackBits, LZMA, ZSTD (both codes). Others (JPEG ...) are tifffile's.
BYTE_CODECS = frozenset({5, 8, 32946, 32773, 34925, 34926, 50000})
#: Strips or tiles decoded at a time: their compressed bytes are read together.
_DECODE_BATCH = 64

#: EPSG linear unit codes -> (name, metres per unit).
LINEAR_UNITS = {
    9001: ("metre", 1.0),
    9002: ("foot", 0.3048),
    9003: ("US survey foot", 1200 / 3937),
    9036: ("kilometre", 1000.0),
}
#: EPSG angular unit codes -> (name, radians per unit).
ANGULAR_UNITS = {
    9101: ("radian", 1.0),
    9102: ("degree", math.pi / 180),
    9103: ("arc-minute", math.pi / 180 / 60),
    9104: ("arc-second", math.pi / 180 / 3600),
    9105: ("grad", math.pi / 200),
}


def read_band(path: Path, max_pixels: int) -> tuple[NDArray[Any], dict[int, Any], list[str]]:
    """The samples of a TIFF's first page (one band, at most ``max_pixels``, as stored: row 0 =
    the north edge), its tags by code, and tifffile's log lines as notes. Raises InputError for
    a missing, truncated or corrupt file, a raster that is not one band of numbers, or a
    compression that needs ``imagecodecs`` when it is not installed."""
    import tifffile

    size = regular_file(path, "DEM file")
    log = _TiffLog()
    tifffile_logger = logging.getLogger("tifffile")
    tifffile_logger.addFilter(log)
    try:
        with tifffile.TiffFile(path) as tif:
            if not tif.pages:
                raise InputError(path, "TIFF holds no image")
            page = tif.pages[0]
            raw, tags = _decode_page(path, page, size, max_pixels)
    except tifffile.TiffFileError as exc:
        raise InputError(path, f"not a readable TIFF file ({_one_line(exc)})") from exc
    except (OSError, ValueError, EOFError, struct.error) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(
            path, f"cannot decode the TIFF (truncated or corrupt?): {_one_line(exc)}"
        ) from exc
    except Exception as exc:
        # tifffile and its codecs meet a corrupt file with whatever their code hits (zlib.error,
        # TypeError from a tag of another type, NotImplementedError): a refusal. An exception
        # raised by our own code is a bug, and stays one.
        if not raised_in(exc, ("tifffile", "imagecodecs")):
            raise
        raise InputError(path, f"cannot decode the TIFF (corrupt?): {_described(exc)}") from exc
    finally:
        tifffile_logger.removeFilter(log)
    return raw, tags, log.messages


def _one_line(exc: BaseException, limit: int = 200) -> str:
    text = " ".join(str(exc).split())
    return text if len(text) <= limit else text[:limit] + "..."


def _described(exc: BaseException) -> str:
    """``module.Type: message`` on one line (``zlib.error: Error -3 ...``)."""
    kind = type(exc)
    name = kind.__name__ if kind.__module__ == "builtins" else f"{kind.__module__}.{kind.__name__}"
    text = _one_line(exc)
    return f"{name}: {text}" if text else name


class _TiffLog(logging.Filter):
    """Keeps tifffile's log lines out of stderr (library code never prints) and collects them
    as notes; GDAL_NODATA complaints are dropped, as the tag is parsed here."""

    def __init__(self) -> None:
        super().__init__()
        self.messages: list[str] = []

    def filter(self, record: logging.LogRecord) -> bool:
        text = record.getMessage()
        if "GDAL_NODATA" not in text:
            self.messages.append(f"tifffile: {printable(text.split('> ', 1)[-1])}")
        return False


def printable(text: str) -> str:
    """``text`` with each character that is not printable (controls, a NUL: a flipped byte in
    GeoAsciiParams) as ``?``: notes go into reports and XML comments, which refuse them."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else "?" for c in text)


def _decode_page(
    path: Path, page: Any, file_size: int, max_pixels: int
) -> tuple[NDArray[Any], dict[int, Any]]:
    """Check the page is one band of numbers, inside the file, then decode it."""
    import tifffile

    try:  # a flipped type or count byte in the IFD gives tuples or text where numbers belong
        photometric = int(page.photometric)
        spp = int(page.samplesperpixel)
        bits = int(page.bitspersample)
        sample_format = int(page.sampleformat)
        shape = tuple(int(s) for s in page.shape)
    except (TypeError, ValueError, OverflowError) as exc:
        raise InputError(
            path, f"corrupt TIFF directory: a tag holds values of the wrong type ({exc})"
        ) from exc
    if photometric == tifffile.PHOTOMETRIC.PALETTE:
        raise InputError(path, "a palette (colour-mapped) image, not a DEM: a DEM has one band")
    if spp != 1:
        kind = "RGB" if photometric == tifffile.PHOTOMETRIC.RGB else "bands"
        raise InputError(path, f"{spp} samples per pixel ({kind}): a DEM has one band of heights")
    if photometric not in (tifffile.PHOTOMETRIC.MINISBLACK, tifffile.PHOTOMETRIC.MINISWHITE):
        name = next((p.name for p in tifffile.PHOTOMETRIC if p.value == photometric), photometric)
        raise InputError(
            path, f"photometric interpretation {name} is not a band of heights (a colour image?)"
        )
    if bits == 1:
        raise InputError(path, "BitsPerSample = 1: a black and white image, not a DEM")
    _check_sample_format(path, sample_format, bits)
    if page.dtype is None or np.dtype(page.dtype).kind not in "iuf":
        raise InputError(path, f"samples of type {page.dtype} are not heights")
    try:
        compression = int(page.compression)
    except (TypeError, ValueError, OverflowError) as exc:  # a flipped count: several values
        raise InputError(
            path, f"Compression = {str(page.compression)[:40]} is not one TIFF compression code"
        ) from exc
    if compression not in _compressions():
        raise InputError(path, f"Compression = {compression} is not a TIFF compression")
    if len(shape) != 2:
        raise InputError(path, f"raster of shape {shape} is not a 2D grid")
    rows, cols = shape
    for field, n in (("ImageWidth", cols), ("ImageLength", rows)):
        if n < 2:
            raise InputError(
                path,
                f"{field} = {n}: a DEM needs at least 2 x 2 samples to be a surface",
            )
    if rows * cols > max_pixels:
        raise InputError(
            path,
            f"raster has {cols}x{rows} = {rows * cols} pixels, over the limit of {max_pixels} "
            "(raise it with --max-pixels if the file is trusted)",
        )
    layout = _layout(path, page, file_size, rows=rows, cols=cols, bits=bits)
    tags = {int(t.code): t.value for t in page.tags.values()}
    raw = _decode_segments(path, page, layout) if compression != 1 else None
    if raw is None:
        raw = _asarray(path, page)
    return np.asarray(raw), tags


@functools.cache
def _compressions() -> frozenset[int]:
    """The Compression codes tifffile knows."""
    import tifffile

    return frozenset(int(c) for c in tifffile.COMPRESSION)


def _asarray(path: Path, page: Any) -> NDArray[Any]:
    """tifffile's own decoding, with a compression it needs imagecodecs for named."""
    import tifffile

    try:
        return np.asarray(page.asarray())
    except (KeyError, ImportError, ValueError) as exc:
        if not isinstance(exc, ImportError) and "imagecodecs" not in str(exc):
            raise
        comp = tifffile.COMPRESSION(int(page.compression)).name
        pred = int(page.predictor)
        how = comp + (f" with predictor {tifffile.PREDICTOR(pred).name}" if pred > 1 else "")
        raise InputError(
            path,
            f"{how} data needs the optional package imagecodecs (pip install imagecodecs), "
            f"or rewrite it uncompressed or Deflate (gdal_translate -co COMPRESS=DEFLATE) ({exc})",
        ) from exc


def _check_sample_format(path: Path, sample_format: int, bits: int) -> None:
    """Refuse samples that are not numbers, and a BitsPerSample their SampleFormat does not
    have (float32 samples read as 16 bits are not float16 heights)."""
    if sample_format not in SAMPLE_FORMATS:
        what = _OTHER_FORMATS.get(sample_format, "not a TIFF sample format")
        raise InputError(
            path,
            f"SampleFormat = {sample_format} ({what}): a DEM's samples are numbers, unsigned or "
            "signed integers or floating point (SampleFormat 1, 2 or 3)",
        )
    kind, sizes = SAMPLE_FORMATS[sample_format]
    if bits not in sizes:
        allowed = ", ".join(str(s) for s in sizes[:-1]) + f" or {sizes[-1]}"
        raise InputError(
            path,
            f"BitsPerSample = {bits} does not match SampleFormat = {sample_format} ({kind}): "
            f"such samples are {allowed} bits",
        )


@dataclass(frozen=True)
class _Layout:
    """Where a page's strips or tiles are and what each holds (index i: the i-th segment).

    ``offsets`` and ``counts`` are the file's (int64); ``nbytes`` what the samples of each take
    uncompressed, ``full`` what a whole strip or tile takes (the last strip may be written
    whole); ``sparse`` the segments GDAL leaves out (offset and byte count 0: read as zeros)."""

    what: str  # "strip" or "tile"
    offsets: NDArray[np.int64]
    counts: NDArray[np.int64]
    nbytes: NDArray[np.int64]
    full: int
    sparse: NDArray[np.bool_]
    rows: int
    cols: int
    seg_rows: int  # rows of a whole segment
    seg_cols: int  # columns of a whole segment
    across: int  # segments across the raster
    itemsize: int
    bits: int

    @property
    def offsets_tag(self) -> str:
        return "StripOffsets" if self.what == "strip" else "TileOffsets"

    @property
    def counts_tag(self) -> str:
        return "StripByteCounts" if self.what == "strip" else "TileByteCounts"

    def place(self, i: int) -> tuple[int, int, int, int]:
        """Segment ``i``'s first row and column in the raster, and its rows and columns there."""
        r0 = (i // self.across) * self.seg_rows
        c0 = (i % self.across) * self.seg_cols
        return r0, c0, min(self.seg_rows, self.rows - r0), min(self.seg_cols, self.cols - c0)

    def takes(self, i: int) -> str:
        """What segment ``i``'s samples are, for a message."""
        _, _, h, w = self.place(i)
        if self.what == "tile":
            h, w = self.seg_rows, self.seg_cols
        return f"{h} rows of {w} samples of {self.bits} bits take {int(self.nbytes[i])} bytes"


def _layout(path: Path, page: Any, file_size: int, *, rows: int, cols: int, bits: int) -> _Layout:
    """The page's strips or tiles, refused unless there are as many as the raster needs, each
    inside the file, clear of the header, the directory and the tags' values (a strip offset
    of 0 read the header as samples), and, uncompressed, exactly as long as its samples."""
    tiled = bool(page.is_tiled)
    try:
        if tiled:
            seg_rows, seg_cols = int(page.tilelength), int(page.tilewidth)
        else:
            seg_rows, seg_cols = min(int(page.rowsperstrip), rows), cols
        offsets = np.array([int(v) for v in page.dataoffsets], dtype=np.float64)
        counts = np.array([int(v) for v in page.databytecounts], dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as exc:
        raise InputError(path, f"corrupt TIFF directory: strip or tile offsets ({exc})") from exc
    what = "tile" if tiled else "strip"
    if seg_rows < 1 or seg_cols < 1:
        field = "TileLength/TileWidth" if tiled else "RowsPerStrip"
        raise InputError(path, f"{field} = {seg_rows if seg_rows < 1 else seg_cols}: no {what}s")
    down, across = -(-rows // seg_rows), -(-cols // seg_cols)
    if not len(offsets):
        raise InputError(path, "no pixel data: its strip or tile offsets are missing or corrupt")
    tags = ("TileOffsets", "TileByteCounts") if tiled else ("StripOffsets", "StripByteCounts")
    for tag, values in zip(tags, (offsets, counts), strict=True):
        if len(values) != down * across:
            raise InputError(
                path,
                f"{tag} holds {len(values)} values, but {rows} x {cols} samples in {what}s of "
                f"{seg_rows} x {seg_cols} need {down * across}",
            )
    # float64: offsets and counts up to 2^64 - 1 (BigTIFF) compare without overflow; any above
    # 2^53 is beyond the file anyway.
    ends = offsets + counts
    if ends.max() > file_size:
        raise InputError(
            path,
            f"truncated: pixel data ends at byte {int(ends.max())} but the file has {file_size} "
            "bytes",
        )
    itemsize = bits // 8
    full = seg_rows * seg_cols * itemsize
    if tiled:
        nbytes = np.full(len(offsets), full, dtype=np.int64)
    else:
        nbytes = np.minimum(seg_rows, rows - np.arange(down) * seg_rows) * cols * itemsize
    layout = _Layout(
        what=what,
        offsets=offsets.astype(np.int64),
        counts=counts.astype(np.int64),
        nbytes=nbytes.astype(np.int64),
        full=full,
        sparse=(offsets == 0) & (counts == 0),
        rows=rows,
        cols=cols,
        seg_rows=seg_rows,
        seg_cols=seg_cols,
        across=across,
        itemsize=itemsize,
        bits=bits,
    )
    _check_clear_of_headers(path, page, layout)
    if int(page.compression) == 1:
        last = np.arange(len(nbytes)) == len(nbytes) - 1
        wrong = (layout.counts != layout.nbytes) & ~(last & (layout.counts == full))
        wrong &= ~layout.sparse
        if wrong.any():
            i = int(np.argmax(wrong))
            raise InputError(
                path,
                f"{layout.counts_tag}[{i}] = {int(layout.counts[i])} bytes, but its "
                f"{layout.takes(i)} uncompressed (BitsPerSample or the byte counts changed?)",
            )
    return layout


def _check_clear_of_headers(path: Path, page: Any, layout: _Layout) -> None:
    """Refuse a strip or tile overlapping the TIFF header, the page's directory or a tag's
    values stored outside it."""
    tiff = page.parent.tiff
    fh = page.parent.filehandle
    fh.seek(page.offset)
    (entries,) = struct.unpack(tiff.tagnoformat, fh.read(tiff.tagnosize))
    regions = [
        (0, 16 if tiff.is_bigtiff else 8, "the TIFF header"),
        (
            page.offset,
            page.offset + tiff.tagnosize + entries * tiff.tagsize + tiff.offsetsize,
            "the image file directory",
        ),
    ]
    for t in page.tags.values():
        if t.valuebytecount > tiff.tagoffsetthreshold:
            end = t.valueoffset + t.valuebytecount
            regions.append((t.valueoffset, end, f"the values of tag {t.code} ({t.name})"))
    starts, ends = layout.offsets, layout.offsets + layout.counts
    bounds = np.array([(lo, hi) for lo, hi, _ in regions], dtype=np.int64)
    hit = (starts < bounds[:, 1:]) & (ends > bounds[:, :1]) & ~layout.sparse  # (region, segment)
    if hit.any():
        r, i = (int(v) for v in np.unravel_index(int(np.argmax(hit)), hit.shape))
        lo, hi, what = regions[r]
        raise InputError(
            path,
            f"{layout.offsets_tag}[{i}] = {int(starts[i])}: its {int(layout.counts[i])} bytes "
            f"(to {int(ends[i])}) overlap {what} (bytes {lo}..{hi}): a corrupt offset or count",
        )


def _decode_segments(path: Path, page: Any, layout: _Layout) -> NDArray[Any] | None:
    """The raster of a page whose strips or tiles are compressed to bytes (:data:`BYTE_CODECS`),
    each checked to decode to exactly its samples' bytes (tifffile silently cuts longer data:
    raw samples read as PackBits made heights of 1e38), on as many threads as tifffile would
    use. None when tifffile must decode it (another compression, a bit order, or a codec or
    predictor that needs imagecodecs: tifffile says so)."""
    import tifffile

    compression = int(page.compression)
    if compression not in BYTE_CODECS or int(page.fillorder) != 1:
        return None
    try:
        decompress = tifffile.TIFF.DECOMPRESSORS[compression]
        predictor = int(page.predictor)
        unpredict = None if predictor == 1 else tifffile.TIFF.UNPREDICTORS[predictor]
    except KeyError:
        return None
    stored = np.dtype(page.dtype).newbyteorder(page.parent.byteorder)
    out = np.zeros((layout.rows, layout.cols), dtype=stored.newbyteorder("="))
    name = next((c.name for c in tifffile.COMPRESSION if c.value == compression), "?")

    def decode(item: tuple[bytes | None, int]) -> None:
        data, i = item
        if data is None:
            if layout.sparse[i]:  # zeros, as tifffile reads it
                return
            data = b""  # a byte count of 0 at an offset
        decoded = decompress(data)
        r0, c0, h, w = layout.place(i)
        if layout.what == "tile":
            want = layout.seg_rows * layout.seg_cols
            seg_h = layout.seg_rows
        else:
            want = h * layout.cols
            seg_h = h
        if len(decoded) not in (want * layout.itemsize, layout.full):
            raise InputError(
                path,
                f"Compression = {compression} ({name}): {layout.what} {i} decodes to "
                f"{len(decoded)} bytes, but its {layout.takes(i)} (corrupt data, or a "
                "Compression tag changed?)",
            )
        samples = np.frombuffer(decoded, stored, count=want).reshape(1, seg_h, -1, 1)
        samples = samples.astype(out.dtype)
        if unpredict is not None:
            samples = unpredict(samples, axis=-2, out=samples)
        out[r0 : r0 + h, c0 : c0 + w] = samples[0, :h, :w, 0]

    fh = page.parent.filehandle
    workers = max(1, min(int(page.maxworkers or 1), os.cpu_count() or 1))
    segments = fh.read_segments(
        [int(v) for v in layout.offsets], [int(v) for v in layout.counts], flat=True
    )
    if workers == 1:
        for item in segments:
            decode(item)
        return out
    with ThreadPoolExecutor(workers) as pool:
        for batch in _batches(segments, _DECODE_BATCH):
            list(pool.map(decode, batch))
    return out


def _batches(items: Iterator[Any], n: int) -> Iterator[list[Any]]:
    batch: list[Any] = []
    for item in items:
        batch.append(item)
        if len(batch) == n:
            yield batch
            batch = []
    if batch:
        yield batch


def incomplete_georeference(tags: dict[int, Any], keys: dict[int, int | float | str]) -> str | None:
    """Why the georeference cannot say what a pixel measures, or None: complete, or absent
    (a TIFF without any georeference tag). Degrees read as metres made a terrain 3.6 cm wide,
    so a pixel scale counts only with GeoKeys that say projected or geographic."""
    scale, ties = TAG_PIXEL_SCALE in tags, TAG_TIEPOINT in tags
    matrix = TAG_TRANSFORMATION in tags
    if not (scale or ties or matrix):
        return None
    if not matrix and scale != ties:
        return "only one of the ModelPixelScale and ModelTiepoint tags"
    what = "ModelTransformation" if matrix else "ModelPixelScale and ModelTiepoint"
    if TAG_GEOKEYS not in tags:
        return f"{what} but no GeoKeyDirectory"
    if keys.get(KEY_MODEL_TYPE) not in (MODEL_PROJECTED, MODEL_GEOGRAPHIC):
        return "GeoKeys without a projected or geographic model type"
    return None


def _numbers(path: Path, tags: dict[int, Any], code: int, name: str) -> NDArray[np.float64]:
    """A tag's values as float64 (1-D), refusing text or other types where numbers belong (a
    corrupt TIFF directory: its type byte flipped)."""
    value = tags.get(code, ())
    try:
        arr = np.atleast_1d(np.asarray(value))
        if arr.dtype.kind not in "iuf":
            raise TypeError
        return arr.astype(np.float64).ravel()
    except (TypeError, ValueError):
        raise InputError(
            path, f"{name} holds {type(value).__name__} values, not numbers (corrupt TIFF tag?)"
        ) from None


def read_geokeys(path: Path, tags: dict[int, Any]) -> dict[int, int | float | str]:
    """GeoKeyDirectoryTag -> {key id: value} (values from the SHORT, DOUBLE or ASCII tags)."""
    directory = tags.get(TAG_GEOKEYS)
    if directory is None:
        return {}
    values = _numbers(path, tags, TAG_GEOKEYS, "GeoKeyDirectory")
    if not (np.all(values == np.floor(values)) and np.all(np.abs(values) < 1 << 32)):
        raise InputError(path, "GeoKeyDirectory holds values that are not integers")
    d = [int(v) for v in values]
    if len(d) < 4 or len(d) < 4 + 4 * d[3]:
        raise InputError(path, "GeoKeyDirectoryTag is shorter than its key count says")
    doubles = _numbers(path, tags, TAG_GEO_DOUBLES, "GeoDoubleParams")
    ascii_params = tags.get(TAG_GEO_ASCII, "")
    if isinstance(ascii_params, bytes):
        ascii_params = ascii_params.decode("latin-1")
    ascii_params = printable(str(ascii_params))
    keys: dict[int, int | float | str] = {}
    for i in range(d[3]):
        key, location, count, value = d[4 + 4 * i : 8 + 4 * i]
        if location == 0:
            keys[key] = value
        elif location == TAG_GEO_DOUBLES and value + count <= len(doubles):
            keys[key] = float(doubles[value])
        elif location == TAG_GEO_ASCII:
            keys[key] = str(ascii_params)[value : value + count]
    return keys


def gdal_nodata(path: Path, tags: dict[int, Any]) -> float | None:
    """The ``GDAL_NODATA`` tag's number, or None when the tag is absent."""
    text = tags.get(TAG_GDAL_NODATA)
    if text is None:
        return None
    if isinstance(text, bytes):
        text = text.decode("latin-1")
    try:
        return float(str(text).strip().strip("\x00").replace(",", "."))
    except ValueError:
        raise InputError(path, f"GDAL_NODATA tag {text!r} is not a number") from None


def gdal_scale_offset(tags: dict[int, Any]) -> tuple[float, float]:
    """GDAL's per-band scale and offset from the GDAL_METADATA XML (1 and 0 when absent)."""
    xml = tags.get(TAG_GDAL_METADATA)
    if not isinstance(xml, str):
        return 1.0, 0.0

    def item(role: str, default: float) -> float:
        m = re.search(rf'<Item[^>]*role="{role}"[^>]*>\s*([^<]+?)\s*</Item>', xml)
        try:
            return float(m.group(1)) if m else default
        except ValueError:
            return default

    return item("scale", 1.0), item("offset", 0.0)


def geotransform(
    path: Path, tags: dict[int, Any], keys: dict[int, int | float | str]
) -> tuple[float, float, float, float, float, float] | None:
    """GDAL's geotransform (x0, dx, rx, y0, ry, dy) of the raster's corner, or None."""
    matrix = tags.get(TAG_TRANSFORMATION)
    scale = tags.get(TAG_PIXEL_SCALE)
    ties = tags.get(TAG_TIEPOINT)
    if matrix is not None:
        m = _numbers(path, tags, TAG_TRANSFORMATION, "ModelTransformation")
        if m.size != 16:
            raise InputError(path, f"ModelTransformationTag has {m.size} values, not 16")
        gt = (m[3], m[0], m[1], m[7], m[4], m[5])
    elif scale is not None and ties is not None:
        s = _numbers(path, tags, TAG_PIXEL_SCALE, "ModelPixelScale")
        t = _numbers(path, tags, TAG_TIEPOINT, "ModelTiepoint")
        if s.size < 2 or t.size < 6:
            raise InputError(path, "ModelPixelScale/ModelTiepoint tags are too short")
        for name, values in (("ModelPixelScale", s[:3]), ("ModelTiepoint", t[:6])):
            if not np.isfinite(values).all():
                shown = ", ".join(f"{v:.6g}" for v in values)
                raise InputError(path, f"{name} = ({shown}) holds a non-finite number")
        if t.size > 6:
            raise InputError(
                path,
                f"{t.size // 6} tie points (ground control points) are not supported: warp the "
                "DEM onto a regular grid first (gdalwarp)",
            )
        i, j, _, x, y, _ = t[:6]
        gt = (x - i * s[0], s[0], 0.0, y + j * s[1], 0.0, -s[1])
    elif scale is not None or ties is not None:
        raise InputError(path, "has only one of the ModelPixelScale and ModelTiepoint tags")
    else:
        return None
    x0, dx, rx, y0, ry, dy = (float(v) for v in gt)
    if not all(math.isfinite(v) for v in (x0, dx, rx, y0, ry, dy)):
        raise InputError(path, "georeference holds a non-finite number")
    if rx != 0.0 or ry != 0.0:
        raise InputError(
            path,
            "rotated or sheared raster (ModelTransformationTag) is not supported: warp it "
            "north-up first (gdalwarp)",
        )
    if dx == 0.0 or dy == 0.0:
        raise InputError(path, f"pixel size ({abs(dx)}, {abs(dy)}) must not be zero")
    if keys.get(KEY_RASTER_TYPE) == RASTER_PIXEL_IS_POINT:
        # The tie point names a pixel's centre: GDAL moves the corner half a pixel out.
        x0 -= dx / 2
        y0 -= dy / 2
    return (x0, dx, rx, y0, ry, dy)


def linear_unit(
    path: Path, keys: dict[int, int | float | str], notes: list[str]
) -> tuple[str, float]:
    """A projected CRS's linear unit: (name, metres per unit); metres when unstated (noted
    when the CRS is named)."""
    code = keys.get(KEY_PROJ_LINEAR_UNITS)
    if code is None:
        if KEY_PROJECTED_CS in keys and keys[KEY_PROJECTED_CS] != 32767:
            notes.append(f"CRS EPSG:{keys[KEY_PROJECTED_CS]} states no linear unit: metres assumed")
        return LINEAR_UNITS[9001]
    if code not in LINEAR_UNITS:
        raise InputError(
            path,
            f"linear unit EPSG:{code} is not supported (metre, foot, US survey foot, kilometre)",
        )
    return LINEAR_UNITS[int(code)]


def angular_unit(path: Path, keys: dict[int, int | float | str]) -> tuple[str, float]:
    """A geographic CRS's angular unit: (name, radians per unit); degrees when unstated."""
    code = keys.get(KEY_GEOG_ANGULAR_UNITS, 9102)
    if code not in ANGULAR_UNITS:
        raise InputError(path, f"angular unit EPSG:{code} is not supported")
    return ANGULAR_UNITS[int(code)]
