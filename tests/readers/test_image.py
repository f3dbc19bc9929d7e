"""Any image -> grey luminance."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tifffile
from PIL import Image

from scan2terrain.errors import InputError
from scan2terrain.readers import read_grey_image
from tests.fixtures import IMAGES, TERRAIN


def test_rgb_uses_luminance_not_first_channel(tmp_path: Path) -> None:
    rgb = np.zeros((2, 3, 3), dtype=np.uint8)
    rgb[0, 0] = (255, 0, 0)
    rgb[0, 1] = (0, 255, 0)
    rgb[0, 2] = (0, 0, 255)
    rgb[1, :] = (10, 200, 30)
    Image.fromarray(rgb).save(tmp_path / "c.png")
    got = read_grey_image(tmp_path / "c.png").values
    expected = np.rint(rgb.astype(float) @ np.array([0.299, 0.587, 0.114])).astype(np.uint8)
    np.testing.assert_array_equal(got, expected)
    assert got[0, 1] > got[0, 0] > got[0, 2]  # green is brightest, blue darkest


@pytest.mark.parametrize("fmt", ["PNG", "BMP", "TIFF", "JPEG"])
def test_formats_and_modes_agree_with_pillow(tmp_path: Path, fmt: str) -> None:
    rgb = np.random.default_rng(1).integers(0, 256, (16, 16, 3), dtype=np.uint8)
    path = tmp_path / f"c.{fmt.lower()}"
    Image.fromarray(rgb).save(path, format=fmt)
    got = read_grey_image(path).values.astype(int)
    ref = np.asarray(Image.open(path).convert("L"), dtype=int)
    assert np.abs(got - ref).max() <= 1  # Pillow rounds its fixed-point luma slightly differently


def test_palette_rgba_and_16_bit(tmp_path: Path) -> None:
    rgb = np.random.default_rng(2).integers(0, 256, (8, 8, 3), dtype=np.uint8)
    Image.fromarray(rgb).convert("P").save(tmp_path / "p.png")
    pal = read_grey_image(tmp_path / "p.png").values
    ref = np.asarray(Image.open(tmp_path / "p.png").convert("L"), dtype=int)
    assert np.abs(pal.astype(int) - ref).max() <= 1
    rgba = np.dstack([rgb, np.zeros((8, 8), np.uint8)])
    Image.fromarray(rgba).save(tmp_path / "a.png")
    luma = np.rint(rgb @ np.array([0.299, 0.587, 0.114]))
    np.testing.assert_array_equal(read_grey_image(tmp_path / "a.png").values, luma)
    g16 = np.arange(64, dtype=np.uint16).reshape(8, 8) * 1000
    Image.fromarray(g16).save(tmp_path / "g.png")
    im = read_grey_image(tmp_path / "g.png")
    assert im.max_value == 65535 and im.values.dtype == np.uint16
    np.testing.assert_array_equal(im.values, g16)


def test_rgb_heightmap_fixture_is_grey() -> None:
    im = read_grey_image(IMAGES["bowl_rgb"])
    with Image.open(IMAGES["bowl_rgb"]) as src:
        rgb = np.asarray(src, dtype=float)
    assert rgb.shape == (129, 129, 3)
    np.testing.assert_array_equal(im.values, np.rint(rgb @ np.array([0.299, 0.587, 0.114])))


def test_bad_images(tmp_path: Path) -> None:
    (tmp_path / "x.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 20)
    with pytest.raises(InputError, match=r"x\.png: "):
        read_grey_image(tmp_path / "x.png")
    with pytest.raises(InputError, match="image file not found"):
        read_grey_image(tmp_path / "none.png")
    Image.fromarray(np.zeros((4, 4), np.float32)).save(tmp_path / "f.tiff")
    with pytest.raises(InputError, match="floating-point"):
        read_grey_image(tmp_path / "f.tiff")


# --- elevation rasters are not pictures ---------------------------------------------------------

DEM_FIXTURES = sorted(TERRAIN.glob("*/*.tif"))
#: A TIFF tag as tifffile.imwrite takes it: (code, data type, count, value, write once).
TiffTag = tuple[int, str, int, tuple[float, ...], bool]
GEO_TAGS: list[TiffTag] = [
    (33550, "d", 3, (10.0, 10.0, 0.0), True),
    (33922, "d", 6, (0.0, 0.0, 0.0, 500000.0, 4100000.0, 0.0), True),
    (34735, "H", 8, (1, 1, 0, 1, 1024, 0, 1, 1), True),
]


@pytest.mark.parametrize("path", DEM_FIXTURES, ids=[p.parent.name for p in DEM_FIXTURES])
def test_dem_fixtures_are_refused_with_a_pointer_to_dem2world(path: Path) -> None:
    assert len(DEM_FIXTURES) == 2
    with pytest.raises(InputError, match=r"elevation raster .*GeoKey.*dem2world") as err:
        read_grey_image(path)
    assert str(err.value).startswith(f"{path}: ") and "\n" not in str(err.value)


@pytest.mark.parametrize(
    ("dtype", "tags", "why"),
    [
        (np.uint16, GEO_TAGS, "ModelPixelScale"),  # a 2,000 m valley as 16-bit grey levels
        (np.uint8, GEO_TAGS[:2], "ModelTiepoint"),  # scale + tie point, no GeoKeys
        (np.uint8, GEO_TAGS[2:], "GeoKeyDirectory"),  # GeoKeys alone
        (np.int16, [], "signed 16-bit samples"),  # SRTM-style heights, no georeference
        (np.int32, [], "signed 32-bit samples"),
        (np.float32, [], "floating-point 32-bit samples"),
        (np.float64, GEO_TAGS, "ModelPixelScale"),
    ],
)
def test_single_band_elevation_tiffs_are_refused(
    tmp_path: Path, dtype: type[np.generic], tags: list[TiffTag], why: str
) -> None:
    path = tmp_path / "valley.tif"
    heights = (np.arange(64).reshape(8, 8) * 31).astype(dtype)
    tifffile.imwrite(path, heights, extratags=tags, photometric="minisblack")
    with pytest.raises(InputError, match=rf"elevation raster \(.*{why}.*\).*dem2world"):
        read_grey_image(path)


def test_plain_and_colour_tiffs_are_still_pictures(tmp_path: Path) -> None:
    """A 16-bit grey TIFF without georeference is a heightmap picture; an RGB GeoTIFF (an
    orthophoto) is a picture too: neither is refused."""
    g16 = (np.arange(64, dtype=np.uint16).reshape(8, 8) * 1000).astype(np.uint16)
    tifffile.imwrite(tmp_path / "g.tif", g16, photometric="minisblack")
    np.testing.assert_array_equal(read_grey_image(tmp_path / "g.tif").values, g16)
    rgb = np.random.default_rng(3).integers(0, 256, (8, 8, 3), dtype=np.uint8)
    tifffile.imwrite(tmp_path / "o.tif", rgb, photometric="rgb", extratags=GEO_TAGS)
    luma = np.rint(rgb @ np.array([0.299, 0.587, 0.114]))
    np.testing.assert_array_equal(read_grey_image(tmp_path / "o.tif").values, luma)
