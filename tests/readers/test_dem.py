"""The GeoTIFF DEM reader against gz-common's own expectations and hand-made GeoTIFFs.

gz-common's ``geospatial/src/Dem_TEST.cc`` (the oracle quoted in the fixtures' SOURCE.txt) loads
the same two files with GDAL. Hand-made GeoTIFFs are written with tifffile in ``tmp_path``.
"""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest
import tifffile

from scan2terrain.errors import InputError
from scan2terrain.readers.dem import EARTH_RADIUS, haversine, read_dem
from tests.fixtures import GZ_SFBAY, MOON, SFBAY
from tests.geotiff import GEOGRAPHIC_DEG, PROJECTED_METRE, write_geotiff

# --- gz-common's numbers ----------------------------------------------------------------------


def test_sfbay_matches_gz_common() -> None:
    dem = read_dem(SFBAY)
    rows, cols = dem.shape
    assert (rows, cols) == (GZ_SFBAY["side"], GZ_SFBAY["side"])
    assert dem.crs == "geographic" and dem.units == "degree" and dem.radius == EARTH_RADIUS
    width, height = dem.extent
    assert width == pytest.approx(GZ_SFBAY["world_width"], rel=1e-3)
    assert height == pytest.approx(GZ_SFBAY["world_height"], rel=1e-3)
    assert dem.z_min == pytest.approx(GZ_SFBAY["min"], rel=1e-3)
    assert dem.z_max == pytest.approx(GZ_SFBAY["max"], rel=1e-3)
    north_first = dem.heights[::-1]  # gz-common's row 0 is the north edge
    for (x, y), want in GZ_SFBAY["corners"].items():
        assert north_first[y, x] == pytest.approx(want, rel=1e-3), (x, y)
    assert dem.valid.all() and dem.nodata == pytest.approx(-3.4028234663852886e38)


def test_sfbay_north_edge_haversine_is_gz_commons_formula() -> None:
    """gz-common's world width is the haversine distance along the north edge; ours is the
    width at the centre latitude, 0.024 % more here. Both are within 0.1 %."""
    dem = read_dem(SFBAY)
    rows, cols = dem.shape
    lon0, lat0 = dem.origin
    dlon, dlat = dem.pixel_size_crs
    north = lat0 + rows * dlat
    gz_w = haversine(north, lon0, north, lon0 + cols * dlon, EARTH_RADIUS)
    gz_h = haversine(north, lon0, lat0, lon0, EARTH_RADIUS)
    assert gz_w == pytest.approx(GZ_SFBAY["world_width"], rel=1e-6)
    assert gz_h == pytest.approx(GZ_SFBAY["world_height"], rel=1e-6)
    assert dem.extent[0] / gz_w - 1 == pytest.approx(2.4e-4, abs=0.2e-4)


def test_moon_negative_heights_and_projected_metres() -> None:
    dem = read_dem(MOON)
    assert dem.shape == (33, 33)
    assert dem.crs == "projected" and dem.units == "metre" and dem.radius is None
    assert dem.z_min == pytest.approx(-212.29616, abs=1e-4)
    assert dem.z_max == pytest.approx(-205.44009, abs=1e-4)
    assert (dem.heights < 0).all() and dem.valid.all()
    assert dem.pixel_size == pytest.approx((2.4266098484848486, 2.4266098484848486))
    # gz-common, with a Moon surface: ~80.0417 m through latitude/longitude; ours is the
    # projected extent itself.
    assert dem.extent[0] == pytest.approx(80.0417, rel=1e-3)
    assert dem.origin == pytest.approx((-53750.0, -51050.0 - 33 * 2.4266098484848486))
    assert "Moon2000" in dem.citation


def test_fixture_reading_logs_nothing(caplog: pytest.LogCaptureFixture) -> None:
    """tifffile complains about GDAL's float32 nodata value; library code never prints."""
    read_dem(SFBAY)
    assert not caplog.records


# --- hand-made GeoTIFFs -----------------------------------------------------------------------


def test_rows_are_flipped_to_grid_order_and_georeferenced(tmp_path: Path) -> None:
    raster = np.arange(12, dtype=np.float32).reshape(3, 4)  # row 0 = north
    path = write_geotiff(tmp_path / "d.tif", raster, scale=(2.0, 3.0), tie=(1000.0, 5000.0))
    dem = read_dem(path)
    np.testing.assert_array_equal(dem.heights, raster[::-1])
    assert dem.origin == (1000.0, 5000.0 - 3 * 3.0)  # lower-left corner
    assert dem.origin_m == dem.origin
    assert dem.pixel_size == (2.0, 3.0)
    assert dem.extent == (8.0, 9.0)
    assert dem.centre == (1004.0, 4995.5)


@pytest.mark.parametrize("dtype", ["int16", "uint16", "int32", "float32", "float64", "uint8"])
def test_sample_types(tmp_path: Path, dtype: str) -> None:
    raster = np.array([[1, 2, 3], [40, 50, 60]], dtype=dtype)
    dem = read_dem(write_geotiff(tmp_path / "d.tif", raster))
    assert dem.heights.dtype == np.float32
    np.testing.assert_array_equal(dem.heights, raster[::-1].astype(np.float32))


def test_nodata_takes_the_lowest_valid_height(tmp_path: Path) -> None:
    raster = np.array([[-9999, 12.5, 13.0], [-3.25, -9999, 20.0]], dtype=np.float32)
    dem = read_dem(write_geotiff(tmp_path / "d.tif", raster, nodata="-9999"))
    grid = raster[::-1]
    np.testing.assert_array_equal(dem.valid, grid != -9999)
    np.testing.assert_array_equal(dem.heights, np.where(grid == -9999, -3.25, grid))
    assert dem.z_min == -3.25 and dem.nodata == -9999


def test_gdal_float32_nodata_and_nan(tmp_path: Path) -> None:
    """GDAL writes -FLT_MAX as '-3.4028234663852886e+38'; NaN samples are nodata too."""
    low = np.finfo(np.float32).min
    raster = np.array([[low, 5.0], [np.nan, 7.0]], dtype=np.float32)
    dem = read_dem(write_geotiff(tmp_path / "d.tif", raster, nodata="-3.4028234663852886e+38"))
    assert dem.valid.sum() == 2
    assert dem.heights.min() == 5.0


def test_int16_nodata(tmp_path: Path) -> None:
    raster = np.array([[-32768, 100], [200, -32768]], dtype=np.int16)
    dem = read_dem(write_geotiff(tmp_path / "d.tif", raster, nodata="-32768"))
    np.testing.assert_array_equal(dem.heights, [[200, 100], [100, 100]])


def test_all_nodata_is_refused(tmp_path: Path) -> None:
    raster = np.full((4, 4), -9999, dtype=np.float32)
    with pytest.raises(InputError, match="every pixel is nodata"):
        read_dem(write_geotiff(tmp_path / "d.tif", raster, nodata="-9999"))


def test_pixel_is_point_moves_half_a_pixel(tmp_path: Path) -> None:
    raster = np.zeros((2, 2), dtype=np.float32)
    keys = {**PROJECTED_METRE, 1025: 2}
    dem = read_dem(write_geotiff(tmp_path / "d.tif", raster, scale=(10, 10), keys=keys))
    assert dem.origin == (-5.0, -15.0)  # corner of the raster, not the first pixel's centre


def test_model_transformation_tag(tmp_path: Path) -> None:
    raster = np.arange(6, dtype=np.float32).reshape(2, 3)
    m = [2.0, 0, 0, 100.0, 0, -4.0, 0, 200.0, 0, 0, 0, 0, 0, 0, 0, 1]
    tag = (34264, "d", 16, tuple(m), True)
    dem = read_dem(write_geotiff(tmp_path / "d.tif", raster, scale=None, extra=(tag,)))
    assert dem.origin == (100.0, 192.0) and dem.pixel_size == (2.0, 4.0)
    np.testing.assert_array_equal(dem.heights, raster[::-1])


def test_rotated_raster_is_refused(tmp_path: Path) -> None:
    m = [2.0, 0.5, 0, 100.0, 0.5, -2.0, 0, 200.0, 0, 0, 0, 0, 0, 0, 0, 1]
    tag = (34264, "d", 16, tuple(m), True)
    path = write_geotiff(tmp_path / "d.tif", np.zeros((2, 2), np.float32), scale=None, extra=(tag,))
    with pytest.raises(InputError, match="rotated or sheared"):
        read_dem(path)


def test_us_survey_feet(tmp_path: Path) -> None:
    keys = {**PROJECTED_METRE, 3076: 9003, 4099: 9003}
    raster = np.full((2, 2), 100.0, dtype=np.float32)
    dem = read_dem(write_geotiff(tmp_path / "d.tif", raster, scale=(3.0, 3.0), keys=keys))
    ft = 1200 / 3937
    assert dem.units == "US survey foot"
    assert dem.pixel_size == pytest.approx((3 * ft, 3 * ft))
    assert dem.heights[0, 0] == pytest.approx(100 * ft)


def test_gdal_scale_and_offset(tmp_path: Path) -> None:
    xml = (
        '<GDALMetadata><Item name="SCALE" sample="0" role="scale">0.1</Item>'
        '<Item name="OFFSET" sample="0" role="offset">-50</Item></GDALMetadata>'
    )
    raster = np.array([[1000, 2000], [0, -500]], dtype=np.int16)  # row 0 = north
    dem = read_dem(write_geotiff(tmp_path / "d.tif", raster, extra=((42112, "s", 0, xml, True),)))
    np.testing.assert_allclose(dem.heights, [[-50.0, -100.0], [50.0, 150.0]])


def test_geographic_on_another_body(tmp_path: Path) -> None:
    """A geographic DEM on the Moon's sphere (semi-major axis 1737400 m in the GeoKeys)."""
    doubles = (34736, "d", 2, (1737400.0, 1737400.0), True)
    directory = [1, 1, 0, 4, 1024, 0, 1, 2, 1025, 0, 1, 1, 2057, 34736, 1, 0, 2058, 34736, 1, 1]
    keys_tag = (34735, "H", len(directory), tuple(directory), True)
    raster = np.zeros((10, 10), dtype=np.float32)
    path = write_geotiff(
        tmp_path / "d.tif", raster, scale=(0.001, 0.001), tie=(10.0, 0.005), keys={},
        extra=(keys_tag, doubles),
    )  # fmt: skip
    dem = read_dem(path)
    assert dem.radius == pytest.approx(1737400.0)
    assert dem.pixel_size[1] == pytest.approx(1737400.0 * math.radians(0.001))
    assert dem.pixel_size[0] == pytest.approx(dem.pixel_size[1])  # at the equator


# --- the height grid --------------------------------------------------------------------------


def test_square_pixels_are_not_resampled() -> None:
    dem = read_dem(MOON)
    grid = dem.to_height_grid()
    assert grid.heights is dem.heights and grid.resolution == dem.pixel_size[0]
    assert grid.origin.x == pytest.approx(-dem.extent[0] / 2)
    assert grid.origin.y == pytest.approx(-dem.extent[1] / 2)


def test_resampling_keeps_a_plane_and_the_georeference(tmp_path: Path) -> None:
    """Non-square metric pixels (geographic) are resampled bilinearly: a tilted plane stays
    the same plane at every new cell centre, extrapolated edges included."""
    rows, cols = 40, 30
    raster = np.empty((rows, cols), dtype=np.float64)
    dem0 = read_dem(
        write_geotiff(
            tmp_path / "g.tif", np.zeros((rows, cols), np.float32), scale=(1e-4, 1e-4),
            tie=(8.0, 47.0), keys=GEOGRAPHIC_DEG,
        )
    )  # fmt: skip
    px, py = dem0.pixel_size
    assert px < py  # 47 degrees north
    # Plane in metres from the DEM centre, sampled at the pixel centres (row 0 = north).
    xc = (np.arange(cols) + 0.5) * px - cols * px / 2
    yc = rows * py / 2 - (np.arange(rows) + 0.5) * py
    raster[:] = 0.01 * xc[None, :] - 0.02 * yc[:, None] + 100.0
    dem = read_dem(
        write_geotiff(
            tmp_path / "p.tif", raster.astype(np.float32), scale=(1e-4, 1e-4), tie=(8.0, 47.0),
            keys=GEOGRAPHIC_DEG,
        )
    )  # fmt: skip
    assert not dem.square
    grid = dem.to_height_grid()
    r = grid.resolution
    assert r == pytest.approx(dem.default_resolution()) and r < px
    n_rows, n_cols = grid.shape
    assert max(n_rows, n_cols) in (65, 129)  # fills the 2^n+1 side
    gx = grid.origin.x + (np.arange(n_cols) + 0.5) * r
    gy = grid.origin.y + (np.arange(n_rows) + 0.5) * r
    want = 0.01 * gx[None, :] - 0.02 * gy[:, None] + 100.0
    inside = (want >= dem.z_min) & (want <= dem.z_max)  # the grid clips to the DEM's range
    np.testing.assert_allclose(grid.heights[inside], want[inside], atol=2e-4)
    # The lattice reaches the DEM's outermost sample centres on both axes.
    assert gx[0] <= xc[0] + 1e-9 and gx[-1] >= xc[-1] - 1e-9
    assert gy[0] <= yc[-1] + 1e-9 and gy[-1] >= yc[0] - 1e-9


# --- bad input --------------------------------------------------------------------------------


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="not found"):
        read_dem(tmp_path / "nope.tif")


def test_not_a_tiff(tmp_path: Path) -> None:
    path = tmp_path / "x.tif"
    path.write_bytes(b"this is not a TIFF file at all")
    with pytest.raises(InputError, match="not a readable TIFF"):
        read_dem(path)


def test_rgb_tiff_is_refused_even_with_a_pixel_size(tmp_path: Path) -> None:
    path = tmp_path / "photo.tif"
    tifffile.imwrite(path, np.zeros((8, 8, 3), np.uint8), photometric="rgb")
    with pytest.raises(InputError, match=r"3 samples per pixel \(RGB\)"):
        read_dem(path, pixel_size=1.0)


def test_tiff_without_georeference_needs_a_pixel_size(tmp_path: Path) -> None:
    path = tmp_path / "plain.tif"
    raster = np.arange(6, dtype=np.uint16).reshape(2, 3)
    tifffile.imwrite(path, raster)
    with pytest.raises(InputError, match=r"without georeference.*--resolution"):
        read_dem(path)
    dem = read_dem(path, pixel_size=0.5)
    assert dem.crs == "local" and dem.pixel_size == (0.5, 0.5)
    np.testing.assert_array_equal(dem.heights, raster[::-1])


def test_truncated_tiff(tmp_path: Path) -> None:
    whole = write_geotiff(tmp_path / "d.tif", np.ones((64, 64), np.float32))
    cut = tmp_path / "cut.tif"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])
    with pytest.raises(InputError, match="truncated"):
        read_dem(cut)


def test_too_many_pixels(tmp_path: Path) -> None:
    path = write_geotiff(tmp_path / "d.tif", np.ones((64, 64), np.float32))
    with pytest.raises(InputError, match="over the limit"):
        read_dem(path, max_pixels=1000)


@pytest.mark.skipif(
    importlib.util.find_spec("imagecodecs") is not None, reason="imagecodecs is installed"
)
def test_lzw_without_imagecodecs_names_the_package(tmp_path: Path) -> None:
    path = write_geotiff(tmp_path / "d.tif", np.ones((4, 4), np.float32))
    data = path.read_bytes()
    # The Compression entry (tag 259, SHORT, count 1, value 1: none) -> 5: LZW.
    entry = (259).to_bytes(2, "little") + (3).to_bytes(2, "little") + (1).to_bytes(4, "little")
    at = data.index(entry + (1).to_bytes(2, "little"))
    path.write_bytes(data[: at + 8] + (5).to_bytes(2, "little") + data[at + 10 :])
    with pytest.raises(InputError, match="LZW data needs the optional package imagecodecs"):
        read_dem(path)
