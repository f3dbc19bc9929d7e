"""Point colours from point-cloud files (issue 15): read only when asked for, as 8-bit RGB row for
row with the finite points; None where the file has none. Files are written by hand (PLY, PCD,
text) or with laspy and Open3D, with colours whose 8-bit values are known."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from scan2terrain.errors import InputError
from scan2terrain.readers._cloud_common import rgb8
from scan2terrain.readers.cloudfile import read_cloud
from tests.fixtures import AUTZEN, OFFICE, SIMPLE_LAS, SIMPLE_LAZ

XYZ = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.5], [-1.0, 0.25, 2.0]])
RGB = np.array([[255, 0, 0], [0, 255, 0], [12, 34, 56], [200, 100, 1]], dtype=np.uint8)


def _ply(path: Path, fmt: str, props: str, body: bytes | str, before: str = "") -> Path:
    head = f"ply\nformat {fmt} 1.0\n{before}element vertex {len(XYZ)}\n{props}end_header\n"
    data = body.encode() if isinstance(body, str) else body
    path.write_bytes(head.encode() + data)
    return path


def _pcd(
    path: Path, spec: tuple[str, str, str], data: str, body: bytes | str, counts: str | None = None
) -> Path:
    """A PCD file: ``spec`` is its FIELDS, SIZE and TYPE lines' values."""
    fields, sizes, types = spec
    n = len(XYZ)
    counts = counts or " ".join("1" * len(fields.split()))
    head = (
        f"VERSION 0.7\nFIELDS {fields}\nSIZE {sizes}\nTYPE {types}\nCOUNT {counts}\n"
        f"WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {data}\n"
    )
    path.write_bytes(head.encode() + (body.encode() if isinstance(body, str) else body))
    return path


def _packed(rgb: np.ndarray, alpha: int = 255) -> np.ndarray:
    """PCL's packing of 8-bit RGB: 0xAARRGGBB."""
    r, g, b = (rgb[:, i].astype(np.uint32) for i in range(3))
    packed: np.ndarray = np.uint32(alpha) << 24 | r << 16 | g << 8 | b
    return packed


# --- the rule for values wider than 8 bits -----------------------------------------------------


def test_rgb8_scales_a_whole_array_by_one_rule() -> None:
    assert rgb8(np.array([[255, 10, 0]], np.uint16)).tolist() == [[255, 10, 0]]  # 8-bit values
    assert rgb8(np.array([[65535, 2560, 256]], np.uint16)).tolist() == [[255, 10, 1]]
    assert rgb8(np.array([[1.0, 0.5, 0.2]])).tolist() == [[255, 128, 51]]  # fractions
    assert rgb8(np.array([[1.0, 1.0, 0.0]])).tolist() == [[1, 1, 0]]  # whole numbers
    assert rgb8(np.array([[1.0, 1.0, 0.0]]), fractions=True).tolist() == [[255, 255, 0]]
    assert rgb8(np.array([[np.nan, 300.0, -4.0]])).tolist() == [[0, 1, 0]]  # NaN 0, 16-bit


# --- PLY ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("order", ["<", ">"])
def test_ply_binary_uchar_colours_between_other_properties(tmp_path: Path, order: str) -> None:
    rec = np.zeros(
        len(XYZ),
        dtype=[
            *[("x", order + "f8"), ("red", "u1"), ("y", order + "f8"), ("q", order + "u2")],
            *[("green", "u1"), ("blue", "u1"), ("z", order + "f4")],
        ],
    )
    rec["x"], rec["y"], rec["z"] = XYZ.T
    rec["red"], rec["green"], rec["blue"] = RGB.T
    props = (
        "property double x\nproperty uchar red\nproperty double y\nproperty ushort q\n"
        "property uchar green\nproperty uchar blue\nproperty float z\n"
    )
    fmt = "binary_little_endian" if order == "<" else "binary_big_endian"
    path = _ply(tmp_path / "c.ply", fmt, props, rec.tobytes())
    cloud = read_cloud(path, colours=True)
    np.testing.assert_array_equal(cloud.points, XYZ)
    assert cloud.colours is not None and cloud.colours.dtype == np.uint8
    assert cloud.colours.flags.c_contiguous
    np.testing.assert_array_equal(cloud.colours, RGB)
    plain = read_cloud(path)
    assert plain.colours is None
    np.testing.assert_array_equal(plain.points, cloud.points)


@pytest.mark.parametrize(
    ("kind", "values", "expected"),
    [
        ("uchar", RGB, RGB),
        ("ushort", RGB.astype(np.uint16) * 257, RGB),  # 16-bit: the high byte
        ("ushort", RGB.astype(np.uint16), RGB),  # 8-bit values in 16 bits: as they are
        ("float", RGB / 255.0, RGB),  # 0..1
        ("double", RGB / 255.0, RGB),
    ],
)
@pytest.mark.parametrize("lists", [False, True], ids=["numpy", "open3d"])
def test_ply_ascii_colour_types(
    tmp_path: Path, kind: str, values: np.ndarray, expected: np.ndarray, lists: bool
) -> None:
    """ASCII rows through numpy, and with a list element first through Open3D (RPly): the same
    colours either way."""
    props = "property float x\nproperty float y\nproperty float z\n" + "".join(
        f"property {kind} {c}\n" for c in ("red", "green", "blue")
    )
    before = "element face 1\nproperty list uchar int vertex_indices\n" if lists else ""
    rows = "".join(
        " ".join(map(repr, [*p, *v])) + "\n"
        for p, v in zip(XYZ.tolist(), values.tolist(), strict=True)
    )
    path = _ply(tmp_path / "a.ply", "ascii", props, ("3 0 1 2\n" if lists else "") + rows, before)
    cloud = read_cloud(path, colours=True)
    np.testing.assert_array_equal(cloud.points, XYZ)
    np.testing.assert_array_equal(cloud.colours, expected)


def test_ply_without_all_three_colours_has_none(tmp_path: Path) -> None:
    props = "property float x\nproperty float y\nproperty float z\nproperty uchar red\n"
    rows = "".join(f"{x} {y} {z} 7\n" for x, y, z in XYZ.tolist())
    path = _ply(tmp_path / "r.ply", "ascii", props, rows)
    assert read_cloud(path, colours=True).colours is None


def test_ply_non_finite_points_drop_their_colours(tmp_path: Path) -> None:
    rec = np.zeros(len(XYZ), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "u1", 3)])
    rec["x"], rec["y"], rec["z"] = XYZ.T
    rec["y"][1] = np.nan
    rec["rgb"] = RGB
    props = "property float x\nproperty float y\nproperty float z\n" + "".join(
        f"property uchar {c}\n" for c in ("red", "green", "blue")
    )
    cloud = read_cloud(_ply(tmp_path / "n.ply", "binary_little_endian", props, rec.tobytes()))
    assert cloud.colours is None and len(cloud.points) == 3
    cloud = read_cloud(tmp_path / "n.ply", colours=True)
    assert cloud.records == 4 and len(cloud.points) == 3
    np.testing.assert_array_equal(cloud.colours, RGB[[0, 2, 3]])


# --- PCD ---------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("field", "kind"), [("rgb", "F"), ("rgb", "U"), ("rgb", "I"), ("rgba", "U")]
)
def test_pcd_binary_packed_colour(tmp_path: Path, field: str, kind: str) -> None:
    """PCL's packing, 0xAARRGGBB little endian, whatever the field's TYPE (for F, the float's
    bits: opaque colours are NaN as floats)."""
    rec = np.zeros(
        len(XYZ),
        dtype=[("x", "<f4"), ("pad", "u1", (3,)), (field, "<u4"), ("y", "<f4"), ("z", "<f8")],
    )
    rec["x"], rec["y"], rec["z"] = XYZ.T
    rec[field] = _packed(RGB)
    spec = (f"x _ {field} y z", "4 1 4 4 8", f"F U {kind} F F")
    path = _pcd(tmp_path / "b.pcd", spec, "binary", rec.tobytes(), counts="1 3 1 1 1")
    cloud = read_cloud(path, colours=True)
    np.testing.assert_array_equal(cloud.points, XYZ)
    np.testing.assert_array_equal(cloud.colours, RGB)
    assert read_cloud(path).colours is None


def test_pcd_ascii_rgb_as_pcl_writes_it_and_as_old_float_text(tmp_path: Path) -> None:
    """PCL writes a float ``rgb`` field as its integer in ASCII; older writers as the float (here
    colours with alpha 0, tiny subnormal floats, written to 9 significant digits)."""
    ints = _packed(RGB)
    rows = [f"{x!r} {y!r} {z!r} {v}" for (x, y, z), v in zip(XYZ.tolist(), ints, strict=True)]
    rows[1] = "nan nan nan 4278255360"  # a non-finite point: its colour goes with it
    path = _pcd(tmp_path / "a.pcd", ("x y z rgb", "4 4 4 4", "F F F F"), "ascii", "\n".join(rows))
    cloud = read_cloud(path, colours=True)
    np.testing.assert_array_equal(cloud.points, XYZ[[0, 2, 3]])
    np.testing.assert_array_equal(cloud.colours, RGB[[0, 2, 3]])

    floats = _packed(RGB, alpha=0).view(np.float32)
    rows = [f"{x!r} {y!r} {z!r} {v:.9g}" for (x, y, z), v in zip(XYZ.tolist(), floats, strict=True)]
    path = _pcd(tmp_path / "f.pcd", ("x y z rgb", "4 4 4 4", "F F F F"), "ascii", "\n".join(rows))
    np.testing.assert_array_equal(read_cloud(path, colours=True).colours, RGB)


def test_pcd_binary_compressed_colours_through_open3d(tmp_path: Path) -> None:
    import open3d

    cloud = open3d.geometry.PointCloud(open3d.utility.Vector3dVector(XYZ))
    cloud.colors = open3d.utility.Vector3dVector(RGB / 255.0)
    path = tmp_path / "c.pcd"
    with open3d.utility.VerbosityContextManager(open3d.utility.VerbosityLevel.Error):
        assert open3d.io.write_point_cloud(path, cloud, compressed=True)
    assert b"DATA binary_compressed" in path.read_bytes()[:400]
    got = read_cloud(path, colours=True)
    assert got.format == "pcd binary_compressed"
    np.testing.assert_array_equal(got.colours, RGB)


def test_office_fixture_colours_are_open3ds_for_the_finite_points() -> None:
    import open3d

    cloud = read_cloud(OFFICE, colours=True)
    with open3d.utility.VerbosityContextManager(open3d.utility.VerbosityLevel.Error):
        ref = open3d.io.read_point_cloud(OFFICE, remove_nan_points=False)
    finite = np.isfinite(np.asarray(ref.points)).all(axis=1)
    expected = np.rint(np.asarray(ref.colors)[finite] * 255).astype(np.uint8)
    assert cloud.colours is not None and cloud.colours.shape == cloud.points.shape
    np.testing.assert_array_equal(cloud.colours, expected)


def test_pcd_without_colour_and_with_an_unusable_rgb(tmp_path: Path) -> None:
    rows = "\n".join(f"{x} {y} {z}" for x, y, z in XYZ.tolist())
    path = _pcd(tmp_path / "p.pcd", ("x y z", "4 4 4", "F F F"), "ascii", rows)
    assert read_cloud(path, colours=True).colours is None
    rows = "\n".join(f"{x} {y} {z} 1" for x, y, z in XYZ.tolist())
    path = _pcd(tmp_path / "w.pcd", ("x y z rgb", "4 4 4 2", "F F F U"), "ascii", rows)
    assert read_cloud(path).colours is None  # not asked for: not looked at
    with pytest.raises(InputError, match="PCD field rgb: TYPE U SIZE 2 COUNT 1 is not PCL"):
        read_cloud(path, colours=True)


# --- LAS / LAZ ---------------------------------------------------------------------------------


def _las(
    path: Path, rgb16: np.ndarray | None, *, point_format: int = 3, classes: list[int] | None = None
) -> Path:
    import laspy  # type: ignore[import-untyped]

    las = laspy.LasData(laspy.LasHeader(point_format=point_format, version="1.4"))
    las.header.scales = np.full(3, 0.001)
    las.header.offsets = np.zeros(3)
    las.x, las.y, las.z = XYZ.T
    if rgb16 is not None:
        las.red, las.green, las.blue = rgb16.T
    if classes is not None:
        las.classification = np.asarray(classes, dtype=np.uint8)
    las.write(path, do_compress=path.suffix == ".laz")
    return path


@pytest.mark.parametrize("suffix", [".las", ".laz"])
@pytest.mark.parametrize("point_format", [2, 3, 7, 8])
def test_las_sixteen_bit_colours_keep_the_high_byte(
    tmp_path: Path, suffix: str, point_format: int
) -> None:
    path = _las(tmp_path / f"c{suffix}", RGB.astype(np.uint16) * 256 + 3, point_format=point_format)
    cloud = read_cloud(path, colours=True)
    np.testing.assert_allclose(cloud.points, XYZ, atol=1e-9)
    np.testing.assert_array_equal(cloud.colours, RGB)
    assert read_cloud(path).colours is None


def test_las_eight_bit_values_are_used_as_they_are(tmp_path: Path) -> None:
    path = _las(tmp_path / "e.las", RGB.astype(np.uint16))
    np.testing.assert_array_equal(read_cloud(path, colours=True).colours, RGB)


def test_las_scale_is_decided_on_the_whole_file_not_the_kept_classes(tmp_path: Path) -> None:
    """Class 2 alone has only values <= 255, the file does not: they are 16-bit (dark)."""
    rgb16 = np.array([[255, 255, 255], [65535, 0, 0], [100, 0, 0], [0, 0, 0]], dtype=np.uint16)
    path = _las(tmp_path / "k.las", rgb16, classes=[2, 1, 2, 2])
    cloud = read_cloud(path, las_classes=[2], colours=True)
    np.testing.assert_allclose(cloud.points, XYZ[[0, 2, 3]], atol=1e-9)
    np.testing.assert_array_equal(cloud.colours, [[0, 0, 0], [0, 0, 0], [0, 0, 0]])


def test_las_point_format_without_colour_has_none(tmp_path: Path) -> None:
    path = _las(tmp_path / "n.las", None, point_format=1)
    assert read_cloud(path, colours=True).colours is None


def test_las_fixtures_colours_are_laspys() -> None:
    """Both fixtures store 8-bit values in LAS's 16-bit fields (max 249 and 236): as they are."""
    import laspy

    for path in (SIMPLE_LAS, SIMPLE_LAZ, AUTZEN):
        ref = laspy.read(path)
        values = np.stack([ref.red, ref.green, ref.blue], axis=1)
        assert values.max() <= 255
        cloud = read_cloud(path, colours=True)
        np.testing.assert_array_equal(cloud.colours, values.astype(np.uint8))


# --- text --------------------------------------------------------------------------------------


def test_csv_colour_columns_by_header_name(tmp_path: Path) -> None:
    rows = "".join(
        f"{r},{x!r},{b},{y!r},{z!r},{g}\n"
        for (x, y, z), (r, g, b) in zip(XYZ.tolist(), RGB.tolist(), strict=True)
    )
    path = tmp_path / "c.csv"
    path.write_text('"Red","X","Blue","Y","Z","Green"\n' + rows)
    cloud = read_cloud(path, colours=True)
    np.testing.assert_array_equal(cloud.points, XYZ)
    np.testing.assert_array_equal(cloud.colours, RGB)
    path.write_text(
        "x y z r g b\n"
        + "".join(
            f"{x} {y} {z} {r * 257} {g * 257} {b * 257}\n"
            for (x, y, z), (r, g, b) in zip(XYZ.tolist(), RGB.tolist(), strict=True)
        )
    )
    np.testing.assert_array_equal(read_cloud(path, colours=True).colours, RGB)


def test_xyzrgb_and_pts_columns_without_a_header(tmp_path: Path) -> None:
    xyzrgb = tmp_path / "a.xyzrgb"
    xyzrgb.write_text(
        "".join(
            " ".join(map(repr, [*p, *(c / 255.0).tolist()])) + "\n"
            for p, c in zip(XYZ.tolist(), RGB, strict=True)
        )
    )
    np.testing.assert_array_equal(read_cloud(xyzrgb, colours=True).colours, RGB)
    pts = tmp_path / "b.pts"
    pts.write_text(
        f"{len(XYZ)}\n"
        + "".join(
            f"{x} {y} {z} -1200 {r} {g} {b}\n"
            for (x, y, z), (r, g, b) in zip(XYZ.tolist(), RGB.tolist(), strict=True)
        )
    )
    cloud = read_cloud(pts, colours=True)
    np.testing.assert_array_equal(cloud.points, XYZ)
    np.testing.assert_array_equal(cloud.colours, RGB)


def test_text_without_known_colour_columns_has_none(tmp_path: Path) -> None:
    """Six numbers in a .xyz may be x y z and a normal: no colour without a header naming it."""
    path = tmp_path / "n.xyz"
    path.write_text("".join(f"{x} {y} {z} 0 0 1\n" for x, y, z in XYZ.tolist()))
    cloud = read_cloud(path, colours=True)
    assert cloud.colours is None
    np.testing.assert_array_equal(cloud.points, XYZ)
    path = tmp_path / "h.csv"
    path.write_text("x,y,z,intensity\n" + "".join(f"{x},{y},{z},5\n" for x, y, z in XYZ.tolist()))
    assert read_cloud(path, colours=True).colours is None
