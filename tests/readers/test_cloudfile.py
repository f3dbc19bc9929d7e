"""Point-cloud files -> float64 points: the real fixtures' documented facts, hand-made files for
every layout, and one clear InputError for every kind of bad file."""

from __future__ import annotations

import csv
import struct
from pathlib import Path

import numpy as np
import pytest

from scan2terrain.errors import InputError
from scan2terrain.readers.cloudfile import SUFFIXES, Cloud, read_cloud
from tests.fixtures import (
    AUTZEN,
    AUTZEN_CSV,
    HDL_PCD,
    HDL_PLY,
    OFFICE,
    SIMPLE_LAS,
    SIMPLE_LAZ,
    STREET,
)


def open3d_points(path: Path) -> np.ndarray:
    """Open3D's reading, as a reference for the PCD/PLY decoders."""
    import open3d

    with open3d.utility.VerbosityContextManager(open3d.utility.VerbosityLevel.Error):
        cloud = open3d.io.read_point_cloud(path)
    return np.asarray(cloud.points)


def assert_bbox(points: np.ndarray, lo: list[float], hi: list[float], tol: float) -> None:
    np.testing.assert_allclose(points.min(axis=0), lo, atol=tol, rtol=0)
    np.testing.assert_allclose(points.max(axis=0), hi, atol=tol, rtol=0)


# --- the real fixtures (facts from their SOURCE.txt) ----------------------------------------


def test_hdl32_pcd_and_ply_twins_give_the_same_points() -> None:
    pcd, ply = read_cloud(HDL_PCD), read_cloud(HDL_PLY)
    assert isinstance(pcd, Cloud) and pcd.path == HDL_PCD
    assert pcd.format == "pcd binary" and ply.format == "ply binary_little_endian"
    assert pcd.points.shape == ply.points.shape == (69_088, 3)
    assert pcd.records == ply.records == 69_088
    assert pcd.points.dtype == np.float64 and pcd.points.flags.c_contiguous
    np.testing.assert_array_equal(pcd.points, ply.points)
    assert_bbox(pcd.points, [-23.337, -74.682, -2.957], [19.025, 8.920, 10.796], 5e-4)
    np.testing.assert_array_equal(pcd.points, open3d_points(HDL_PCD))
    np.testing.assert_array_equal(ply.points, open3d_points(HDL_PLY))
    # float32 in the files: every value is a float32
    np.testing.assert_array_equal(pcd.points, pcd.points.astype(np.float32))


def test_office_organized_compressed_drops_nans() -> None:
    cloud = read_cloud(OFFICE)
    assert cloud.format == "pcd binary_compressed"
    assert cloud.records == 640 * 480
    assert cloud.points.shape == (254_456, 3)
    assert np.isfinite(cloud.points).all()
    assert_bbox(cloud.points, [-2.645, -2.196, 1.833], [1.504, 1.581, 5.364], 5e-4)
    ref = open3d_points(OFFICE)
    np.testing.assert_array_equal(cloud.points, ref[np.isfinite(ref).all(axis=1)])


def test_las_and_laz_twins_give_the_same_points() -> None:
    import laspy  # type: ignore[import-untyped]

    las, laz = read_cloud(SIMPLE_LAS), read_cloud(SIMPLE_LAZ)
    assert las.format == "las 1.2 point format 3" and laz.format == "laz 1.2 point format 3"
    assert las.points.shape == laz.points.shape == (1065, 3)
    np.testing.assert_array_equal(las.points, laz.points)
    assert_bbox(las.points, [635619.85, 848899.70, 406.59], [638982.55, 853535.43, 586.38], 5e-3)
    # float64 scaled integers, exactly as LAS defines them: X * scale + offset
    ref = laspy.read(SIMPLE_LAS)
    ints = np.stack([ref.X, ref.Y, ref.Z], axis=1).astype(np.float64)
    np.testing.assert_array_equal(las.points, ints * ref.header.scales + ref.header.offsets)


def test_autzen_laz_and_its_ground_class() -> None:
    import laspy

    everything = read_cloud(AUTZEN)
    assert everything.points.shape == (110_000, 3)
    assert_bbox(
        everything.points, [636001.76, 848935.20, 406.26], [637179.22, 849497.90, 520.51], 5e-3
    )
    ref = laspy.read(AUTZEN)
    classes = np.asarray(ref.classification)
    assert set(np.unique(classes).tolist()) == {1, 2}
    ground = read_cloud(AUTZEN, las_classes=(2,))
    n_ground = int((classes == 2).sum())
    assert 0 < n_ground < 110_000
    assert ground.points.shape == (n_ground, 3) and ground.records == n_ground
    np.testing.assert_array_equal(ground.points, everything.points[classes == 2])
    both = read_cloud(AUTZEN, las_classes=[2, 1, 2])
    np.testing.assert_array_equal(both.points, everything.points)
    with pytest.raises(InputError, match=r"no point of class 6, 7 \(classes present: 1, 2\)"):
        read_cloud(AUTZEN, las_classes=(7, 6))


def test_autzen_csv_columns_by_header_name() -> None:
    cloud = read_cloud(AUTZEN_CSV)
    assert cloud.format == "txt" and cloud.points.shape == (106, 3)
    assert_bbox(cloud.points, [635616.31, 848977.79, 407.35], [638864.60, 853362.37, 536.84], 1e-6)
    with AUTZEN_CSV.open(newline="") as f:
        rows = list(csv.DictReader(f))
    ref = np.array([[float(r["X"]), float(r["Y"]), float(r["Z"])] for r in rows])
    np.testing.assert_array_equal(cloud.points, ref)
    naive = np.loadtxt(AUTZEN_CSV, delimiter=",", skiprows=1, usecols=(0, 1, 2))
    assert not np.array_equal(naive, cloud.points)  # the first three columns are colours


def test_street_xyz() -> None:
    cloud = read_cloud(STREET)
    assert cloud.format == "xyz" and cloud.points.shape == (33_656, 3)
    assert_bbox(cloud.points, [-57.87, -36.74, -1.57], [7.50, 56.14, 23.08], 5e-3)
    assert cloud.points[0].tolist() == [-16.67, 19.53, 7.94]  # the file's first line
    np.testing.assert_array_equal(cloud.points, open3d_points(STREET))


# --- hand-made PCD files --------------------------------------------------------------------

PCD_HEAD = "# .PCD v0.7\nVERSION 0.7\nFIELDS {f}\nSIZE {s}\nTYPE {t}\nCOUNT {c}\nWIDTH {w}\nHEIGHT {h}\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {d}\n"  # noqa: E501


def pcd_header(
    fields: str, sizes: str, types: str, counts: str, *, w: int, h: int, data: str
) -> str:
    return PCD_HEAD.format(f=fields, s=sizes, t=types, c=counts, w=w, h=h, n=w * h, d=data)


def test_pcd_ascii_with_nan_rows_and_shuffled_fields(tmp_path: Path) -> None:
    head = pcd_header(
        "normal z rgb y x", "4 8 4 4 4", "F F U F F", "3 1 1 1 1", w=2, h=2, data="ascii"
    )
    rows = [
        "0 0 1 3.5 4278190080 2.25 1.125",
        "0 0 1 nan 0 nan nan",
        "0 0 1 -7.0e2 0 0.5 500000.123456789",
        "0 0 1 1 0 2 3",
    ]
    path = tmp_path / "a.pcd"
    path.write_text(head + "\n".join(rows) + "\n")
    cloud = read_cloud(path)
    assert cloud.format == "pcd ascii" and cloud.records == 4
    np.testing.assert_array_equal(
        cloud.points, [[1.125, 2.25, 3.5], [500000.123456789, 0.5, -700.0], [3, 2, 1]]
    )


def test_pcd_binary_types_and_padding(tmp_path: Path) -> None:
    n = 5
    rng = np.random.default_rng(1)
    rec = np.zeros(n, dtype=[("pad", "u1", (3,)), ("y", "<i2"), ("z", "<f8"), ("x", "<f4")])
    rec["pad"] = 255
    rec["y"] = rng.integers(-3000, 3000, n)
    rec["z"] = rng.normal(size=n) * 1e6
    rec["x"] = rng.normal(size=n).astype(np.float32)
    rec["x"][2] = np.inf
    path = tmp_path / "b.PCD"  # the extension is case-insensitive
    head = pcd_header("_ y z x", "1 2 8 4", "U I F F", "3 1 1 1", w=n, h=1, data="binary")
    path.write_bytes(head.encode() + rec.tobytes() + b"trailing bytes are ignored")
    cloud = read_cloud(path)
    expected = np.stack([rec["x"], rec["y"], rec["z"]], axis=1).astype(np.float64)
    np.testing.assert_array_equal(cloud.points, np.delete(expected, 2, axis=0))
    assert cloud.records == 5


@pytest.mark.parametrize("data", ["ascii", "binary"])
def test_pcd_field_names_in_any_case(tmp_path: Path, data: str) -> None:
    """``FIELDS X Y Z RGB`` (as some writers spell them; CSV headers are read so too) gives the
    points and colours ``x y z rgb`` would; an exact lower-case name wins over another case."""
    xyz = np.array([[1.5, -2.25, 3.0], [500000.125, 4.0, -0.5]])
    packed = np.array([0xFF102030, 0xFFA0B0C0], dtype=np.uint32)
    rec = np.zeros(2, dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("rgb", "<u4")])
    rec["x"], rec["y"], rec["z"] = xyz.T
    rec["rgb"] = packed
    rows = "".join(f"{a!r} {b!r} {c!r} {int(d)}\n" for a, b, c, d in rec.tolist())
    body = rows.encode() if data == "ascii" else rec.tobytes()
    for fields in ("X Y Z RGB", "X y Z Rgb"):
        path = tmp_path / f"{fields.replace(' ', '')}.pcd"
        head = pcd_header(fields, "8 8 8 4", "F F F U", "1 1 1 1", w=2, h=1, data=data)
        path.write_bytes(head.encode() + body)
        cloud = read_cloud(path, colours=True)
        np.testing.assert_array_equal(cloud.points, xyz)
        np.testing.assert_array_equal(cloud.colours, [[0x10, 0x20, 0x30], [0xA0, 0xB0, 0xC0]])
    # "x" and "X" both: the lower-case one is x (PCL's names are lower case)
    both = pcd_header("X x y z", "8 8 8 8", "F F F F", "1 1 1 1", w=1, h=1, data="ascii")
    (tmp_path / "both.pcd").write_text(both + "9 1 2 3\n")
    np.testing.assert_array_equal(read_cloud(tmp_path / "both.pcd").points, [[1.0, 2.0, 3.0]])
    # binary_compressed goes through Open3D, which knows only lower-case names
    import open3d

    pc = open3d.geometry.PointCloud(open3d.utility.Vector3dVector(xyz))
    pc.colors = open3d.utility.Vector3dVector(np.array([[16, 32, 48], [160, 176, 192]]) / 255)
    open3d.io.write_point_cloud(tmp_path / "lzf.pcd", pc, compressed=True)
    raw = (tmp_path / "lzf.pcd").read_bytes()
    assert raw.count(b"FIELDS x y z rgb\n") == 1
    (tmp_path / "LZF.pcd").write_bytes(raw.replace(b"FIELDS x y z rgb", b"FIELDS X Y Z RGB"))
    cloud = read_cloud(tmp_path / "LZF.pcd", colours=True)
    np.testing.assert_array_equal(cloud.points, read_cloud(tmp_path / "lzf.pcd").points)
    np.testing.assert_array_equal(cloud.colours, [[16, 32, 48], [160, 176, 192]])
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith("LZF")) == ["LZF.pcd"]
    # no field of any case
    (tmp_path / "none.pcd").write_text(both.replace("X x", "W w") + "9 1 2 3\n")
    with pytest.raises(InputError, match="PCD has no field x"):
        read_cloud(tmp_path / "none.pcd")


def test_pcd_binary_compressed_written_by_open3d(tmp_path: Path) -> None:
    import open3d

    pts = np.random.default_rng(2).normal(size=(1000, 3)) * 10
    path = tmp_path / "c.pcd"
    cloud = open3d.geometry.PointCloud(open3d.utility.Vector3dVector(pts))
    with open3d.utility.VerbosityContextManager(open3d.utility.VerbosityLevel.Error):
        assert open3d.io.write_point_cloud(path, cloud, compressed=True)
    assert b"DATA binary_compressed" in path.read_bytes()[:400]
    got = read_cloud(path)
    assert got.format == "pcd binary_compressed"
    # Open3D stores float32 (its default PCD precision) -> compare at float32
    np.testing.assert_allclose(got.points, pts, rtol=1e-6, atol=1e-5)


def corrupt_office(tmp_path: Path) -> Path:
    raw = bytearray(OFFICE.read_bytes())
    start = raw.index(b"DATA binary_compressed\n") + len(b"DATA binary_compressed\n") + 8
    raw[start + 1000 : start + 201_000] = (bytes(range(256)) * 800)[:200_000]
    path = tmp_path / "corrupt.pcd"
    path.write_bytes(bytes(raw))
    return path


def test_pcd_compressed_corrupt_block(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="corrupt data: the header says 307200 points"):
        read_cloud(corrupt_office(tmp_path))


# --- hand-made PLY files --------------------------------------------------------------------


def test_ply_binary_big_endian_with_extra_properties_and_faces(tmp_path: Path) -> None:
    n = 4
    rec = np.zeros(n, dtype=[("red", "u1"), ("z", ">f8"), ("y", ">f4"), ("x", ">i4"), ("q", ">u2")])
    rec["x"] = [1, -2, 3, 4]
    rec["y"] = [0.5, 1.5, np.nan, 2.5]
    rec["z"] = [5e6 + 0.001, 1.0, 2.0, 3.0]
    head = (
        "ply\nformat binary_big_endian 1.0\ncomment made by hand\nelement vertex 4\n"
        "property uchar red\nproperty double z\nproperty float y\nproperty int x\n"
        "property ushort q\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
    )
    face = struct.pack(">Biii", 3, 0, 1, 2)
    path = tmp_path / "be.ply"
    path.write_bytes(head.encode() + rec.tobytes() + face)
    cloud = read_cloud(path)
    assert cloud.format == "ply binary_big_endian" and cloud.records == 4
    np.testing.assert_array_equal(
        cloud.points, [[1, 0.5, 5e6 + 0.001], [-2, 1.5, 1.0], [4, 2.5, 3.0]]
    )


def test_ply_ascii_with_an_element_before_the_vertices(tmp_path: Path) -> None:
    path = tmp_path / "a.ply"
    path.write_text(
        "ply\nformat ascii 1.0\nelement camera 2\nproperty float fov\n"
        "element vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
        "property uchar red\nend_header\n60\n70\n1 2 3 255\n4 5 6 0\n7 8 9.5 1\n"
    )
    cloud = read_cloud(path)
    assert cloud.format == "ply ascii"
    np.testing.assert_array_equal(cloud.points, [[1, 2, 3], [4, 5, 6], [7, 8, 9.5]])


def test_ply_binary_with_a_fixed_element_before_the_vertices(tmp_path: Path) -> None:
    cams = np.array([(60.0, 1), (70.0, 2)], dtype=[("fov", "<f4"), ("id", "u1")])
    verts = np.array([(1.5, 2.0, 3.0), (4.0, -5.0, 6.25)], dtype="<f8")
    path = tmp_path / "c.ply"
    path.write_bytes(
        b"ply\nformat binary_little_endian 1.0\nelement camera 2\nproperty float fov\n"
        b"property uchar id\nelement vertex 2\nproperty double x\nproperty double y\n"
        b"property double z\nend_header\n" + cams.tobytes() + verts.tobytes()
    )
    np.testing.assert_array_equal(read_cloud(path).points, verts)
    np.testing.assert_array_equal(open3d_points(path), verts)


def test_ply_lists_before_the_vertices_go_through_open3d(tmp_path: Path) -> None:
    path = tmp_path / "l.ply"
    path.write_text(
        "ply\nformat ascii 1.0\nelement face 2\nproperty list uchar int vertex_indices\n"
        "element vertex 3\nproperty double x\nproperty double y\nproperty double z\n"
        "end_header\n3 0 1 2\n4 0 1 2 0\n1 2 3\n4 5 6\n7 8 9.5\n"
    )
    cloud = read_cloud(path)
    np.testing.assert_array_equal(cloud.points, [[1, 2, 3], [4, 5, 6], [7, 8, 9.5]])


# --- text files -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("name", "text", "expected"),
    [
        ("a.xyz", "1 2 3\n4 5 6\n", [[1, 2, 3], [4, 5, 6]]),
        ("crlf.xyz", "# made by hand\r\n\r\n1\t2\t3\r\n4 5 6 # tail\r\n", [[1, 2, 3], [4, 5, 6]]),
        ("c.xyzrgb", "1 2 3 255 0 0\n-4e3 5 6 0 255 0\n", [[1, 2, 3], [-4000, 5, 6]]),
        ("n.xyzn", "1 2 3 0 0 1\nnan 1 1 0 0 1\n", [[1, 2, 3]]),
        ("b.txt", "500000.125 5000000.25 12\n", [[500000.125, 5000000.25, 12]]),
        ("h.txt", "x y z intensity\n1 2 3 9\n", [[1, 2, 3]]),
        ("p.pts", "2\n1 2 3 -120 10 20 30\n4 5 6 -3 1 2 3\n", [[1, 2, 3], [4, 5, 6]]),
        ("q.pts", "1 2 3\n", [[1, 2, 3]]),
        ("s.csv", "Z;y;X\n3;2;1\n6;5;4\n", [[1, 2, 3], [4, 5, 6]]),
        ("q.csv", '"i","x" , "Y","z"\n9, 1, 2, 3\n9,4,5,6\n', [[1, 2, 3], [4, 5, 6]]),
        ("cc.csv", "//X,Y,Z,R,G,B\n1,2,3,0,0,0\n", [[1, 2, 3]]),
        ("plain.csv", "1,2,3\n4,5,6\n", [[1, 2, 3], [4, 5, 6]]),
        ("w.csv", "x y z\n1 2 3\n", [[1, 2, 3]]),
    ],
)
def test_text_layouts(tmp_path: Path, name: str, text: str, expected: list[list[float]]) -> None:
    path = tmp_path / name
    path.write_bytes(text.encode())
    cloud = read_cloud(path)
    assert cloud.format == path.suffix[1:]
    np.testing.assert_array_equal(cloud.points, expected)


def test_text_keeps_full_float64_precision(tmp_path: Path) -> None:
    pts = np.random.default_rng(3).uniform(-1, 1, (200, 3)) * 5e6
    path = tmp_path / "f.csv"
    path.write_text("x,y,z\n" + "\n".join(",".join(repr(v) for v in p) for p in pts.tolist()))
    np.testing.assert_array_equal(read_cloud(path).points, pts)


# --- bad files ------------------------------------------------------------------------------


def truncated(src: Path, tmp_path: Path, keep: int) -> Path:
    path = tmp_path / f"cut{src.suffix}"
    path.write_bytes(src.read_bytes()[:keep])
    return path


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda t: truncated(HDL_PCD, t, 500_000), "truncated: 69088 points of 16 bytes"),
        (lambda t: truncated(HDL_PCD, t, 300), "truncated"),
        (lambda t: truncated(HDL_PLY, t, 500_000), "truncated: 69088 vertices of 16 bytes"),
        (lambda t: truncated(HDL_PLY, t, 200), "PLY header has no end_header"),
        (lambda t: truncated(OFFICE, t, 900_000), "truncated: a compressed block of"),
        (lambda t: truncated(OFFICE, t, 198), "truncated: the compressed block's sizes"),
        (lambda t: truncated(SIMPLE_LAS, t, 20_000), "truncated LAS file: 1065 points of 34"),
        (lambda t: truncated(SIMPLE_LAS, t, 227 + 1000 * 34), "truncated LAS file"),
        (lambda t: truncated(SIMPLE_LAS, t, 100), "cannot read as LAS/LAZ"),
        (lambda t: truncated(SIMPLE_LAZ, t, 9000), "truncated or corrupt LAZ file: its chunk"),
        (lambda t: truncated(AUTZEN_CSV, t, 33), "no finite point in the cloud \\(no points\\)"),
    ],
)
def test_truncated_files(tmp_path: Path, make: object, message: str) -> None:
    path = make(tmp_path)  # type: ignore[operator]
    with pytest.raises(InputError, match=message) as info:
        read_cloud(path)
    assert info.value.path == path
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    ("name", "content", "message"),
    [
        ("e.pcd", b"", "empty file"),
        ("e.las", b"", "empty file"),
        ("e.csv", b"", "empty file"),
        ("g.xyz", b"hello world\nfoo bar baz\n", "line 1 \\('hello world'\\) is neither numbers"),
        ("p.xyz", b"1 2 3\n4 5 x\n", "not a table of numbers: could not convert string 'x'"),
        ("r.xyz", b"1 2 3\n4 5\n", "not a table of numbers"),
        ("two.xyz", b"1 2\n3 4\n", "line 1: 2 numbers, expected x y z"),
        ("bin.xyz", b"\xff\xfe\x00\x01\x80 binary", "not a text file"),
        ("c.xyz", b"# only a comment\n\n", "no points \\(only blank or comment lines\\)"),
        ("nz.csv", b"x,y,elevation\n1,2,3\n", "neither numbers nor a header naming one x"),
        ("dx.csv", b"x,x,y,z\n1,2,3,4\n", "neither numbers nor a header"),
        ("nan.xyz", b"nan 1 2\n1 inf 2\n", "all 2 points are NaN or infinite"),
        ("n.pts", b"3\n1 2 3\n4 5 6\n", "the .pts file says 3 points, has 2"),
        ("n1.pts", b"3\n", "truncated: the .pts file says 3 points, has none"),
        ("x.pcd", b"hello\n", "not a PCD file \\(it starts with 'hello'\\)"),
        ("d.pcd", b"VERSION 0.7\nFIELDS x y z\n", "no DATA line"),
        ("f.pcd", b"VERSION 0.7\nDATA ascii\n", "no FIELDS line"),
        (
            "z.pcd",
            pcd_header("x y", "4 4", "F F", "1 1", w=1, h=1, data="ascii").encode() + b"1 2\n",
            "PCD has no field z \\(FIELDS x y\\)",
        ),
        (
            "t.pcd",
            pcd_header("x y z", "4 4 2", "F F F", "1 1 1", w=1, h=1, data="binary").encode(),
            "field z: unsupported TYPE F SIZE 2",
        ),
        (
            "l.pcd",
            pcd_header("x y z", "4 4", "F F F", "1 1 1", w=1, h=1, data="binary").encode(),
            "differ in length",
        ),
        (
            "k.pcd",
            pcd_header("x y z", "4 4 4", "F F F", "1 1 1", w=1, h=1, data="lzma").encode(),
            "unknown DATA 'lzma'",
        ),
        (
            "w.pcd",
            pcd_header("x y z", "4 4 4", "F F F", "1 1 1", w=2, h=1, data="ascii")
            .replace("POINTS 2", "POINTS 3")
            .encode(),
            "POINTS 3 is not WIDTH x HEIGHT 2x1",
        ),
        (
            "a.pcd",
            pcd_header("x y z", "4 4 4", "F F F", "1 1 1", w=2, h=1, data="ascii").encode()
            + b"1 2 3\n",
            "truncated: PCD header says 2 points, the data has 1",
        ),
        (
            "long.pcd",
            pcd_header("x y z", "4 4 4", "F F F", "1 1 1", w=1, h=1, data="ascii").encode()
            + b"1 2 3\n4 5 6\n",
            "^[^ ]* PCD header says 1 points, the data has 2",
        ),
        (
            "neg.pcd",
            pcd_header(
                "i x y z", "-4 4 4 4", "F F F F", "1 1 1 1", w=1, h=1, data="binary"
            ).encode(),
            "SIZE must be positive",
        ),
        (
            "b.pcd",
            pcd_header("x y z", "4 4 4", "F F F", "1 1 1", w=2, h=1, data="ascii").encode()
            + b"1 2 3\n4 x 6\n",
            "not a table of numbers",
        ),
        ("m.ply", b"PLY\nformat ascii 1.0\n", "not a PLY file"),
        ("v.ply", b"ply\nformat ascii 1.0\nelement face 0\nend_header\n", "no vertex element"),
        (
            "u.ply",
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
            b"end_header\n1 2\n",
            "PLY vertex element has no property z",
        ),
        (
            "q.ply",
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float128 x\nend_header\n",
            "PLY header: cannot read the line 'property float128 x'",
        ),
        (
            "s.ply",
            b"ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\n"
            b"property double z\nend_header\n1 2 3\n4 5 6\n",
            "truncated: PLY header says 3 vertices, the data has 2",
        ),
        (
            "fmt.ply",
            b"ply\nformat binary_middle_endian 1.0\nelement vertex 0\nproperty double x\n"
            b"property double y\nproperty double z\nend_header\n",
            "unknown format 'binary_middle_endian'",
        ),
        ("t.las", b"not a LAS file, just some text", "cannot read as LAS/LAZ"),
    ],
)
def test_bad_files(tmp_path: Path, name: str, content: bytes, message: str) -> None:
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(InputError, match=message) as info:
        read_cloud(path)
    assert info.value.path == path
    assert str(info.value).startswith(str(path)) and "\n" not in str(info.value)


def test_missing_file_and_unknown_extension(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="point-cloud file not found"):
        read_cloud(tmp_path / "nope.pcd")
    (tmp_path / "mesh.obj").write_text("v 1 2 3\n")
    with pytest.raises(InputError, match=r"unknown point-cloud extension '\.obj'"):
        read_cloud(tmp_path / "mesh.obj")
    with pytest.raises(InputError, match="'\\(none\\)'"):
        read_cloud(tmp_path / "noext")
    assert ".laz" in SUFFIXES and ".csv" in SUFFIXES


def test_las_classes_only_for_las(tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r"only be selected in \.las/\.laz"):
        read_cloud(STREET, las_classes=(2,))
    for bad in [(), (256,), (-1,)]:
        with pytest.raises(ValueError, match="las_classes"):
            read_cloud(SIMPLE_LAS, las_classes=bad)
