"""convert keeps what the target format can hold (issue 25): classification, intensity, colour,
return numbers, GPS time, LAS's point format, scales, offsets and CRS, double precision; says
in one line what the target cannot hold; and a convert and back gives the same points and
attributes."""

from __future__ import annotations

from pathlib import Path

import laspy  # type: ignore[import-untyped]
import numpy as np
import pytest

from scan2terrain.cli import main
from scan2terrain.readers.cloudfile import read_cloud
from tests.fixtures import AUTZEN, AUTZEN_CSV, HDL_PCD, SIMPLE_LAS

FORMAT3 = [
    "intensity", "return_number", "number_of_returns", "scan_direction_flag",
    "edge_of_flight_line", "classification", "synthetic", "key_point", "withheld",
    "scan_angle_rank", "user_data", "point_source_id", "gps_time", "red", "green", "blue",
]  # fmt: skip


def convert(capsys: pytest.CaptureFixture[str], *args: object) -> str:
    code = main(["convert", *(str(a) for a in args)])
    out, err = capsys.readouterr()
    assert code == 0, err
    return out


def cannot_hold(report: str) -> list[str]:
    return [line.strip() for line in report.splitlines() if "cannot hold" in line]


def records(path: Path) -> np.ndarray:
    array: np.ndarray = laspy.read(path).points.array
    return array


def crs_records(path: Path) -> list[tuple[str, int, bytes]]:
    return [(v.user_id, v.record_id, v.record_data_bytes()) for v in laspy.read(path).header.vlrs]


def test_laz_to_las_and_back_keeps_every_record_and_the_crs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    las, laz = tmp_path / "a.las", tmp_path / "b.laz"
    report = convert(capsys, AUTZEN, las)
    assert cannot_hold(report) == []
    convert(capsys, las, laz)
    source = laspy.read(AUTZEN)
    for path in (las, laz):
        got = laspy.read(path)
        assert got.header.point_format.id == 3 and str(got.header.version) == "1.2"
        np.testing.assert_array_equal(got.header.scales, source.header.scales)
        np.testing.assert_array_equal(got.header.offsets, source.header.offsets)
        assert got.header.creation_date == source.header.creation_date
        assert got.header.system_identifier == source.header.system_identifier
        assert got.header.are_points_compressed == (path.suffix == ".laz")
        assert got.points.array.dtype == source.points.array.dtype
        np.testing.assert_array_equal(got.points.array, source.points.array)
        assert crs_records(path) == crs_records(AUTZEN)
        assert len(crs_records(path)) == 5
    # the converted file keeps its classes: --las-classes 2 finds the same ground points
    ground = tmp_path / "ground.ply"
    report = convert(capsys, las, ground, "--las-classes", "2")
    want = read_cloud(AUTZEN, las_classes=[2]).points
    assert f"({len(want):,} points)" in report and len(want) > 1000
    np.testing.assert_array_equal(read_cloud(ground).points, want)


@pytest.mark.parametrize("suffix", [".pcd", ".ply", ".csv"])
def test_laz_through_each_format_and_back_is_the_same_points_and_attributes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], suffix: str
) -> None:
    middle, back = tmp_path / f"m{suffix}", tmp_path / "back.laz"
    report = convert(capsys, AUTZEN, middle)
    assert cannot_hold(report) == [f"{suffix[1:].upper()} cannot hold: the CRS (5 LAS records)"]
    # double precision: UTM coordinates exactly as LAS gives them (float32 moved them 0.25 m)
    source = read_cloud(AUTZEN, attributes=True)
    mid = read_cloud(middle, attributes=True)
    np.testing.assert_array_equal(mid.points, source.points)
    assert list(mid.attributes) == FORMAT3
    for name in FORMAT3:
        np.testing.assert_array_equal(mid.attributes[name], source.attributes[name], err_msg=name)
    report = convert(capsys, middle, back)
    assert cannot_hold(report) == []
    got, want = laspy.read(back), laspy.read(AUTZEN)
    assert got.header.point_format.id == 3
    np.testing.assert_array_equal(got.header.scales, want.header.scales)  # found from the points
    np.testing.assert_array_equal(got.header.offsets, want.header.offsets)
    np.testing.assert_array_equal(got.points.array, want.points.array)
    assert got.header.vlrs == []  # the CRS did not survive the middle format, as it said


def test_pcd_header_keeps_pcl_conventions(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """x y z F 8 for LAS coordinates, intensity F 4 (PCL's PointXYZI), colour packed into rgb."""
    convert(capsys, AUTZEN, tmp_path / "a.pcd")
    head = (tmp_path / "a.pcd").read_bytes().split(b"DATA binary\n")[0].decode()
    lines = dict(line.split(" ", 1) for line in head.splitlines() if not line.startswith("#"))
    fields = lines["FIELDS"].split()
    types = dict(
        zip(fields, zip(lines["TYPE"].split(), lines["SIZE"].split(), strict=True), strict=True)
    )
    assert fields[:4] == ["x", "y", "z", "intensity"] and fields[-1] == "rgb"
    assert types["x"] == ("F", "8") and types["intensity"] == ("F", "4")
    assert types["classification"] == ("U", "1") and types["gps_time"] == ("F", "8")
    assert types["rgb"] == ("F", "4") and types["scan_angle_rank"] == ("I", "1")
    cloud = read_cloud(tmp_path / "a.pcd", colours=True)
    np.testing.assert_array_equal(cloud.colours, read_cloud(AUTZEN, colours=True).colours)


def test_xyz_says_it_holds_points_only(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    report = convert(capsys, AUTZEN, tmp_path / "a.xyz")
    (line,) = cannot_hold(report)
    assert line.startswith("XYZ cannot hold: intensity, return_number, ")
    assert "classification" in line and "gps_time" in line and "red/green/blue" in line
    assert line.endswith("; the CRS (5 LAS records)")
    np.testing.assert_array_equal(read_cloud(tmp_path / "a.xyz").points, read_cloud(AUTZEN).points)


def test_pcl_cloud_through_ply_and_back_is_the_same_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The HDL-32 PCD (x y z intensity, float32): PLY keeps float32 and the intensity, and the
    PCD made from it is the source file, byte for byte."""
    ply, pcd = tmp_path / "a.ply", tmp_path / "b.pcd"
    assert cannot_hold(convert(capsys, HDL_PCD, ply)) == []
    assert b"property float x\n" in ply.read_bytes()[:400]
    assert b"property float intensity\n" in ply.read_bytes()[:400]
    assert cannot_hold(convert(capsys, ply, pcd)) == []
    assert pcd.read_bytes() == HDL_PCD.read_bytes()


def test_pcl_cloud_to_las_keeps_intensity_and_says_how_far_points_moved(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    las, pcd = tmp_path / "a.las", tmp_path / "b.pcd"
    (line,) = cannot_hold(convert(capsys, HDL_PCD, las))
    assert line.startswith("LAS cannot hold: coordinates rounded to 0.001 m, moved up to ")
    source = read_cloud(HDL_PCD, attributes=True)
    got = laspy.read(las)
    assert got.header.point_format.id == 0
    np.testing.assert_array_equal(got.intensity, source.attributes["intensity"])
    assert np.abs(read_cloud(las).points - source.points).max() <= 0.0005 + 1e-9
    convert(capsys, las, pcd)
    back = read_cloud(pcd, attributes=True)
    np.testing.assert_array_equal(back.attributes["intensity"], source.attributes["intensity"])


def test_text_colours_to_las_and_back(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """PDAL's text export (quoted Red, Green, X, Y, Blue, Z): LAS point format 2, colours as
    they are, coordinates on the 0.01 m grid they were written with, nothing said lost. (The
    decimal 414.21 is not 41421 * 0.01 in binary: the last bit may differ, 1e-13 m.)"""
    las, csv = tmp_path / "a.las", tmp_path / "b.csv"
    rows = AUTZEN_CSV.read_text().splitlines()
    rng = np.random.default_rng(7)  # the fixture's colours are all 0: give it some
    for i in range(1, len(rows)):
        r, g, x, y, b, z = rows[i].split(",")
        r, g, b = (str(v) for v in rng.integers(0, 256, 3))
        rows[i] = ",".join([r, g, x, y, b, z])
    text = tmp_path / "pdal.txt"
    text.write_text("\n".join(rows) + "\n")
    assert cannot_hold(convert(capsys, text, las)) == []
    source = read_cloud(text, attributes=True)
    got = laspy.read(las)
    assert got.header.point_format.id == 2
    np.testing.assert_array_equal(got.header.scales, [0.01, 0.01, 0.01])
    np.testing.assert_allclose(read_cloud(las).points, source.points, rtol=0, atol=1e-9)
    for name in ("red", "green", "blue"):
        np.testing.assert_array_equal(got[name], source.attributes[name])
    assert np.any(source.attributes["red"] > 0)
    convert(capsys, las, csv)
    back = read_cloud(csv, attributes=True)
    header = csv.read_text().splitlines()[0]  # LAS's point format 2 dimensions, zeros
    assert header.startswith("x,y,z,intensity,") and header.endswith(",red,green,blue")
    assert not back.attributes["classification"].any()
    np.testing.assert_allclose(back.points, source.points, rtol=0, atol=1e-9)
    for name in ("red", "green", "blue"):
        np.testing.assert_array_equal(back.attributes[name], source.attributes[name])


def test_values_las_cannot_hold_are_named(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A class of 300, an intensity of 2.5: not written, and said so; a column LAS has no
    dimension for becomes an extra-bytes dimension; a class of 40 needs point format 6."""
    text = "X,Y,Z,Classification,Intensity,curvature\n1,2,3,300,2.5,0.25\n4,5,6,2,7,-1.5\n"
    (tmp_path / "odd.csv").write_text(text)
    (line,) = cannot_hold(convert(capsys, tmp_path / "odd.csv", tmp_path / "odd.las"))
    assert line == (
        "LAS cannot hold: classification (values outside 0..31); intensity (not whole numbers)"
    )
    got = laspy.read(tmp_path / "odd.las")
    np.testing.assert_array_equal(got.classification, [0, 0])
    np.testing.assert_array_equal(got.curvature, [0.25, -1.5])
    np.testing.assert_array_equal(read_cloud(tmp_path / "odd.las").points, [[1, 2, 3], [4, 5, 6]])
    (tmp_path / "c40.csv").write_text("x,y,z,classification\n1,2,3,40\n4,5,6,2\n")
    assert cannot_hold(convert(capsys, tmp_path / "c40.csv", tmp_path / "c40.las")) == []
    got = laspy.read(tmp_path / "c40.las")
    assert got.header.point_format.id == 6 and str(got.header.version) == "1.4"
    np.testing.assert_array_equal(got.classification, [40, 2])


def test_several_files_keep_what_they_share(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    twice = tmp_path / "twice.laz"
    assert cannot_hold(convert(capsys, AUTZEN, AUTZEN, twice)) == []
    got = laspy.read(twice)
    want = records(AUTZEN)
    np.testing.assert_array_equal(got.points.array, np.concatenate([want, want]))
    assert crs_records(twice) == crs_records(AUTZEN)
    report = convert(capsys, AUTZEN, SIMPLE_LAS, tmp_path / "mixed.las")
    assert "the files' LAS records (the CRS) differ: none kept" in report
    mixed = laspy.read(tmp_path / "mixed.las")
    assert mixed.header.vlrs == [] and mixed.header.point_format.id == 3
    np.testing.assert_array_equal(mixed.points.array, np.concatenate([want, records(SIMPLE_LAS)]))


@pytest.mark.parametrize("suffix", [".las", ".laz", ".pcd", ".ply", ".csv", ".xyz"])
def test_same_bytes_every_time(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], suffix: str
) -> None:
    convert(capsys, AUTZEN, tmp_path / f"a{suffix}")
    convert(capsys, AUTZEN, tmp_path / f"b{suffix}")
    assert (tmp_path / f"a{suffix}").read_bytes() == (tmp_path / f"b{suffix}").read_bytes()
