"""Digital elevation models: single-band GeoTIFF files in, heights in metres out.

A pure-Python reader (``tifffile``; no GDAL). What is read, as GDAL reads it:

* Georeference: ``ModelPixelScaleTag`` (33550) + one ``ModelTiepointTag`` (33922), or an
  axis-aligned ``ModelTransformationTag`` (34264); ``RasterPixelIsPoint`` (GeoKey 1025) moves the
  raster half a pixel as GDAL does. Rotated or sheared rasters and ground control points are
  refused (``gdalwarp`` them first).
* CRS from the ``GeoKeyDirectoryTag`` (34735): ``GTModelTypeGeoKey`` 1 = projected (linear units
  from ``ProjLinearUnitsGeoKey``: metre, foot, US survey foot, kilometre), 2 = geographic (angular
  units from ``GeogAngularUnitsGeoKey``, degrees by default). Heights are metres unless
  ``VerticalUnitsGeoKey`` says feet; GDAL's per-band scale and offset (``GDAL_METADATA``) apply.
  A pixel scale without GeoKeys that say projected or geographic is an incomplete georeference
  (metres or degrees? degree pixels read as metres made a terrain 3.6 cm wide): like a TIFF
  without georeference, it is read only with a pixel size given in metres (``--resolution``).
* Before decoding, only a regular file is opened, and its strips or tiles must lie inside it;
  whatever tifffile or imagecodecs raise on a corrupt file (``zlib.error``, a ``TypeError`` from
  a tag of another type, ``NotImplementedError``) is an :class:`InputError`.
* ``GDAL_NODATA`` (42113, ASCII) and non-finite samples are nodata: they take the lowest valid
  height (what gz-common's ``Dem::FillHeightMap`` does with them). A DEM of nothing but nodata is
  refused. Negative heights are kept (bathymetry, the Moon).
* Samples: one band of any integer or floating-point type (int16, uint16, int32, float32,
  float64 ...). Colour, palette and multi-band TIFFs are refused. Uncompressed, Deflate and LZMA
  data decode with tifffile alone; LZW, PackBits, ZSTD, JPEG and the predictors need the optional
  ``imagecodecs`` package, and a file that needs it says so.

Geographic DEMs are converted to metres on a sphere, as gz-common does (gz-math
``SphericalCoordinates::Distance``, the haversine formula with the Earth's mean radius
6 371 000 m; a body with another ellipsoid in the GeoKeys, such as the Moon, uses its own mean
radius ``(2 a + b) / 3``). gz-common measures the width along the DEM's *north* edge; we measure
it along the *centre* parallel, the best single value for the whole DEM (for the bundled
San Francisco DEM the two differ by 0.024 %). The metric frame of a geographic DEM is the
equirectangular projection at the centre latitude: ``x = R cos(lat_c) lon``, ``y = R lat``
(radians). Like gz-common's, it treats the DEM as a rectangle: the east-west scale at a latitude
``dlat`` (radians) north or south of the centre is off by about ``tan(lat_c) dlat`` (0.1 % at
8 km from the centre at 38 degrees). Reproject large DEMs to UTM first
(``gdalwarp -t_srs EPSG:326zz``).

Frames: :class:`Dem` arrays are in grid order (row 0 = the *south* edge, as
:class:`~scan2terrain.types.HeightGrid`); GeoTIFF row 0 is the north edge, flipped here.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import re
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError
from scan2terrain.readers._files import raised_in, regular_file
from scan2terrain.types import HeightGrid, Pose2D

#: gz-math's Earth radius for ``SphericalCoordinates::Distance`` (metres).
EARTH_RADIUS = 6_371_000.0
#: WGS84 semi-major axis (metres): an ellipsoid within 1 % of it is the Earth.
_EARTH_A = 6_378_137.0

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

CrsKind = Literal["projected", "geographic", "local"]

#: Pixel sizes closer than this (relative) count as square: no resampling.
SQUARE_TOLERANCE = 1e-6
#: Made square at the default resolution, a DEM may have at most this many times its own
#: pixels. Geographic pixels are 1 / cos(latitude) times taller than wide, and the 2^n+1 image
#: rounds up: a 1-degree tile at 80 degrees north takes about 14 times its pixels, at 86 degrees
#: up to 52. A tie point moved to 89.99 degrees made 8,097 times (a 129 x 129 DEM resampled to
#: 257 x 524,289, a grid 2 cm wide and 4 km long).
MAX_UPSAMPLE = 64
#: Output cells resampled at a time (:meth:`Dem.to_height_grid`), so that the float64
#: interpolation's temporaries stay small whatever the grid's size.
_RESAMPLE_BLOCK = 1 << 22


@dataclass(frozen=True)
class Dem:
    """A DEM in grid order, with its georeference.

    Attributes
    ----------
    heights : float32 array (H, W)
        Ground elevation in metres, row 0 = the south edge, column 0 = the west edge. Nodata
        cells hold the lowest valid height.
    valid : bool array (H, W)
        False where the file held nodata (``GDAL_NODATA`` or a non-finite sample).
    pixel_size : (float, float)
        Pixel width (east) and height (north) in metres.
    pixel_size_crs : (float, float)
        The same in the CRS's own units (degrees for a geographic DEM).
    origin : (float, float)
        Lower-left (south-west) corner of the raster, edge not pixel centre, in CRS units: easting
        and northing (projected), longitude and latitude (geographic), or metres (local).
    origin_m : (float, float)
        The same corner in metres: projected CRS units times the unit; for a geographic DEM the
        equirectangular projection at the centre latitude (``R cos(lat_c) lon``, ``R lat``).
    crs : "projected" | "geographic" | "local"
        ``local``: a TIFF with no georeference, given a pixel size by the caller.
    units : str
        Name of the CRS unit ("metre", "degree", ...).
    radius : float or None
        Sphere radius in metres used for a geographic DEM, else None.
    nodata : float or None
        The ``GDAL_NODATA`` value, as written in the file.
    citation : str
        The CRS's citation GeoKeys ("" when absent), for reports.
    notes : tuple of str
        Assumptions made while reading (for the command's report).
    """

    heights: NDArray[np.float32]
    valid: NDArray[np.bool_]
    pixel_size: tuple[float, float]
    pixel_size_crs: tuple[float, float]
    origin: tuple[float, float]
    origin_m: tuple[float, float]
    crs: CrsKind
    units: str
    radius: float | None = None
    nodata: float | None = None
    citation: str = ""
    notes: tuple[str, ...] = field(default_factory=tuple)

    @property
    def shape(self) -> tuple[int, int]:
        """Rows and columns."""
        return (int(self.heights.shape[0]), int(self.heights.shape[1]))

    @property
    def extent(self) -> tuple[float, float]:
        """Width (east) and height (north) of the raster in metres, edge to edge."""
        rows, cols = self.shape
        return (cols * self.pixel_size[0], rows * self.pixel_size[1])

    @property
    def centre(self) -> tuple[float, float]:
        """The raster's centre in CRS units (easting/northing, or longitude/latitude)."""
        rows, cols = self.shape
        return (
            self.origin[0] + cols * self.pixel_size_crs[0] / 2,
            self.origin[1] + rows * self.pixel_size_crs[1] / 2,
        )

    @property
    def z_min(self) -> float:
        """Lowest valid height, metres."""
        return float(self.heights[self.valid].min())

    @property
    def z_max(self) -> float:
        """Highest valid height, metres."""
        return float(self.heights[self.valid].max())

    @property
    def square(self) -> bool:
        """Whether the pixels are square in metres (projected DEMs, usually)."""
        return _close(*self.pixel_size)

    def default_resolution(self) -> float:
        """The cell side :meth:`to_height_grid` uses by default, metres.

        Square pixels: the DEM's own (no resampling at all). Otherwise (geographic DEMs) the
        finest square cell that fits the same 2^n+1 heightmap as the finer of the two pixel
        sizes would: the longer side then spans exactly 2^n+1 samples, the image is filled
        rather than padded, and the re-interpolation error (about ``r / 4`` times a change of
        slope, at the DEM's own samples) is as small as that image allows.
        """
        px, py = self.pixel_size
        if self.square:
            return px
        rows, cols = self.shape
        finer = min(px, py)
        side = _side(max(_samples(cols, px, finer), _samples(rows, py, finer)))
        return max((cols - 1) * px, (rows - 1) * py) / (side - 1)

    def to_height_grid(self, resolution: float | None = None) -> HeightGrid:
        """The DEM as a height grid with square cells, its centre at (0, 0).

        Parameters
        ----------
        resolution : float, optional
            Cell side in metres; default :meth:`default_resolution`.

        Returns
        -------
        HeightGrid
            Heights in metres, ``known`` = valid (nearest sample), origin = lower-left corner
            relative to the DEM's centre (metres, x east, y north). When no resampling is needed
            the DEM's own samples are returned unchanged. Otherwise each axis is resampled
            linearly (bilinear overall) onto a lattice centred on the DEM that reaches its
            outermost sample centres, extrapolating linearly by at most half a pixel at the edges
            and clipping to the DEM's height range, so the four corner samples, and every sample
            of an axis that was not resampled, keep their exact heights.
        """
        px, py = self.pixel_size
        r = self.default_resolution() if resolution is None else float(resolution)
        if not (r > 0 and math.isfinite(r)):
            raise ValueError(f"resolution must be a positive number of metres, got {resolution}")
        rows, cols = self.shape
        if _close(px, r) and _close(py, r):
            return HeightGrid(
                self.heights, self.valid, r, Pose2D(-cols * px / 2, -rows * py / 2, 0.0)
            )
        nx = _samples(cols, px, r)
        ny = _samples(rows, py, r)
        # Lattice positions in DEM sample-index units (sample k has its centre at k).
        tx = (np.arange(nx, dtype=np.float64) - (nx - 1) / 2) * (r / px) + (cols - 1) / 2
        ty = (np.arange(ny, dtype=np.float64) - (ny - 1) / 2) * (r / py) + (rows - 1) / 2
        across = _linear(self.heights, tx, axis=1)
        # Row blocks: the float64 temporaries of the interpolation (five arrays) would be 40
        # bytes a cell of the whole grid at once, for a float32 result of 4.
        heights = np.empty((ny, nx), dtype=np.float32)
        step = max(1, _RESAMPLE_BLOCK // nx)
        for a in range(0, ny, step):  # a few blocks of rows, not a loop over cells
            block = _linear(across, ty[a : a + step], axis=0)
            heights[a : a + step] = np.clip(block, self.z_min, self.z_max, out=block)
        ix = np.clip(np.rint(tx), 0, cols - 1).astype(np.intp)
        iy = np.clip(np.rint(ty), 0, rows - 1).astype(np.intp)
        known = self.valid[np.ix_(iy, ix)]
        return HeightGrid(heights, known, r, Pose2D(-nx * r / 2, -ny * r / 2, 0.0))


def _close(a: float, b: float) -> bool:
    return abs(a - b) <= SQUARE_TOLERANCE * max(abs(a), abs(b))


def _side(n: int) -> int:
    """The smallest 2^k + 1 >= n (k >= 1): a Gazebo heightmap side."""
    return (1 << max(1, math.ceil(math.log2(max(n, 2) - 1)))) + 1


def _samples(n: int, pixel: float, r: float) -> int:
    """Samples at spacing ``r`` that reach the outermost of ``n`` samples ``pixel`` apart."""
    if n == 1:
        return 1
    return max(2, math.ceil((n - 1) * pixel / r - 1e-9) + 1)


def _linear(
    a: NDArray[np.floating[Any]], t: NDArray[np.float64], *, axis: int
) -> NDArray[np.float64]:
    """Linear interpolation of ``a`` along ``axis`` at fractional sample positions ``t``,
    extrapolating linearly by at most half a sample beyond either end."""
    n = a.shape[axis]
    if n == 1:
        return np.repeat(a.astype(np.float64), len(t), axis=axis)
    t = np.clip(t, -0.5, n - 0.5)
    i0 = np.clip(np.floor(t).astype(np.intp), 0, n - 2)
    f = t - i0
    lo = np.take(a, i0, axis=axis).astype(np.float64)
    hi = np.take(a, i0 + 1, axis=axis).astype(np.float64)
    shape = [1, 1]
    shape[axis] = len(t)
    w = f.reshape(shape)
    out: NDArray[np.float64] = lo + (hi - lo) * w
    return out


# --- reading ---------------------------------------------------------------------------------


def read_dem(
    path: Path | str, *, pixel_size: float | None = None, max_pixels: int = 1 << 28
) -> Dem:
    """Read a single-band GeoTIFF DEM.

    Parameters
    ----------
    path : Path
        The TIFF file.
    pixel_size : float, optional
        Metres per pixel for a TIFF without georeference (then read as a local DEM, x east =
        columns, y north = rows). Ignored when the file is georeferenced.
    max_pixels : int
        Refuse rasters with more pixels than this, before decoding.

    Returns
    -------
    Dem

    Raises
    ------
    InputError
        Missing, truncated or corrupt file; not a single-band raster; no georeference (and no
        ``pixel_size``); an unsupported georeference; every pixel nodata; a compression that
        needs ``imagecodecs`` when it is not installed.
    """
    import tifffile

    path = Path(path)
    size = regular_file(path, "DEM file")
    log = _TiffLog()
    tifffile_logger = logging.getLogger("tifffile")
    tifffile_logger.addFilter(log)
    try:
        with tifffile.TiffFile(path) as tif:
            if not tif.pages:
                raise InputError(path, "TIFF holds no image")
            page = tif.pages[0]
            raw, tags = _decode(path, page, size, max_pixels)
    except tifffile.TiffFileError as exc:
        raise InputError(path, f"not a readable TIFF file ({_one_line(exc)})") from None
    except (OSError, ValueError, EOFError, struct.error) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(
            path, f"cannot decode the TIFF (truncated or corrupt?): {_one_line(exc)}"
        ) from None
    except Exception as exc:
        # tifffile and its codecs meet a corrupt file with whatever their code hits (zlib.error,
        # TypeError from a tag of another type, NotImplementedError): a refusal. An exception
        # raised by our own code is a bug, and stays one.
        if not raised_in(exc, ("tifffile", "imagecodecs")):
            raise
        raise InputError(path, f"cannot decode the TIFF (corrupt?): {_described(exc)}") from None
    finally:
        tifffile_logger.removeFilter(log)
    dem = _to_dem(path, raw, tags, pixel_size)
    if pixel_size is None and not dem.square:
        _check_resampled_size(path, dem, max_pixels)
    if log.messages:
        dem = dataclasses.replace(dem, notes=(*dem.notes, *log.messages))
    return dem


def _check_resampled_size(path: Path, dem: Dem, max_pixels: int) -> None:
    """Refuse a DEM whose pixels, made square at its default resolution, would be more than
    ``max_pixels``, or more than :data:`MAX_UPSAMPLE` times its own: non-square pixels of very
    different sides (a corrupt pixel scale of 1e300 made a 1e303-pixel grid, a tie point moved
    to a pole 8,097 times the DEM's pixels) are the file's fault, so the file is named. Checked
    before anything of that size is allocated."""
    px, py = dem.pixel_size
    w, h = dem.extent
    if not all(math.isfinite(v) and v > 0 for v in (px, py, w, h)):
        raise InputError(path, f"pixel size {px} x {py} m is not a finite number of metres")
    rows, cols = dem.shape
    limit = min(max_pixels, MAX_UPSAMPLE * rows * cols)
    finer = min(px, py)
    # The default resolution lies between half the finer pixel side and that side: counts at
    # half of it bound the grid from above without rounding huge numbers up to integers.
    if (2 * w / finer + 2) * (2 * h / finer + 2) <= limit:
        return
    if w / finer * (h / finer) > 1e15:  # refused whatever the rounding
        r, nx, ny = finer, w / finer, h / finer
    else:
        r = dem.default_resolution()
        nx, ny = _samples(cols, px, r), _samples(rows, py, r)
    if nx * ny <= limit:
        return
    made = (
        f"its {px:.3g} x {py:.3g} m pixels, made square ({r:.3g} m), would be {_count(nx)} x "
        f"{_count(ny)} pixels"
    )
    if nx * ny > max_pixels:
        raise InputError(
            path,
            f"{made}, over the limit of {max_pixels} pixels (--max-pixels; a corrupt pixel "
            "scale?): give a coarser --resolution, or raise --max-pixels if the file is trusted",
        )
    raise InputError(
        path,
        f"{made}, {_count(nx * ny / (rows * cols))} times its own {cols} x {rows}, more than "
        f"{MAX_UPSAMPLE} (a corrupt georeference, or a DEM at a pole?): choose the pixel size "
        f"with --resolution (its pixels' longer side is {max(px, py):.3g} m)",
    )


def _count(v: float) -> str:
    """A pixel count for a message: with thousands separators, or in powers of ten when huge."""
    return f"{round(v):,}" if v < 1e15 else f"{v:.3g}"


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


def _decode(
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
        ) from None
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
        raise InputError(path, f"corrupt TIFF directory: strip or tile offsets ({exc})") from None
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
        ) from None
    return np.asarray(raw), tags


def _to_dem(path: Path, raw: NDArray[Any], tags: dict[int, Any], pixel_size: float | None) -> Dem:
    notes: list[str] = []
    keys = _geokeys(path, tags)
    data = raw.astype(np.float64)
    valid = np.isfinite(data)
    nodata = _nodata(path, tags)
    if nodata is not None and math.isfinite(nodata):
        marker = _as_sample(nodata, raw.dtype)
        if marker is not None:
            valid &= data != marker
    if not valid.any():
        what = f"GDAL_NODATA {tags[TAG_GDAL_NODATA]!r}" if nodata is not None else "non-finite"
        raise InputError(path, f"every pixel is nodata ({what}): no heights to make terrain of")

    scale, offset = _gdal_scale_offset(tags)
    vertical = keys.get(KEY_VERTICAL_UNITS)
    v_factor = 1.0
    if isinstance(vertical, int) and vertical in LINEAR_UNITS and vertical != 9001:
        name, v_factor = LINEAR_UNITS[vertical]
        notes.append(f"heights converted from {name} to metres")
    data = (data * scale + offset) * v_factor

    incomplete = _incomplete(tags, keys)
    gt = None if incomplete else _geotransform(path, tags, keys)
    if gt is None:
        if pixel_size is None and incomplete:
            raise InputError(
                path,
                f"its georeference is incomplete ({incomplete}: metres or degrees?), so its pixel "
                "size is unknown: give it in metres with --resolution",
            )
        if pixel_size is None:
            raise InputError(
                path,
                "a TIFF without georeference (no ModelPixelScale/ModelTiepoint or "
                "ModelTransformation tag): give its pixel size in metres with --resolution",
            )
        if not (pixel_size > 0 and math.isfinite(pixel_size)):
            raise InputError(path, f"pixel size must be > 0 metres, got {pixel_size}")
        rows, cols = data.shape
        gt = (0.0, float(pixel_size), 0.0, rows * float(pixel_size), 0.0, -float(pixel_size))
        what = f"incomplete georeference ({incomplete})" if incomplete else "no georeference"
        notes.append(f"{what}: {pixel_size:g} m pixels, centred on the world origin")
        crs: CrsKind = "local"
    else:
        crs = "geographic" if keys[KEY_MODEL_TYPE] == MODEL_GEOGRAPHIC else "projected"

    # To grid order: x grows with the column, y with the row (row 0 = south).
    x0, dx, _, y0, _, dy = gt
    rows, cols = data.shape
    if dx < 0:
        data, valid = data[:, ::-1], valid[:, ::-1]
    if dy < 0:
        data, valid = data[::-1, :], valid[::-1, :]
    west = min(x0, x0 + cols * dx)
    south = min(y0, y0 + rows * dy)
    sx, sy = abs(dx), abs(dy)

    radius = None
    if crs == "geographic":
        uname, per_unit = _angular_unit(path, keys)
        radius = _radius(keys, notes)
        lat_c = (south + rows * sy / 2) * per_unit
        if not (abs(south * per_unit) <= math.pi / 2 + 1e-9 and abs(lat_c) < math.pi / 2):
            raise InputError(path, f"latitude {south} {uname}s is out of range: wrong GeoKeys?")
        k = radius * math.cos(lat_c)
        size_m = (k * sx * per_unit, radius * sy * per_unit)
        origin_m = (k * west * per_unit, radius * south * per_unit)
    elif crs == "projected":
        uname, per_unit = _linear_unit(path, keys, notes)
        size_m = (sx * per_unit, sy * per_unit)
        origin_m = (west * per_unit, south * per_unit)
    else:
        uname = "metre"
        size_m = (sx, sy)
        origin_m = (west, south)

    floor = float(data[valid].min())
    heights = np.where(valid, data, floor).astype(np.float32)
    if nodata is None and floor <= -9999:
        notes.append(
            f"no GDAL_NODATA tag, and the lowest height is {floor:g} m: if that marks missing "
            "data, set it (gdal_edit.py -a_nodata)"
        )
    citation = " / ".join(
        str(keys[k]).strip("|").strip()
        for k in (KEY_CITATION, KEY_GEOG_CITATION)
        if isinstance(keys.get(k), str) and str(keys[k]).strip("|").strip()
    )
    return Dem(
        heights=np.ascontiguousarray(heights),
        valid=np.ascontiguousarray(valid),
        pixel_size=size_m,
        pixel_size_crs=(sx, sy),
        origin=(west, south),
        origin_m=origin_m,
        crs=crs,
        units=uname,
        radius=radius,
        nodata=nodata,
        citation=citation,
        notes=tuple(notes),
    )


def _incomplete(tags: dict[int, Any], keys: dict[int, int | float | str]) -> str | None:
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


def _geokeys(path: Path, tags: dict[int, Any]) -> dict[int, int | float | str]:
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


def _nodata(path: Path, tags: dict[int, Any]) -> float | None:
    text = tags.get(TAG_GDAL_NODATA)
    if text is None:
        return None
    if isinstance(text, bytes):
        text = text.decode("latin-1")
    try:
        return float(str(text).strip().strip("\x00").replace(",", "."))
    except ValueError:
        raise InputError(path, f"GDAL_NODATA tag {text!r} is not a number") from None


def _as_sample(value: float, dtype: np.dtype[Any]) -> float | None:
    """``value`` as the file's samples store it (None when no sample can hold it)."""
    if dtype.kind == "f":
        with np.errstate(over="ignore"):
            return float(np.asarray(value).astype(dtype))
    info = np.iinfo(dtype)
    if value != int(value) or not info.min <= value <= info.max:
        return None
    return float(value)


def _gdal_scale_offset(tags: dict[int, Any]) -> tuple[float, float]:
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


def _geotransform(
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


def _linear_unit(
    path: Path, keys: dict[int, int | float | str], notes: list[str]
) -> tuple[str, float]:
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


def _angular_unit(path: Path, keys: dict[int, int | float | str]) -> tuple[str, float]:
    code = keys.get(KEY_GEOG_ANGULAR_UNITS, 9102)
    if code not in ANGULAR_UNITS:
        raise InputError(path, f"angular unit EPSG:{code} is not supported")
    return ANGULAR_UNITS[int(code)]


def _radius(keys: dict[int, int | float | str], notes: list[str]) -> float:
    """The Earth's mean radius, or another body's mean radius (2a + b) / 3 from the GeoKeys."""
    a = keys.get(KEY_SEMI_MAJOR)
    if not isinstance(a, (int, float)) or a <= 0 or abs(a - _EARTH_A) <= 0.01 * _EARTH_A:
        return EARTH_RADIUS
    b = keys.get(KEY_SEMI_MINOR)
    inv_f = keys.get(KEY_INV_FLATTENING)
    if not isinstance(b, (int, float)) or b <= 0:
        b = a * (1 - 1 / inv_f) if isinstance(inv_f, (int, float)) and inv_f > 0 else a
    radius = (2 * float(a) + float(b)) / 3
    notes.append(f"not the Earth: sphere of radius {radius:.1f} m from the CRS's ellipsoid")
    return radius


def haversine(lat_a: float, lon_a: float, lat_b: float, lon_b: float, radius: float) -> float:
    """Great-circle distance in metres between two points given in degrees, on a sphere of
    ``radius`` metres (gz-math ``SphericalCoordinates::Distance``)."""
    p1, p2 = math.radians(lat_a), math.radians(lat_b)
    dp, dl = p2 - p1, math.radians(lon_b - lon_a)
    h = math.sin(dp / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(dl / 2) ** 2
    return 2 * radius * math.atan2(math.sqrt(h), math.sqrt(1 - h))
