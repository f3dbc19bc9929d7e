"""Issue 25 item 3: a world built from georeferenced clouds can be put back on the earth. The
local origin subtracted from the clouds is recorded in the effective config (a rerun with it
gives the same bytes), in every world file and in the map YAMLs; with a CRS (given, or a
LAS/LAZ file's own) each world holds <spherical_coordinates>, which SDFormat and gz-math (the
code gz-sim uses for NavSat) read back as the cloud's own places on the earth."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from scan2terrain.cli import main
from tests.fixtures import AUTZEN
from tests.gazebo_harness import probe_spherical

#: A 60 x 40 m patch of UTM zone 10N (central meridian -123): at 5,000 km north and 600 km east
#: its grid north is 0.76 degrees from true north, so a heading with the wrong sign puts a
#: point 500 m away 13 m off.
X0, Y0, Z0 = 600_000.0, 5_000_000.0, 120.0
CRS = "EPSG:32610"


def hill_cloud(path: Path) -> Path:
    """A smooth hill of points (x y z text) in UTM coordinates."""
    rng = np.random.default_rng(7)
    xy = rng.uniform((0, 0), (60, 40), size=(20_000, 2))
    z = 3.0 * np.exp(-(((xy[:, 0] - 30) / 12) ** 2 + ((xy[:, 1] - 20) / 9) ** 2))
    pts = np.column_stack([xy[:, 0] + X0, xy[:, 1] + Y0, z + Z0])
    np.savetxt(path, pts, fmt="%.3f")
    return path


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> str:
    code = main(list(argv))
    captured = capsys.readouterr()
    assert code == 0, captured.err
    return captured.out


def wgs84(x: float, y: float) -> tuple[float, float]:
    from pyproj import Transformer

    lon, lat = Transformer.from_crs(CRS, "EPSG:4326", always_xy=True).transform(x, y)
    return lat, lon


def ground_metres(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    from pyproj import Geod

    return float(Geod(ellps="WGS84").inv(lon1, lat1, lon2, lat2)[2])


@pytest.mark.parametrize("grid", ["height", "occupancy"])
def test_a_world_from_utm_points_lands_where_they_are(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], grid: str
) -> None:
    cloud = hill_cloud(tmp_path / "hill.xyz")
    out = tmp_path / "w"
    argv = ["cloud2world", str(cloud), "-o", str(out), "--resolution", "0.5", "--crs", CRS]
    argv += ["--grid", grid, "--simulator", "both"] + (
        ["--geometry", "heightmap"] * (grid == "height")
    )
    run(capsys, *argv)
    cfg = yaml.safe_load((out / "scan2terrain.yaml").read_text())
    origin = cfg["scans"]["local_origin"]
    assert isinstance(origin, list) and len(origin) == 3
    assert cfg["scans"]["crs"] == CRS
    assert abs(origin[0] - (X0 + 30)) <= 1 and abs(origin[1] - (Y0 + 20)) <= 1
    for world, yaml_name in [("world_gz.sdf", "map_gz.yaml"), ("world_classic.world", None)]:
        text = (out / world).read_text()
        assert "Georeference: world (x, y, z) = source coordinates -" in text
        if yaml_name and grid == "occupancy":  # height grids make no navigation map
            assert "Georeference" in (out / "map" / yaml_name).read_text()
        sph = probe_spherical(out / world, [out / "models"], tmp_path)
        assert sph is not None, world
        # Where this world's origin is in the cloud's coordinates: its comment says.
        found = text.split("source coordinates - (")[1].split(")")[0]
        ox, oy, oz = (float(v) for v in found.split(","))
        assert abs(sph["elevation"] - oz) < 1e-3
        for x, y, _z, lat, lon, _ in sph["points"]:
            want_lat, want_lon = wgs84(ox + x, oy + y)
            off = ground_metres(lat, lon, want_lat, want_lon)
            # Gazebo's frame is a tangent plane: UTM's scale (0.99962 here) and nothing else.
            assert off <= 4.5e-4 * math.hypot(x, y) + 0.01, (world, x, y, off)
    # The effective config rebuilds the same world, byte for byte.
    again = tmp_path / "again"
    run(
        capsys,
        "cloud2world",
        str(cloud),
        "-o",
        str(again),
        "--config",
        str(out / "scan2terrain.yaml"),
    )
    for f in ("world_gz.sdf", "world_classic.world", "octree.bt", "preview.png"):
        assert (again / f).read_bytes() == (out / f).read_bytes(), f


def test_a_given_origin_is_used_and_no_crs_means_no_spherical(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cloud = hill_cloud(tmp_path / "hill.xyz")
    out = tmp_path / "w"
    argv = ["cloud2world", str(cloud), "-o", str(out), "--resolution", "0.5"]
    printed = run(capsys, *argv, "--local-origin", "600000", "5000000", "100")
    assert "local origin (600000, 5000000, 100) subtracted" in printed
    text = (out / "world_gz.sdf").read_text()
    assert "source coordinates - (600000.000000, 5000000.000000, 100.000000)" in text
    assert "<spherical_coordinates>" not in text and "no CRS known" in text
    cfg = yaml.safe_load((out / "scan2terrain.yaml").read_text())
    assert cfg["scans"]["local_origin"] == [600000.0, 5000000.0, 100.0]


def test_a_laz_files_own_crs_is_used(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:

    laz = AUTZEN
    out = tmp_path / "w"
    printed = run(capsys, "cloud2world", str(laz), "-o", str(out), "--resolution", "2")
    # Its CRS is in international feet: the world is not in metres, and the report says so.
    assert "the CRS's unit is the foot (0.3048 m)" in printed and "3.281 times too large" in printed
    cfg = yaml.safe_load((out / "scan2terrain.yaml").read_text())
    assert cfg["scans"]["crs"]  # the file's Lambert conformal conic (Oregon, feet)
    sph = probe_spherical(out / "world_gz.sdf", [out / "models"], tmp_path)
    assert sph is not None
    # Autzen Stadium, Eugene, Oregon.
    assert 44.0 < sph["latitude_deg"] < 44.1 and -123.1 < sph["longitude_deg"] < -123.0


def test_a_bad_crs_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cloud = hill_cloud(tmp_path / "hill.xyz")
    for crs, words in [("EPSG:999999", "not a CRS"), ("EPSG:4326", "not a projected CRS")]:
        out = tmp_path / "w"
        assert main(["cloud2world", str(cloud), "-o", str(out), "--crs", crs]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and words in err and "--crs" in err, err
        assert not out.exists()


def test_streamed_worlds_say_the_same(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cloud = hill_cloud(tmp_path / "hill.xyz")
    worlds: list[str] = []
    for extra in ([], ["--stream"]):
        out = tmp_path / f"w{len(worlds)}"
        run(capsys, "cloud2world", str(cloud), "-o", str(out), "--resolution", "0.5",
            "--crs", CRS, *extra)  # fmt: skip
        text = (out / "world_gz.sdf").read_text()
        worlds.append(text[text.index("Georeference") : text.index("</spherical_coordinates>")])
    assert worlds[0] == worlds[1]
