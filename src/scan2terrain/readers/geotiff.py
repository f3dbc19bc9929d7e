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
* Before decoding, only a regular file is opened, and its strips or tiles must lie inside it;
  whatever tifffile or imagecodecs raise on a corrupt file (``zlib.error``, a ``TypeError`` from
  a tag of another type, ``NotImplementedError``) is an :class:`InputError`.
* Samples: one band of any integer or floating-point type (int16, uint16, int32, float32,
  float64 ...). Colour, palette and multi-band TIFFs are refused. Uncompressed, Deflate and LZMA
  data decode with tifffile alone; LZW, PackBits, ZSTD, JPEG and the predictors need the optional
  ``imagecodecs`` package, and a file that needs it says so.
"""

from __future__ import annotations

import logging
import math
import re
import struct
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
            self.messages.append(f"tifffile: {text.split('> ', 1)[-1]}")
        return False


def _decode_page(
    path: Path, page: Any, file_size: int, max_pixels: int
) -> tuple[NDArray[Any], dict[int, Any]]:
    """Check the page is one band of numbers, inside the file, then decode it."""
    import tifffile

    try:  # a flipped type or count byte in the IFD gives tuples or text where numbers belong
        photometric = int(page.photometric)
        spp = int(page.samplesperpixel)
        bits = int(page.bitspersample)
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
    if page.dtype is None or np.dtype(page.dtype).kind not in "iuf":
        raise InputError(path, f"samples of type {page.dtype} are not heights")
    if bits == 1:
        raise InputError(path, "a 1-bit (black and white) image, not a DEM")
    if len(shape) != 2 or min(shape) < 1:
        raise InputError(path, f"raster of shape {shape} is not a 2D grid")
    rows, cols = shape
    if rows * cols > max_pixels:
        raise InputError(
            path,
            f"raster has {cols}x{rows} = {rows * cols} pixels, over the limit of {max_pixels} "
            "(raise it with --max-pixels if the file is trusted)",
        )
    try:
        ends = [
            int(o) + int(n) for o, n in zip(page.dataoffsets, page.databytecounts, strict=False)
        ]
    except (TypeError, ValueError, OverflowError) as exc:
        raise InputError(path, f"corrupt TIFF directory: strip or tile offsets ({exc})") from exc
    if not ends:
        raise InputError(path, "no pixel data: its strip or tile offsets are missing or corrupt")
    if max(ends) > file_size:
        raise InputError(
            path,
            f"truncated: pixel data ends at byte {max(ends)} but the file has {file_size} bytes",
        )
    tags = {int(t.code): t.value for t in page.tags.values()}
    try:
        raw = page.asarray()
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
    return np.asarray(raw), tags


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
