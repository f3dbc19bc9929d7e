"""Point-cloud files written by the exporter read back (by our reader, Open3D and laspy) to the
same points, within each format's precision; bytes are deterministic and writes atomic."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

from scan2terrain.errors import InputError
from scan2terrain.exporters._las import LAS_SCALE
from scan2terrain.exporters.pointcloud import FORMATS, points_bytes, write_points
from scan2terrain.readers.cloudfile import read_cloud


def utm_points(n: int = 2000, seed: int = 0) -> NDArray[np.float64]:
    """Map points at UTM magnitudes (eastings ~5e5 m, northings ~5e6 m), some negative z."""
    rng = np.random.default_rng(seed)
    return rng.uniform(-300, 300, (n, 3)) + np.array([512345.678, 5401234.567, -2.0], np.float64)


def las_expected(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """What LAS at 1 mm holds: the nearest millimetre count from floor(min)."""
    offset: NDArray[np.float64] = np.floor(points.min(axis=0))
    return np.round((points - offset) / LAS_SCALE) * LAS_SCALE + offset


@pytest.mark.parametrize("suffix", FORMATS)
def test_round_trip_through_read_cloud(tmp_path: Path, suffix: str) -> None:
    points = utm_points()
    path = tmp_path / f"p{suffix}"
    write_points(path, points)
    cloud = read_cloud(path)
    assert cloud.points.shape == points.shape and cloud.records == len(points)
    if suffix in (".ply", ".xyz", ".csv"):  # float64 / shortest repr: exact
        np.testing.assert_array_equal(cloud.points, points)
    elif suffix == ".pcd":  # float32 by design (PCL's PointXYZ)
        np.testing.assert_array_equal(cloud.points, points.astype(np.float32))
        assert not np.array_equal(cloud.points, points)  # UTM in float32 does lose precision
    else:
        assert np.abs(cloud.points - points).max() <= LAS_SCALE / 2 + 1e-9
        np.testing.assert_allclose(cloud.points, las_expected(points), rtol=0, atol=1e-9)
    assert [p.name for p in tmp_path.iterdir()] == [path.name]


@pytest.mark.parametrize("suffix", [".xyz", ".csv", ".ply", ".pcd"])
def test_open3d_reads_the_files_too(tmp_path: Path, suffix: str) -> None:
    """An independent reader: Open3D (it reads neither .csv headers nor LAS; .csv is checked as
    the text our reader parses, with the header skipped)."""
    import open3d

    points = utm_points(300, seed=1)
    path = tmp_path / f"p{suffix}"
    write_points(path, points)
    if suffix == ".csv":
        got = np.loadtxt(path, delimiter=",", skiprows=1)
        assert path.read_text().startswith("x,y,z\n")
    else:
        with open3d.utility.VerbosityContextManager(open3d.utility.VerbosityLevel.Error):
            got = np.asarray(open3d.io.read_point_cloud(path).points)
    expected = points.astype(np.float32) if suffix == ".pcd" else points
    np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_las_header(tmp_path: Path, suffix: str) -> None:
    import laspy  # type: ignore[import-untyped]

    points = utm_points(500, seed=2)
    path = tmp_path / f"p{suffix}"
    write_points(path, points)
    las = laspy.read(path)
    assert las.header.point_format.id == 0 and str(las.header.version) == "1.2"
    np.testing.assert_array_equal(las.header.scales, [LAS_SCALE] * 3)
    np.testing.assert_array_equal(las.header.offsets, np.floor(points.min(axis=0)))
    np.testing.assert_allclose(las.header.mins, las_expected(points).min(axis=0), atol=1e-9)
    np.testing.assert_allclose(las.header.maxs, las_expected(points).max(axis=0), atol=1e-9)
    assert las.header.creation_date is None  # day 0 / year 0: no timestamp in the file
    assert las.header.point_count == 500
    assert las.header.are_points_compressed == (suffix == ".laz")


@pytest.mark.parametrize("suffix", FORMATS)
def test_bytes_are_deterministic(suffix: str) -> None:
    points = utm_points(100, seed=3)
    assert points_bytes(points, suffix) == points_bytes(points.copy(), suffix.upper())


def test_text_formats(tmp_path: Path) -> None:
    points = np.array([[0.1, -2.0, 3e-7], [1e300, -0.0, 5401234.567]])
    assert points_bytes(points, ".xyz") == b"0.1 -2.0 3e-07\n1e+300 -0.0 5401234.567\n"
    assert points_bytes(points, ".csv") == b"x,y,z\n0.1,-2.0,3e-07\n1e+300,-0.0,5401234.567\n"
    single = np.array([[0.1, 2.0, 3.0]], dtype=np.float32)  # written as the float64 it is
    # float32 given where float64 is promised: the writer widens it, as this pins.
    assert points_bytes(single, ".xyz") == b"0.10000000149011612 2.0 3.0\n"  # type: ignore[arg-type]
    many = utm_points(70_000, seed=4)  # more than one formatting block
    write_points(tmp_path / "m.xyz", many)
    np.testing.assert_array_equal(read_cloud(tmp_path / "m.xyz").points, many)


def test_integer_points_and_negative_las_offsets(tmp_path: Path) -> None:
    points = np.array([[-10, -20, -30], [5, 6, 7]], dtype=np.int32)
    for suffix in (".las", ".xyz", ".ply"):
        write_points(tmp_path / f"i{suffix}", points)  # type: ignore[arg-type]
        np.testing.assert_array_equal(read_cloud(tmp_path / f"i{suffix}").points, points)


def test_empty_clouds_write_but_do_not_read(tmp_path: Path) -> None:
    for suffix in FORMATS:
        path = tmp_path / f"e{suffix}"
        write_points(path, np.zeros((0, 3)))
        # .xyz is 0 bytes: "empty file"; the others have a header and no point
        with pytest.raises(InputError, match=r"no finite point|empty file"):
            read_cloud(path)
    assert (tmp_path / "e.xyz").read_bytes() == b""
    assert (tmp_path / "e.csv").read_bytes() == b"x,y,z\n"


def test_las_span_limit(tmp_path: Path) -> None:
    fits = np.array([[0.0, 0.0, 0.0], [2_147_000.0, 1.0, 1.0]])
    write_points(tmp_path / "ok.las", fits)
    np.testing.assert_allclose(read_cloud(tmp_path / "ok.las").points, fits, atol=1e-9)
    with pytest.raises(ValueError, match="more than LAS can hold"):
        write_points(tmp_path / "far.laz", np.array([[0.0, 0.0, 0.0], [0.0, 2_200_000.0, 0.0]]))
    assert not (tmp_path / "far.laz").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ok.las"]


@pytest.mark.parametrize(
    ("name", "points", "message"),
    [
        ("p.obj", np.zeros((1, 3)), r"unsupported point cloud extension '\.obj'"),
        ("p", np.zeros((1, 3)), "extension"),
        ("p.csv", np.zeros((2, 2)), r"\(N, 3\)"),
        ("p.las", np.array([[0.0, np.inf, 0.0]]), "finite"),
        ("p.xyz", np.array([["a", "b", "c"]]), "number array"),
    ],
)
def test_rejects(tmp_path: Path, name: str, points: np.ndarray, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        write_points(tmp_path / name, points)
    assert not list(tmp_path.iterdir())
