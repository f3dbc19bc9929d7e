"""Issue 28, hostile files round 2: the numbers of point-cloud files against the physical world.

LAS/LAZ scales, offsets and header bounds (metres, or degrees of arc where the file's CRS is
geographic), coordinates that must stay exact in float64, the LASzip VLR lazrs decodes by, and
the coordinates of CSV/XYZ and PCD files. Each input here was read as valid (a world written
from nonsense), failed with exit 1, or took the process down with SIGABRT; each is refused now
through the real command, on the default path and ``--stream`` alike, with exit 2 and exactly
one stderr line ``scan2terrain: error: <path>: <field> = <value> ...``, and nothing written.

The commands run once for the module through :func:`tests.mutation_runner.run_cases` (forked
children under an address-space limit: an abort is reported as a signal, not pytest's death).
"""

from __future__ import annotations

import itertools
import math
import re
import struct
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from scan2terrain.errors import InputError
from scan2terrain.readers._limits import MAX_COORDINATE_M
from tests.fixtures import AUTZEN, AUTZEN_CSV, OFFICE, SIMPLE_LAS, SIMPLE_LAZ, STREET
from tests.mutation_runner import Case, Outcome, one_line, run_cases

LIMIT_BYTES = 3 << 30
TIMEOUT_S = 60
WORLD = ["--simulator", "gz", "--no-preview"]

# The LAS 1.0-1.4 header: three float64 scale factors at byte 131, three offsets at 155, then
# the bounds max X, min X, max Y, min Y, max Z, min Z from byte 179.
SCALE, OFFSET, BOUNDS = 131, 155, 179


def _patched(src: Path, dst: Path, edits: dict[int, float]) -> Path:
    data = bytearray(src.read_bytes())
    for at, value in edits.items():
        struct.pack_into("<d", data, at, value)
    dst.write_bytes(bytes(data))
    return dst


def _las(
    path: Path,
    xyz: np.ndarray,
    *,
    scales: tuple[float, float, float],
    offsets: tuple[float, float, float],
    crs: str | None = None,
    version: str = "1.2",
) -> Path:
    """A LAS file laspy writes (point format 3, or 6 for 1.4), with ``crs`` (GeoKeys before
    LAS 1.4, WKT in 1.4) when given."""
    import laspy  # type: ignore[import-untyped]

    header = laspy.LasHeader(point_format=6 if version == "1.4" else 3, version=version)
    header.scales = np.array(scales)
    header.offsets = np.array(offsets)
    if crs is not None:
        import pyproj

        header.add_crs(pyproj.CRS(crs))
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.write(path)
    return path


#: Points about Portland, in degrees of longitude and latitude and metres of height.
DEGREES = np.array([[-122.68, 45.52, 15.0], [-122.67, 45.53, 19.5], [-122.675, 45.525, 17.25]])
#: Points in UTM zone 10N, metres (within the 2.1 m a 1e-9 scale reaches from its offset).
UTM = np.array([[525_000.5, 5_040_000.25, 15.0], [525_001.5, 5_040_001.0, 19.5]])


def _las_inputs(tmp: Path) -> dict[str, tuple[Path, list[str]]]:
    """name -> (the input, its command line with {in} and {out})."""
    world = ["cloud2world", "{in}", "-o", "{out}", *WORLD]
    stream = [*world, "--stream"]
    convert = ["convert", "{in}", "{out}.xyz"]
    header: dict[str, dict[int, float]] = {
        "x-scale-1e-300": {SCALE: 1e-300},  # exit 0: a world of one point
        "y-scale-denormal": {SCALE + 8: 5e-324},
        "z-scale-1e-300": {SCALE + 16: 1e-300},
        "x-scale-1e10": {SCALE: 1e10},  # --stream: exit 1, "array is too big"
        "z-scale-1e10": {SCALE + 16: 1e10},
        "x-offset-1e17": {OFFSET: 1e17},  # --stream: exit 0, the default path another refusal
        "y-offset-1e300": {OFFSET + 8: 1e300},
        "z-offset--1e300": {OFFSET + 16: -1e300},
        "max-x-1e300": {BOUNDS: 1e300},  # two lines: a numpy warning, then "no known voxel"
        "min-y--1e17": {BOUNDS + 24: -1e17},
        "max-z-inf": {BOUNDS + 32: math.inf},
        "min-x-over-max-x": {BOUNDS + 8: 7e5},  # the bounds planned the stream's tiles
    }
    inputs: dict[str, tuple[Path, list[str]]] = {}
    for name, edits in header.items():
        src = _patched(SIMPLE_LAS, tmp / f"{name}.las", edits)
        inputs[name] = (src, world)
        inputs[f"{name} --stream"] = (src, stream)
    laz = _patched(SIMPLE_LAZ, tmp / "laz-x-offset-1e17.laz", {OFFSET: 1e17})
    inputs["laz-x-offset-1e17"] = (laz, world)
    inputs["laz-x-offset-1e17 --stream"] = (laz, stream)
    # A scale of 1 m lets an int32 reach 2.1e9 m: a point beyond the limit under sane bounds.
    far = _las(tmp / "far.las", np.array([[2e9, 0.0, 0.0], [0.0, 5.0, 1.0]]),
               scales=(1.0, 1.0, 0.01), offsets=(0.0, 0.0, 0.0))  # fmt: skip
    _patched(far, far, {BOUNDS: 10.0})
    inputs["far-point"] = (far, world)
    inputs["far-point --stream"] = (far, stream)
    # Degrees of arc: the scales of geographic LAS (1e-9 degree is 0.1 mm).
    for name, crs, version in (
        ("geographic-geokeys", "EPSG:4326", "1.2"),
        ("geographic-wkt", "EPSG:4326", "1.4"),
        ("no-crs-degrees", None, "1.2"),
    ):
        path = _las(tmp / f"{name}.las", DEGREES, scales=(1e-9, 1e-9, 0.001),
                    offsets=(-122.0, 45.0, 0.0), crs=crs, version=version)  # fmt: skip
        inputs[name] = (path, convert)
    inputs["projected-1e-9"] = (
        _las(tmp / "projected-1e-9.las", UTM, scales=(1e-9, 1e-9, 0.001),
             offsets=(525_000.0, 5_040_000.0, 0.0), crs="EPSG:32610"),
        convert,
    )  # fmt: skip
    inputs["no-crs-metres-1e-9"] = (
        _las(tmp / "no-crs-metres-1e-9.las", UTM, scales=(1e-9, 1e-9, 0.001),
             offsets=(525_000.0, 5_040_000.0, 0.0)),
        convert,
    )  # fmt: skip
    geo = _las(tmp / "geographic-inexact.las", DEGREES, scales=(1e-9, 1e-9, 0.001),
               offsets=(-122.0, 45.0, 0.0), crs="EPSG:4326")  # fmt: skip
    inputs["geographic-inexact"] = (_patched(geo, geo, {SCALE: 1e-11, OFFSET: 1e6}), convert)
    geo10 = _las(tmp / "geographic-10-degrees.las", DEGREES, scales=(1e-9, 1e-9, 0.001),
                 offsets=(-122.0, 45.0, 0.0), crs="EPSG:4326")  # fmt: skip
    inputs["geographic-10-degrees"] = (_patched(geo10, geo10, {SCALE + 8: 10.0}), convert)
    return inputs


def _run(tmp: Path, inputs: dict[str, tuple[Path, list[str]]]) -> dict[str, tuple[Path, Outcome]]:
    cases = []
    for name, (src, argv) in inputs.items():
        out = tmp / "out" / re.sub(r"\W+", "_", name)
        out.mkdir(parents=True)
        filled = [a.replace("{in}", str(src)).replace("{out}", str(out / "o")) for a in argv]
        cases.append(Case(name, filled, str(out)))
    results = run_cases(cases, limit_bytes=LIMIT_BYTES, timeout_s=TIMEOUT_S, workdir=tmp / "_r")
    return {c.name: (inputs[c.name][0], o) for c, o in zip(cases, results, strict=True)}


@pytest.fixture(scope="module")
def las_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, Outcome]]:
    tmp = tmp_path_factory.mktemp("las")
    return _run(tmp, _las_inputs(tmp))


# --- LAS/LAZ: scales, offsets and bounds --------------------------------------------------------


@pytest.mark.parametrize(
    ("case", "field"),
    [
        ("x-scale-1e-300", "X scale factor = 1e-300 m"),
        ("y-scale-denormal", "Y scale factor = 4.94066e-324 m"),
        ("z-scale-1e-300", "Z scale factor = 1e-300 m"),
        ("x-scale-1e10", "X scale factor = 1e+10 m"),
        ("z-scale-1e10", "Z scale factor = 1e+10 m"),
        ("x-offset-1e17", "X offset = 1e+17 m"),
        ("y-offset-1e300", "Y offset = 1e+300 m"),
        ("z-offset--1e300", "Z offset = -1e+300 m"),
        ("max-x-1e300", "Max X = 1e+300 m"),
        ("min-y--1e17", "Min Y = -1e+17 m"),
        ("max-z-inf", "Max Z = inf m"),
        ("min-x-over-max-x", "Min X = 700000 m is above Max X = 638983 m"),
        ("laz-x-offset-1e17", "X offset = 1e+17 m"),
        ("far-point", "point 0: X = 2e+09 m"),
    ],
)
def test_las_numbers_beyond_the_physical_world_are_refused_on_both_paths(
    las_runs: dict[str, tuple[Path, Outcome]], case: str, field: str
) -> None:
    """One answer whichever path: the same line from the default path and ``--stream``."""
    src, default = las_runs[case]
    _, streamed = las_runs[f"{case} --stream"]
    line = one_line(default, src)
    assert line.startswith(f"scan2terrain: error: {src}: {field}"), line
    assert one_line(streamed, src) == line


def test_las_scale_limits_follow_the_files_crs(las_runs: dict[str, tuple[Path, Outcome]]) -> None:
    """1e-9 is a geographic LAS's scale (0.1 mm in degrees): read where the CRS is geographic
    (GeoKeys or WKT), or unknown with x and y within degrees' range; refused in metres."""
    for case in ("geographic-geokeys", "geographic-wkt", "no-crs-degrees"):
        src, o = las_runs[case]
        assert o.exit == 0 and o.signal is None, o.describe()
        written = np.loadtxt(Path(o.argv[-1]))
        np.testing.assert_allclose(written, DEGREES, atol=1e-9)
    for case in ("projected-1e-9", "no-crs-metres-1e-9"):
        src, o = las_runs[case]
        line = one_line(o, src)
        assert f"{src}: X scale factor = 1e-09 m makes no sense" in line, line
    src, o = las_runs["geographic-10-degrees"]
    assert f"{src}: Y scale factor = 10 deg makes no sense" in one_line(o, src)


def test_las_offsets_that_float64_cannot_hold_exactly_are_refused(
    las_runs: dict[str, tuple[Path, Outcome]],
) -> None:
    """A 1e-11 degree scale is legal, an offset of 1e6 too, but not both: steps of 1e-11 at
    1e6 merge in float64."""
    src, o = las_runs["geographic-inexact"]
    line = one_line(o, src)
    assert f"{src}: X: offset 1e+06 with scale 1e-11 cannot be held exactly" in line, line


def test_las_header_checks_read_the_fixtures(tmp_path: Path) -> None:
    """The fixtures' headers pass (scales 0.01 in metres and in feet, no CRS and a projected
    one), through every reader."""
    from scan2terrain.readers.cloudfile import read_cloud
    from scan2terrain.readers.las import iter_las, las_info

    for path in (SIMPLE_LAS, SIMPLE_LAZ, AUTZEN):
        cloud = read_cloud(path)
        info = las_info(path)
        streamed = np.concatenate(list(iter_las(path)))
        np.testing.assert_array_equal(streamed, cloud.points)
        assert info.points == len(cloud.points)
        assert np.abs(cloud.points).max() < MAX_COORDINATE_M


def test_las_header_refusals_name_the_field_in_process(tmp_path: Path) -> None:
    """las_info, read_cloud and iter_las give the same refusal (the stream plans by las_info)."""
    from scan2terrain.readers.cloudfile import read_cloud
    from scan2terrain.readers.las import iter_las, las_info

    path = _patched(SIMPLE_LAS, tmp_path / "s.las", {OFFSET + 8: 1e17})
    readers: list[Callable[[Path], object]] = [read_cloud, las_info, lambda p: list(iter_las(p))]
    for read in readers:
        with pytest.raises(InputError) as info:
            read(path)
        assert info.value.path == path
        assert info.value.problem.startswith("Y offset = 1e+17 m makes no sense"), info.value


# --- LAZ: the laszip VLR lazrs decodes by -----------------------------------------------------


def _laszip_payload(data: bytes) -> int:
    """Where the laszip VLR's payload starts (its user id is at +2 of its 54-byte header)."""
    return data.index(b"laszip encoded") - 2 + 54


def _laz_with(src: Path, dst: Path, at: int, fmt: str, value: int) -> Path:
    data = bytearray(src.read_bytes())
    struct.pack_into(fmt, data, _laszip_payload(bytes(data)) + at, value)
    dst.write_bytes(bytes(data))
    return dst


#: LASzip VLR payload fields: compressor (uint16 at 0), coder (2), chunk size (uint32 at 12),
#: number of items (uint16 at 32), then items of type, size, version (uint16 each) from 34.
VLR_FIELDS = {
    "compressor-3": (0, "<H", 3, "laszip VLR compressor = 3"),
    "compressor-7": (0, "<H", 7, "laszip VLR compressor = 7"),
    "coder-1": (2, "<H", 1, "laszip VLR coder = 1"),
    "item-1-type-10": (34, "<H", 10, "laszip VLR item 1 = type 10 (20 bytes, version 2)"),
    "item-2-type-8": (40, "<H", 8, "laszip VLR item 2 = type 8 (8 bytes, version 2)"),
    "item-3-version-3": (50, "<H", 3, "laszip VLR item 3 = type 8 (6 bytes, version 3)"),
    "item-2-version-0": (44, "<H", 0, "laszip VLR item 2 = type 7 (8 bytes, version 0)"),
    "item-1-type-6-swapped": (34, "<H", 7, "laszip VLR item 1 = type 7 (20 bytes, version 2)"),
    # Two bytes of the chunk size (50,000 -> 2,139,079,504): lazrs allocated 73 GB for the
    # last chunk's points and aborted the process (SIGABRT) where it could not have them.
    "chunk-size-2-bytes": (12, "<I", 0x7F7FC350, "laszip VLR chunk size = 2139079504 points"),
}


def _laz_inputs(tmp: Path) -> dict[str, tuple[Path, list[str]]]:
    world = ["cloud2world", "{in}", "-o", "{out}", *WORLD]
    inputs: dict[str, tuple[Path, list[str]]] = {}
    for name, (at, fmt, value, _) in VLR_FIELDS.items():
        src = _laz_with(SIMPLE_LAZ, tmp / f"{name}.laz", at, fmt, value)
        inputs[name] = (src, ["convert", "{in}", "{out}.xyz"])
        inputs[f"{name} world"] = (src, world)
        inputs[f"{name} --stream"] = (src, [*world, "--stream"])
    # Seeded: two bytes of the laszip VLR's payload set to random values, in both fixtures
    # (simple.laz is one chunk, so any chunk size from its point count up passes the table).
    rng = np.random.default_rng(28)
    for seed in (SIMPLE_LAZ, AUTZEN):
        data = seed.read_bytes()
        payload = _laszip_payload(data)
        length = struct.unpack_from("<H", data, payload - 54 + 20)[0]
        for k in range(FLIPS):
            mutated = bytearray(data)
            for at in rng.choice(length, size=2, replace=False):
                mutated[payload + int(at)] = int(rng.integers(256))
            path = tmp / f"flip-{seed.stem}-{k}.laz"
            path.write_bytes(bytes(mutated))
            inputs[f"flip {seed.stem} {k}"] = (path, ["convert", "{in}", "{out}.xyz"])
            inputs[f"flip {seed.stem} {k} --stream"] = (path, [*world, "--stream"])
    return inputs


#: Seeded mutations of each LAZ fixture's laszip VLR.
FLIPS = 24


@pytest.fixture(scope="module")
def laz_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, Outcome]]:
    tmp = tmp_path_factory.mktemp("laz")
    return _run(tmp, _laz_inputs(tmp))


@pytest.mark.parametrize("case", list(VLR_FIELDS))
def test_laszip_vlrs_that_do_not_describe_the_points_are_refused(
    laz_runs: dict[str, tuple[Path, Outcome]], case: str
) -> None:
    """The laszip VLR against LASzip's rules and the header's point format: its compressor,
    coder, items (type, size, version in LASzip's order) and chunk size; refused before lazrs
    decodes by it, by convert, cloud2world and --stream alike."""
    field = VLR_FIELDS[case][3]
    for how in ("", " world", " --stream"):
        src, o = laz_runs[case + how]
        line = one_line(o, src)
        head = f"scan2terrain: error: {src}: {field}"
        assert line.startswith(head) and line[len(head)] in " :", line


def _sane_xyz(o: Outcome) -> None:
    """A converted cloud: the fixture's points exactly (the VLR fields lazrs does not decode by
    -- LASzip's version, options, special EVLRs -- change nothing)."""
    name = o.name.split()[1]
    seed = SIMPLE_LAZ if name == SIMPLE_LAZ.stem else AUTZEN
    written = np.loadtxt(Path(o.argv[-1]))
    from scan2terrain.readers.cloudfile import read_cloud

    np.testing.assert_allclose(written, read_cloud(seed).points, rtol=0, atol=1e-9)


def test_flipped_laszip_vlr_bytes_are_read_or_refused_never_a_signal(
    laz_runs: dict[str, tuple[Path, Outcome]],
) -> None:
    """Every seeded mutation ends with exit 0 and the fixture's points (convert) or a world
    (--stream), or exit 2 and one line naming the file: no signal, no exit 1."""
    ends: dict[str, int] = {}
    for name, (src, o) in laz_runs.items():
        if not name.startswith("flip "):
            continue
        assert o.signal is None and o.exit in (0, 2), o.describe()
        ends[name] = int(o.exit)
        if o.exit == 2:
            one_line(o, src)
        elif "--stream" not in name:
            _sane_xyz(o)
        else:
            assert (Path(o.argv[3]) / "scan2terrain.yaml").is_file(), o.describe()
    # Both ends are met (the seeds are fixed): harmless fields read, the rest refused.
    assert set(ends.values()) == {0, 2}, ends


# --- CSV/XYZ and PCD: the coordinates themselves --------------------------------------------

PCD_HEAD = (
    "# .PCD v0.7\nVERSION 0.7\nFIELDS {f}\nSIZE {s}\nTYPE {t}\nCOUNT 1 1 1\nWIDTH {n}\n"
    "HEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {d}\n"
)


def _text_with(src: Path, dst: Path, line: int, column: int, value: str) -> Path:
    """``src`` with the number in ``column`` (0-based) of ``line`` (1-based) replaced."""
    lines = src.read_text().splitlines()
    sep = "," if "," in lines[line - 1] else " "
    cells = lines[line - 1].split(sep)
    cells[column] = value
    lines[line - 1] = sep.join(cells)
    dst.write_text("\n".join(lines) + "\n")
    return dst


def _pcd_binary(path: Path, xyz: np.ndarray, code: str, data: str = "binary") -> Path:
    rec = np.ascontiguousarray(xyz, dtype=f"<{code}")
    size = rec.dtype.itemsize
    head = PCD_HEAD.format(f="x y z", s=f"{size} {size} {size}", t="F F F", n=len(rec), d=data)
    path.write_bytes(head.encode() + rec.tobytes())
    return path


def _pcd_compressed(path: Path, xyz: np.ndarray) -> Path:
    import open3d

    cloud = open3d.geometry.PointCloud(open3d.utility.Vector3dVector(xyz))
    assert open3d.io.write_point_cloud(path, cloud, write_ascii=False, compressed=True)
    assert b"DATA binary_compressed" in path.read_bytes()[:400]
    return path


#: A small scene, metres, and the same with one number made absurd.
SCENE = np.array([[0.0, 0.0, 0.0], [1.5, -2.0, 0.25], [3.0, 1.0, 2.0], [-4.0, 2.5, 1.0]])


def _scene_with(row: int, axis: int, value: float) -> np.ndarray:
    xyz: np.ndarray = SCENE.copy()
    xyz[row, axis] = value
    return xyz


#: name -> (how the input is made, the field and value of its refusal).
TEXT_AND_PCD: dict[str, tuple[Callable[[Path], Path], str]] = {
    # 106 points of Autzen as CSV with a quoted header: data row 5 is line 6, X column 2.
    "csv-x-1e300": (
        lambda t: _text_with(AUTZEN_CSV, t / "x300.txt", 6, 2, "1e300"),
        "line 6: x = 1e+300 m",
    ),
    "csv-z-denormal": (
        lambda t: _text_with(AUTZEN_CSV, t / "zden.txt", 10, 5, "4.9e-324"),
        "line 10: z = 4.94066e-324 m",
    ),
    "csv-y--1e17": (
        lambda t: _text_with(AUTZEN_CSV, t / "y17.txt", 107, 3, "-1e17"),
        "line 107: y = -1e+17 m",
    ),
    "xyz-y-1e17": (
        lambda t: _text_with(STREET, t / "y17.xyz", 3, 1, "1e17"),
        "line 3: y = 1e+17 m",
    ),
    "xyz-x-1e-300": (
        lambda t: _text_with(STREET, t / "x-300.xyz", 33656, 0, "1e-300"),
        "line 33656: x = 1e-300 m",
    ),
    "xyz-comments": (  # lines are the file's, comments and blank lines counted
        lambda t: _write(t / "c.xyz", "# a comment\n\n1 2 3\n# another\n\n4 2e9 6\n"),
        "line 6: y = 2e+09 m",
    ),
    "pcd-ascii-1e300": (
        lambda t: _write(
            t / "a.pcd",
            PCD_HEAD.format(f="x y z", s="4 4 4", t="F F F", n=3, d="ascii")
            + "1 2 3\nnan nan nan\n1e300 0 0\n",
        ),
        "line 14: x = 1e+300 m",
    ),
    "pcd-binary-f8-1e17": (
        lambda t: _pcd_binary(t / "b8.pcd", _scene_with(2, 0, 1e17), "f8"),
        "point 2: x = 1e+17 m",
    ),
    "pcd-binary-f4-denormal": (
        lambda t: _pcd_binary(t / "b4.pcd", _scene_with(1, 1, 1e-40), "f4"),
        "point 1: y = 9.99995e-41 m",
    ),
    "pcd-compressed-5e9": (
        lambda t: _pcd_compressed(t / "c.pcd", _scene_with(3, 2, 5e9)),
        "point 3: z = 5e+09 m",
    ),
}


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def text_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, Outcome]]:
    tmp = tmp_path_factory.mktemp("text")
    world = ["cloud2world", "{in}", "-o", "{out}", *WORLD]
    inputs: dict[str, tuple[Path, list[str]]] = {}
    for name, (make, _) in TEXT_AND_PCD.items():
        src = make(tmp)
        inputs[name] = (src, world)
        inputs[f"{name} --stream"] = (src, [*world, "--stream"])
    return _run(tmp, inputs)


@pytest.mark.parametrize("case", list(TEXT_AND_PCD))
def test_text_and_pcd_coordinates_beyond_the_physical_world_are_refused(
    text_runs: dict[str, tuple[Path, Outcome]], case: str
) -> None:
    """A coordinate of 1e300, 1e17 or 2e9 m, or a denormal: the line (text) or point (binary),
    the axis and the value, the same on both paths."""
    src, default = text_runs[case]
    _, streamed = text_runs[f"{case} --stream"]
    line = one_line(default, src)
    field = TEXT_AND_PCD[case][1]
    assert line.startswith(f"scan2terrain: error: {src}: {field} makes no sense"), line
    assert one_line(streamed, src) == line


def test_coordinates_within_the_limits_and_no_return_marks_are_read(tmp_path: Path) -> None:
    """0, the limits themselves and the smallest normal float32 are coordinates; NaN and inf
    are the formats' no-return marks (PCL's organised clouds), dropped as before."""
    from scan2terrain.readers._limits import MIN_COORDINATE_M
    from scan2terrain.readers.cloudfile import read_cloud

    edge = np.array(
        [[0.0, -0.0, MAX_COORDINATE_M], [-MAX_COORDINATE_M, MIN_COORDINATE_M, 1.0],
         [np.nan, 1.0, 2.0], [1.0, np.inf, 2.0]]
    )  # fmt: skip
    text = "\n".join(" ".join(repr(float(v)) for v in row) for row in edge) + "\n"
    for path in (
        _write(tmp_path / "e.xyz", text),
        _write(tmp_path / "e.csv", "x,y,z\n" + text.replace(" ", ",")),
        _pcd_binary(tmp_path / "e8.pcd", edge, "f8"),
        _write(
            tmp_path / "ea.pcd",
            PCD_HEAD.format(f="x y z", s="8 8 8", t="F F F", n=4, d="ascii") + text,
        ),
    ):
        np.testing.assert_array_equal(read_cloud(path).points, edge[:2], err_msg=str(path))
    office = read_cloud(OFFICE)  # NaN: no return
    assert office.records > len(office.points) > 0


# --- a fixture CSV at the default resolution --------------------------------------------------


@pytest.mark.parametrize(
    "extra",
    [
        [],
        ["--geometry", "voxels"],  # 20 s in a 4e9-cell numpy allocation, then exit 1
        ["--stream"],
    ],
)
def test_a_survey_csv_at_the_default_resolution_is_refused_quickly(
    tmp_path: Path, extra: list[str]
) -> None:
    """Autzen's 106 points span 3.2 x 4.4 km: at 0.05 m (the default resolution, given) that
    is 65,000 x 88,000 cells, over max_pixels; refused by the cell budget before a grid of them
    is allocated, on every geometry and path."""
    out = tmp_path / "out"
    out.mkdir()
    argv = ["cloud2world", str(AUTZEN_CSV), "-o", str(out / "o"), *WORLD, "--resolution", "0.05"]
    (o,) = run_cases(
        [Case("csv", [*argv, *extra], str(out))],
        limit_bytes=LIMIT_BYTES,
        timeout_s=TIMEOUT_S,
        workdir=tmp_path / "_r",
    )
    line = one_line(o, AUTZEN_CSV)
    assert re.search(r"span 64966 x \d+ cells of 0.05 m, over --max-pixels 268435456", line), line
    assert o.seconds < 10, o.describe()


# --- LAZ of variable-size chunks (COPC's) on the streamed path -------------------------------


def _variable_chunk_laz(path: Path, sizes: tuple[int, ...] = (400, 300, 365)) -> Path:
    """simple.laz's points compressed again by lazrs in chunks of ``sizes`` points (a chunk
    size of 2^32 - 1 in the laszip VLR: the chunk table holds each chunk's point count)."""
    import io

    import laspy
    import lazrs  # type: ignore[import-untyped]

    src = SIMPLE_LAZ.read_bytes()
    raw = laspy.read(SIMPLE_LAZ).points.array.tobytes()
    record = len(raw) // sum(sizes)
    vlr = lazrs.LazVlr.new_for_compression(3, 0, True)
    out = io.BytesIO()
    compressor = lazrs.LasZipCompressor(out, vlr)
    bounds = np.cumsum((0, *sizes)) * record
    compressor.compress_chunks([raw[a:b] for a, b in itertools.pairwise(bounds)])
    compressor.done()
    data = out.getvalue()
    start = struct.unpack_from("<I", src, 96)[0]
    table = struct.unpack_from("<q", data, 0)[0] + start  # its offset, from the file's start
    head = bytearray(src[:start])
    payload = _laszip_payload(src)
    head[payload : payload + 52] = bytes(vlr.record_data())
    path.write_bytes(bytes(head) + struct.pack("<q", table) + data[8:])
    return path


def test_a_laz_of_variable_size_chunks_streams_the_points_it_holds(tmp_path: Path) -> None:
    """lazrs seeks into such a file wrongly (zeros or other points: it takes a point's place
    in its chunk as its index modulo 2^32 - 1): a piece read from point 500 held zeros, which
    widened the grid to 639,000 x 851,000 cells. Read from the start now, and planned as one
    piece: the same world as the default path."""
    from scan2terrain.readers.cloudfile import read_cloud
    from scan2terrain.readers.las import iter_las, las_info

    path = _variable_chunk_laz(tmp_path / "variable.laz")
    points = read_cloud(path).points
    np.testing.assert_array_equal(points, read_cloud(SIMPLE_LAZ).points)
    assert las_info(path).variable_chunks and not las_info(SIMPLE_LAZ).variable_chunks
    for start in (100, 400, 500, 1000):
        got = np.concatenate(list(iter_las(path, start=start, count=50, step=17)))
        np.testing.assert_array_equal(got, points[start : start + 50])
    outs = {}
    for name, extra in (("default", []), ("stream", ["--stream", "--chunk-points", "100"])):
        out = tmp_path / name
        argv = ["cloud2world", str(path), "-o", str(out), *WORLD, "--resolution", "1", *extra]
        (o,) = run_cases([Case(name, argv, str(tmp_path))], limit_bytes=LIMIT_BYTES,
                         timeout_s=TIMEOUT_S, workdir=tmp_path / f"_{name}")  # fmt: skip
        assert o.exit == 0, o.describe()
        outs[name] = {
            str(p.relative_to(out)): p.read_bytes()
            for p in out.rglob("*")
            if p.is_file() and p.name not in ("scan2terrain.yaml", "octree.bt")
        }
    assert outs["stream"] == outs["default"]
