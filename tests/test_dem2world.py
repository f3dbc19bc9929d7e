"""dem2world end to end: worlds checked with Gazebo's own parser and heightmap loader.

The ground of the written world, rebuilt by gz-common (tests/gazebo_harness.py), must be at the
DEM's elevations at the world positions of its samples: the DEM's centre is the world origin,
x east, y north, z = elevation (gz-sim). Debian's gz-common 4 is built without GDAL (its
graphics library has no ``Dem`` class), so the GeoTIFF passthrough world is only parsed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tifffile
import yaml
from lxml import etree

from scan2terrain.cli import COMMAND_DEFAULTS, main
from scan2terrain.commands import dem
from scan2terrain.config import load_config
from scan2terrain.errors import ConfigError
from scan2terrain.readers.dem import Dem, read_dem
from scan2terrain.world.folder import Result
from tests.fixtures import GZ_SFBAY, MOON, SFBAY
from tests.gazebo_harness import ProbeError, probe_world
from tests.geotiff import write_geotiff
from tests.world_checks import ground


def build(source: Path, out: Path, **overrides: object) -> Result:
    cfg = load_config(None, dict(overrides), defaults=COMMAND_DEFAULTS["dem2world"])
    return dem.dem2world(source, out, cfg)


def text_at(doc: etree._ElementTree, path: str) -> str:
    """The text of the first element at ``path``, which must be there."""
    text = doc.findtext(path)
    assert text is not None, path
    return text


def sample_centres(dem: Dem) -> tuple[np.ndarray, np.ndarray]:
    """World x, y of every DEM sample (grid order), the DEM's centre at the origin."""
    rows, cols = dem.shape
    px, py = dem.pixel_size
    x = (np.arange(cols) + 0.5) * px - cols * px / 2
    y = (np.arange(rows) + 0.5) * py - rows * py / 2
    return np.meshgrid(x, y)


def test_sfbay_corners_land_at_gz_commons_elevations(tmp_path: Path) -> None:
    result = build(SFBAY, tmp_path / "w")
    dem = read_dem(SFBAY)
    (w,) = result.worlds
    assert w.placement.simulator == "gz"
    assert result.size_z == pytest.approx(dem.z_max - dem.z_min, rel=0.01)
    x, y = sample_centres(dem)
    got = ground(result, tmp_path, x, y)
    north_first = got[::-1]
    span = GZ_SFBAY["max"] - GZ_SFBAY["min"]
    for (col, row), want in GZ_SFBAY["corners"].items():
        assert north_first[row, col] == pytest.approx(want, abs=1e-3 * span), (col, row)
    # Every other sample: the north-south axis was resampled (non-square geographic pixels),
    # so Gazebo's bilinear surface differs from the DEM's at its own samples by the
    # re-interpolation error, about r/4 times a change of slope: bounded, not zero.
    err = np.abs(got - dem.heights)
    assert err.mean() < 0.002 * span and err.max() < 0.02 * span, (err.mean(), err.max())


def test_sfbay_world_is_16_bit_and_placed_at_the_lowest_elevation(tmp_path: Path) -> None:
    result = build(SFBAY, tmp_path / "w")
    (w,) = result.worlds
    _, probes = probe_world(w.world, [w.models], tmp_path / "p")
    (col,) = [p for p in probes if p.kind == "collision"]
    assert col.image_bpp == 16 and col.image_width == col.image_height == 257
    assert col.pose[2] == pytest.approx(GZ_SFBAY["min"], abs=1e-3)  # pose z = lowest height
    assert any("latitude 37.98" in n for n in result.notes)
    text = (w.models / w.placement.model_name / "model.sdf").read_text()
    assert "longitude -122.2048" in text  # the offset is in the SDF comment


def test_moon_every_sample_lands_exactly(tmp_path: Path) -> None:
    """Square projected pixels are not resampled: every sample within 16-bit quantisation."""
    result = build(MOON, tmp_path / "w")
    dem = read_dem(MOON)
    x, y = sample_centres(dem)
    got = ground(result, tmp_path, x, y)
    span = dem.z_max - dem.z_min
    np.testing.assert_allclose(got, dem.heights, atol=span / 65535 + 1e-4)
    assert got.max() < -205 and got.min() == pytest.approx(-212.29616, abs=1e-3)


def test_moon_classic_world_sits_at_elevation_minus_lowest(tmp_path: Path) -> None:
    """Gazebo Classic: 8-bit, and no heightmap pose (sdf.py writes none), so z - lowest."""
    result = build(MOON, tmp_path / "w", **{"world.simulator": "classic", "terrain.bit_depth": 8})
    dem = read_dem(MOON)
    x, y = sample_centres(dem)
    (w,) = result.worlds
    ox, oy = w.placement.offset
    got = ground(result, tmp_path, x - ox, y - oy)
    span = dem.z_max - dem.z_min
    np.testing.assert_allclose(got, dem.heights - dem.z_min, atol=span / 255 / 2 + 1e-4)


def test_nodata_dem_world(tmp_path: Path) -> None:
    raster = np.linspace(10.0, 60.0, 33 * 33, dtype=np.float32).reshape(33, 33)
    raster[5:9, 20:25] = -9999
    path = write_geotiff(tmp_path / "n.tif", raster, scale=(2.0, 2.0), nodata="-9999")
    result = build(path, tmp_path / "w")
    dem = read_dem(path)
    x, y = sample_centres(dem)
    got = ground(result, tmp_path, x, y)
    lowest = float(raster[raster != -9999].min())
    want = np.where(raster == -9999, lowest, raster)[::-1]
    np.testing.assert_allclose(got, want, atol=50 / 65535 + 1e-4)


def test_simulator_both_needs_8_bit(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="--bit-depth 8"):
        build(MOON, tmp_path / "w", **{"world.simulator": "both"})
    assert not (tmp_path / "w").exists()


def test_passthrough_world_references_the_geotiff(tmp_path: Path) -> None:
    result = build(SFBAY, tmp_path / "w", **{"dem.passthrough": True})
    world = tmp_path / "w/world_gz_dem.sdf"
    (model_dir,) = (tmp_path / "w/models").glob("*_dem")
    assert (model_dir / "dem_squared.tif").read_bytes() == SFBAY.read_bytes()
    doc = etree.parse(str(model_dir / "model.sdf"))
    uris = {
        u.text for u in doc.iter("uri") if (p := u.getparent()) is not None and p.tag == "heightmap"
    }
    assert uris == {f"model://{model_dir.name}/dem_squared.tif"}
    size = [float(v) for v in text_at(doc, ".//collision//size").split()]
    # gz-common's DEM world size, heights absolute (pose z 0, size.z = max - min).
    assert size[0] == pytest.approx(GZ_SFBAY["world_width"], rel=1e-3)
    assert size[1] == pytest.approx(GZ_SFBAY["world_height"], rel=1e-3)
    assert size[2] == pytest.approx(GZ_SFBAY["max"] - GZ_SFBAY["min"], rel=1e-3)
    assert text_at(doc, ".//collision/pose").split() == ["0.0"] * 6
    # SDFormat parses it strictly; gz-common 4 here cannot load a GeoTIFF as a heightmap.
    with pytest.raises(ProbeError, match="cannot load heightmap image"):
        probe_world(world, [tmp_path / "w/models"], tmp_path / "p")
    assert any("world_gz_dem.sdf" in n for n in result.notes)


# --- the command line -------------------------------------------------------------------------


def run(capsys: pytest.CaptureFixture[str], *args: object) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_writes_the_folder_and_reports_the_offset(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "sfbay"
    code, stdout, err = run(capsys, "dem2world", SFBAY, "-o", out)
    assert code == 0, err
    assert "latitude 37.98374999" in stdout and "z = elevation in gz-sim" in stdout
    names = {p.name for p in out.iterdir()}
    assert names == {
        "world_gz.sdf",
        "models",
        "preview.png",
        "preview3d.png",
        "robot",
        "scan2terrain.yaml",
        "spawn.yaml",
    }
    cfg = yaml.safe_load((out / "scan2terrain.yaml").read_text())
    assert cfg["terrain"]["bit_depth"] == 16 and cfg["world"]["simulator"] == "gz"
    assert cfg["filter"]["kind"] == "none"


def test_cli_config_file_beats_the_command_defaults(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    conf = tmp_path / "c.yaml"
    conf.write_text("terrain:\n  bit_depth: 8\nworld:\n  simulator: both\n")
    code, _, err = run(capsys, "dem2world", MOON, "-o", tmp_path / "w", "--config", conf)
    assert code == 0, err
    assert (tmp_path / "w/world_classic.world").is_file()


def _rgb(tmp: Path) -> Path:
    path = tmp / "photo.tif"
    tifffile.imwrite(path, np.zeros((8, 8, 3), np.uint8), photometric="rgb")
    return path


def _all_nodata(tmp: Path) -> Path:
    return write_geotiff(tmp / "empty.tif", np.full((4, 4), -9999, np.float32), nodata="-9999")


def _truncated(tmp: Path) -> Path:
    data = SFBAY.read_bytes()
    path = tmp / "cut.tif"
    path.write_bytes(data[: len(data) // 2])
    return path


def _plain(tmp: Path) -> Path:
    path = tmp / "plain.tif"
    tifffile.imwrite(path, np.ones((8, 8), np.float32))
    return path


@pytest.mark.parametrize(
    ("make", "problem"),
    [
        (_rgb, "3 samples per pixel (RGB): a DEM has one band"),
        (_all_nodata, "every pixel is nodata"),
        (_truncated, "truncated"),
        (_plain, "without georeference"),
        (lambda tmp: tmp / "missing.tif", "DEM file not found"),
    ],
    ids=["rgb", "all_nodata", "truncated", "no_georeference", "missing"],
)
def test_cli_bad_input(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], make: object, problem: str
) -> None:
    inputs = tmp_path / "in"
    inputs.mkdir()
    source = make(inputs)  # type: ignore[operator]
    work = tmp_path / "work"
    work.mkdir()
    code, stdout, err = run(capsys, "dem2world", source, "-o", work / "out")
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"scan2terrain: error: {source}: ")
    assert problem in lines[0]
    assert stdout == "" and list(work.iterdir()) == []  # nothing written, nothing left behind


def test_cli_plain_tiff_with_resolution(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "w"
    code, stdout, err = run(capsys, "dem2world", _plain(tmp_path), "-o", out, "--resolution", "0.5")
    assert code == 0, err
    assert "no georeference: 0.5 m pixels" in stdout
