"""Digital elevation models: single-band GeoTIFF files in, heights in metres out.

The file is read by :mod:`.geotiff` (tifffile; no GDAL), which also parses its georeference.
What is made of it here:

* Heights are metres unless ``VerticalUnitsGeoKey`` says feet; GDAL's per-band scale and offset
  (``GDAL_METADATA``) apply. A pixel scale without GeoKeys that say projected or geographic is an
  incomplete georeference (metres or degrees? degree pixels read as metres made a terrain 3.6 cm
  wide): like a TIFF without georeference, it is read only with a pixel size given in metres
  (``--resolution``).
* ``GDAL_NODATA`` and non-finite samples are nodata: they take the lowest valid height (what
  gz-common's ``Dem::FillHeightMap`` does with them). A DEM of nothing but nodata is refused.
  Negative heights are kept (bathymetry, the Moon).

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
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError
from scan2terrain.readers._limits import (
    MAX_BODY_RADIUS_M,
    MAX_COORDINATE_M,
    MAX_ELEVATION_M,
    MAX_SPACING_DEG,
    MAX_SPACING_M,
    MIN_BODY_RADIUS_M,
    MIN_SPACING_DEG,
    MIN_SPACING_M,
    exact_after_scaling,
    within,
)
from scan2terrain.readers.geotiff import (
    KEY_CITATION,
    KEY_GEOG_CITATION,
    KEY_INV_FLATTENING,
    KEY_MODEL_TYPE,
    KEY_SEMI_MAJOR,
    KEY_SEMI_MINOR,
    KEY_VERTICAL_UNITS,
    LINEAR_UNITS,
    MODEL_GEOGRAPHIC,
    TAG_GDAL_NODATA,
    TAG_TRANSFORMATION,
    angular_unit,
    gdal_nodata,
    gdal_scale_offset,
    geotransform,
    incomplete_georeference,
    linear_unit,
    read_band,
    read_geokeys,
)
from scan2terrain.types import HeightGrid, Pose2D

#: gz-math's Earth radius for ``SphericalCoordinates::Distance`` (metres).
EARTH_RADIUS = 6_371_000.0
#: WGS84 semi-major axis (metres): an ellipsoid within 1 % of it is the Earth.
_EARTH_A = 6_378_137.0

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
    path: Path | str,
    *,
    pixel_size: float | None = None,
    max_pixels: int = 1 << 28,
    max_elevation: float = MAX_ELEVATION_M,
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
    max_elevation : float
        Refuse a valid sample (nodata excluded) more than this many metres above or below the
        datum, after GDAL's scale and offset and the vertical unit.

    Returns
    -------
    Dem

    Raises
    ------
    InputError
        Missing, truncated or corrupt file; not a single-band raster of at least 2 x 2
        samples; no georeference (and no ``pixel_size``); an unsupported georeference; numbers
        that make no sense (pixel sizes, the raster's placement, elevations: see
        :mod:`._limits`); every pixel nodata; a compression that needs ``imagecodecs`` when it
        is not installed.
    """
    path = Path(path)
    raw, tags, messages = read_band(path, max_pixels)
    dem = _to_dem(path, raw, tags, pixel_size, max_elevation)
    if pixel_size is None and not dem.square:
        _check_resampled_size(path, dem, max_pixels)
    if messages:
        dem = dataclasses.replace(dem, notes=(*dem.notes, *messages))
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


def _to_dem(
    path: Path,
    raw: NDArray[Any],
    tags: dict[int, Any],
    pixel_size: float | None,
    max_elevation: float,
) -> Dem:
    notes: list[str] = []
    keys = read_geokeys(path, tags)
    data = raw.astype(np.float64)
    valid = np.isfinite(data)
    nodata = gdal_nodata(path, tags)
    if nodata is not None and math.isfinite(nodata):
        marker = _as_sample(nodata, raw.dtype)
        if marker is not None:
            valid &= data != marker
    if not valid.any():
        what = f"GDAL_NODATA {tags[TAG_GDAL_NODATA]!r}" if nodata is not None else "non-finite"
        raise InputError(path, f"every pixel is nodata ({what}): no heights to make terrain of")

    scale, offset = gdal_scale_offset(tags)
    vertical = keys.get(KEY_VERTICAL_UNITS)
    v_factor = 1.0
    if isinstance(vertical, int) and vertical in LINEAR_UNITS and vertical != 9001:
        name, v_factor = LINEAR_UNITS[vertical]
        notes.append(f"heights converted from {name} to metres")
    with np.errstate(over="ignore", invalid="ignore"):  # refused below, not warned about
        data = (data * scale + offset) * v_factor
    known = data[valid]
    floor, top = float(known.min()), float(known.max())
    _check_elevations(path, data, valid, (floor, top), max_elevation)

    incomplete = incomplete_georeference(tags, keys)
    gt = None if incomplete else geotransform(path, tags, keys)
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

    georef = "ModelTransformation" if TAG_TRANSFORMATION in tags else "ModelPixelScale"
    tie = "ModelTransformation" if TAG_TRANSFORMATION in tags else "ModelTiepoint"
    radius = None
    if crs == "geographic":
        uname, per_unit = angular_unit(path, keys)
        radius = _radius(path, keys, notes)
        _check_placement(
            path, (georef, tie), (west, south), (sx, sy), (rows, cols),
            degrees=per_unit / math.radians(1), reach=MAX_COORDINATE_M / radius / math.radians(1),
        )  # fmt: skip
        lat_c = (south + rows * sy / 2) * per_unit
        if not (abs(south * per_unit) <= math.pi / 2 + 1e-9 and abs(lat_c) < math.pi / 2):
            raise InputError(path, f"latitude {south} {uname}s is out of range: wrong GeoKeys?")
        k = radius * math.cos(lat_c)
        size_m = (k * sx * per_unit, radius * sy * per_unit)
        origin_m = (k * west * per_unit, radius * south * per_unit)
    elif crs == "projected":
        uname, per_unit = linear_unit(path, keys, notes)
        _check_placement(
            path, (georef, tie), (west, south), (sx, sy), (rows, cols), metres=per_unit
        )
        size_m = (sx * per_unit, sy * per_unit)
        origin_m = (west * per_unit, south * per_unit)
    else:
        uname = "metre"
        size_m = (sx, sy)
        origin_m = (west, south)

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


def _check_elevations(
    path: Path,
    data: NDArray[np.float64],
    valid: NDArray[np.bool_],
    low_high: tuple[float, float],
    max_elevation: float,
) -> None:
    """Refuse a valid sample beyond ``max_elevation`` metres either side of the datum (a
    strip of the header read as float32 gave 2.6e38 m), naming the first such sample as the
    file stores it (column, row from the north-west corner)."""
    if all(math.isfinite(v) and abs(v) <= max_elevation for v in low_high):
        return
    with np.errstate(invalid="ignore"):
        beyond = valid & ~(np.abs(data) <= max_elevation)
    row, col = (int(v) for v in np.unravel_index(int(np.argmax(beyond)), data.shape))
    try:
        within(
            path,
            f"elevation (column {col}, row {row})",
            float(data[row, col]),
            lo=0.0,
            hi=max_elevation,
            unit="m",
        )
    except InputError as exc:
        raise InputError(
            path,
            f"{exc.problem} (nodata excluded; --max-elevation widens it if the file is trusted)",
        ) from None


def _check_placement(
    path: Path,
    fields: tuple[str, str],
    corner: tuple[float, float],
    pixel: tuple[float, float],
    shape: tuple[int, int],
    *,
    metres: float | None = None,
    degrees: float | None = None,
    reach: float = MAX_COORDINATE_M,
) -> None:
    """Refuse a georeference whose numbers make no sense (a pixel scale of 1e300 m made a world
    3.3e301 m wide, a tie point of 1e308 was taken as placed): pixel sizes (CRS units) between
    the spacing limits, in metres for a projected CRS (``metres`` per unit) or degrees of arc
    for a geographic one (``degrees`` per unit), and the raster's edges within ``reach`` of the
    CRS's origin (metres, or its equivalent in degrees on the body's sphere), where float64
    still tells neighbouring pixels apart."""
    scale_field, tie_field = fields
    west, south = corner
    sx, sy = pixel
    rows, cols = shape
    if degrees is not None:
        unit, factor, lo, hi = "degrees", degrees, MIN_SPACING_DEG, MAX_SPACING_DEG
    else:
        unit, factor, lo, hi = "m", float(metres or 1.0), MIN_SPACING_M, MAX_SPACING_M
    within(path, f"{scale_field} pixel width", sx * factor, lo=lo, hi=hi, unit=unit)
    within(path, f"{scale_field} pixel height", sy * factor, lo=lo, hi=hi, unit=unit)
    # The tie point is usually the north-west corner: its edges first.
    edges = (
        ("west", west),
        ("north", south + rows * sy),
        ("east", west + cols * sx),
        ("south", south),
    )
    for name, value in edges:
        within(path, f"{tie_field} {name} edge", value * factor, lo=0.0, hi=reach, unit=unit)
    exact_after_scaling(path, f"{tie_field} west edge", sx, west, cols * sx)
    exact_after_scaling(path, f"{tie_field} south edge", sy, south, rows * sy)


def _as_sample(value: float, dtype: np.dtype[Any]) -> float | None:
    """``value`` as the file's samples store it (None when no sample can hold it)."""
    if dtype.kind == "f":
        with np.errstate(over="ignore"):
            return float(np.asarray(value).astype(dtype))
    info = np.iinfo(dtype)
    if value != int(value) or not info.min <= value <= info.max:
        return None
    return float(value)


def _radius(path: Path, keys: dict[int, int | float | str], notes: list[str]) -> float:
    """The Earth's mean radius, or another body's mean radius (2a + b) / 3 from the GeoKeys;
    semi-axes that make no sense for a body (0, negative, 1e-300 m: a world of size 0) are
    refused."""
    a = keys.get(KEY_SEMI_MAJOR)
    if not isinstance(a, (int, float)):
        return EARTH_RADIUS
    a = _semi_axis(path, "GeogSemiMajorAxisGeoKey", float(a))
    if abs(a - _EARTH_A) <= 0.01 * _EARTH_A:
        return EARTH_RADIUS
    b = keys.get(KEY_SEMI_MINOR)
    inv_f = keys.get(KEY_INV_FLATTENING)
    if isinstance(b, (int, float)):
        b = _semi_axis(path, "GeogSemiMinorAxisGeoKey", float(b))
    elif isinstance(inv_f, (int, float)) and inv_f > 0:
        field = f"semi-minor axis (from GeogInvFlatteningGeoKey = {inv_f:.6g})"
        b = _semi_axis(path, field, a * (1 - 1 / inv_f))
    else:
        b = a
    radius = (2 * a + b) / 3
    notes.append(f"not the Earth: sphere of radius {radius:.1f} m from the CRS's ellipsoid")
    return radius


def _semi_axis(path: Path, field: str, value: float) -> float:
    """``value`` when it is a body's semi-axis in metres (see :data:`MIN_BODY_RADIUS_M`)."""
    if not value > 0:
        raise InputError(
            path,
            f"{field} = {value:.6g} m makes no sense: a body's semi-axis is a positive length "
            f"({MIN_BODY_RADIUS_M:g}..{MAX_BODY_RADIUS_M:g} m)",
        )
    return within(path, field, value, lo=MIN_BODY_RADIUS_M, hi=MAX_BODY_RADIUS_M, unit="m")


def haversine(lat_a: float, lon_a: float, lat_b: float, lon_b: float, radius: float) -> float:
    """Great-circle distance in metres between two points given in degrees, on a sphere of
    ``radius`` metres (gz-math ``SphericalCoordinates::Distance``)."""
    p1, p2 = math.radians(lat_a), math.radians(lat_b)
    dp, dl = p2 - p1, math.radians(lon_b - lon_a)
    h = math.sin(dp / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(dl / 2) ** 2
    return 2 * radius * math.atan2(math.sqrt(h), math.sqrt(1 - h))
