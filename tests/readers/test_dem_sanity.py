"""A GeoTIFF DEM's numbers must make sense (issue 28): against the file (strips inside it, not
over its header or directory, byte counts that fit the samples), against TIFF's rules (a sample
format of numbers, bits that match it, data that decodes to the size the tags say) and against
the physical world (pixel sizes, the raster's placement, elevations: readers/_limits.py).

Each quoted case is a fixture DEM with a field changed, run through ``dem2world``: exit 2, one
line naming the file, the field and the value, nothing written. The seeded fuzz flips bytes in
the directories of both fixtures: every run refuses in one line or writes a world whose numbers
are sane.
"""

from __future__ import annotations

import math
import random
import struct
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import tifffile
import yaml
from lxml import etree
from PIL import Image

from scan2terrain.cli import main
from scan2terrain.readers._limits import MAX_COORDINATE_M, MAX_ELEVATION_M
from scan2terrain.readers.dem import read_dem
from tests.fixtures import MOON, SFBAY
from tests.geotiff import write_geotiff
from tests.mutation_runner import Case, Outcome, run_cases

# --- editing a TIFF's first directory --------------------------------------------------------


def entries(data: bytes) -> dict[int, int]:
    """Tag code -> offset of its 12-byte entry in a little-endian TIFF's first IFD."""
    assert data[:4] == b"II*\x00"
    ifd = struct.unpack_from("<I", data, 4)[0]
    n = struct.unpack_from("<H", data, ifd)[0]
    return {struct.unpack_from("<H", data, ifd + 2 + 12 * i)[0]: ifd + 2 + 12 * i for i in range(n)}


def values_at(data: bytes, code: int) -> int:
    """Where a tag's values are: in its entry when they fit in 4 bytes, else where it points."""
    entry = entries(data)[code]
    kind, count = struct.unpack_from("<HI", data, entry + 2)
    size = {1: 1, 2: 1, 3: 2, 4: 4, 11: 4, 12: 8, 16: 8}[kind] * count
    return entry + 8 if size <= 4 else int(struct.unpack_from("<I", data, entry + 8)[0])


def put(data: bytes, at: int, fmt: str, *value: object) -> bytes:
    out = bytearray(data)
    struct.pack_into(fmt, out, at, *value)
    return bytes(out)


def tag(code: int, fmt: str, *value: object, index: int = 0) -> Callable[[bytes], bytes]:
    """An edit: the ``index``-th value of tag ``code`` set to ``value`` (packed as ``fmt``)."""
    size = struct.calcsize(fmt) // len(value)
    return lambda data: put(data, values_at(data, code) + index * size, fmt, *value)


def both(*edits: Callable[[bytes], bytes]) -> Callable[[bytes], bytes]:
    def edit(data: bytes) -> bytes:
        for e in edits:
            data = e(data)
        return data

    return edit


def packbits_literal(raw: bytes) -> bytes:
    """A valid PackBits stream of ``raw``: literal runs of up to 128 bytes."""
    chunks = [raw[i : i + 128] for i in range(0, len(raw), 128)]
    return b"".join(bytes([len(c) - 1]) + c for c in chunks)


def packbits_dem(data: bytes) -> bytes:
    """A one-strip DEM whose strip is re-encoded as genuine PackBits, appended to the file."""
    offset = values_at(data, 273)
    start, count = struct.unpack_from("<I", data, offset)[0], values_at(data, 279)
    length = struct.unpack_from("<I", data, count)[0]
    encoded = packbits_literal(data[start : start + length])
    data = put(data, offset, "<I", len(data))
    data = put(data, count, "<I", len(encoded))
    data = put(data, values_at(data, 259), "<H", 32773)
    return data + encoded


# --- the quoted cases ------------------------------------------------------------------------

PIXEL_SCALE, TIEPOINT = 33550, 33922

#: name -> (fixture, edit, what the one line must hold: the field and the value).
QUOTED: dict[str, tuple[Path, Callable[[bytes], bytes], tuple[str, ...]]] = {
    # A world 3.3e301 m wide was written.
    "pixelscale-1e300": (
        MOON,
        both(tag(PIXEL_SCALE, "<d", 1e300), tag(PIXEL_SCALE, "<d", 1e300, index=1)),
        ("ModelPixelScale pixel width = 1e+300 m", "1e-06..120000 m"),
    ),
    "pixelscale-1e-300": (
        MOON,
        both(tag(PIXEL_SCALE, "<d", 1e-300), tag(PIXEL_SCALE, "<d", 1e-300, index=1)),
        ("ModelPixelScale pixel width = 1e-300 m",),
    ),
    "pixelscale-1e-9": (
        MOON,
        both(tag(PIXEL_SCALE, "<d", 1e-9), tag(PIXEL_SCALE, "<d", 1e-9, index=1)),
        ("ModelPixelScale pixel width = 1e-09 m",),
    ),
    "pixelscale-height-1e-300": (
        MOON,
        tag(PIXEL_SCALE, "<d", 1e-300, index=1),
        ("ModelPixelScale pixel height = 1e-300 m",),
    ),
    # Geographic: a pixel scale in degrees.
    "sfbay-pixelscale-1e-300": (
        SFBAY,
        both(tag(PIXEL_SCALE, "<d", 1e-300), tag(PIXEL_SCALE, "<d", 1e-300, index=1)),
        ("ModelPixelScale pixel width = 1e-300 degrees", "1e-11..1 degrees"),
    ),
    "sfbay-pixelscale-3": (
        SFBAY,
        tag(PIXEL_SCALE, "<d", 3.0),
        ("ModelPixelScale pixel width = 3 degrees",),
    ),
    # The header read as samples: heights up to 2.6e38 m.
    "stripoffset-0": (MOON, tag(273, "<I", 0), ("StripOffsets[0] = 0", "header")),
    "sfbay-stripoffset-0": (SFBAY, tag(273, "<I", 0), ("StripOffsets[0] = 0", "header")),
    "sfbay-stripoffset-ifd": (SFBAY, tag(273, "<I", 100, index=4), ("StripOffsets[4] = 100",)),
    "stripoffset-geokeys": (MOON, tag(273, "<I", 300), ("StripOffsets[0] = 300", "34735")),
    "tiepoint-1e308": (
        MOON,
        tag(TIEPOINT, "<d", 1e308, index=3),
        ("ModelTiepoint west edge = 1e+308 m", "0..1e+09 m"),
    ),
    "sfbay-tiepoint-1e308": (
        SFBAY,
        tag(TIEPOINT, "<d", 1e308, index=3),
        ("ModelTiepoint west edge = 1e+308 degrees",),
    ),
    "tiepoint-north-1e12": (
        MOON,
        tag(TIEPOINT, "<d", 1e12, index=4),
        ("ModelTiepoint north edge = 1e+12 m",),
    ),
    # The tie point's raster position (column 1e15): the corner 2.4e15 m away.
    "raster-position-huge": (
        MOON,
        tag(TIEPOINT, "<d", 1e15),
        ("ModelTiepoint west edge = -2.42661e+15 m",),
    ),
    "sampleformat-void": (MOON, tag(339, "<H", 4), ("SampleFormat = 4 (void)",)),
    "width-1": (MOON, tag(256, "<H", 1), ("ImageWidth = 1:", "at least 2 x 2")),
    "length-1": (MOON, tag(257, "<H", 1), ("ImageLength = 1:", "at least 2 x 2")),
    # float32 samples read as float16.
    "bits-16": (MOON, tag(258, "<H", 16), ("StripByteCounts[0] = 4356", "2178")),
    "sfbay-bits-16": (SFBAY, tag(258, "<H", 16), ("StripByteCounts[0] = 7740", "3870")),
    "bits-24-float": (MOON, tag(258, "<H", 24), ("BitsPerSample = 24", "SampleFormat = 3")),
    "bits-12-uint": (
        MOON,
        both(tag(258, "<H", 12), tag(339, "<H", 1)),
        ("BitsPerSample = 12", "SampleFormat = 1"),
    ),
    # Uncompressed data read as PackBits.
    "packbits": (MOON, tag(259, "<H", 32773), ("Compression = 32773 (PACKBITS)", "strip 0")),
    "sfbay-packbits": (SFBAY, tag(259, "<H", 32773), ("Compression = 32773 (PACKBITS)",)),
    "bytecount-short": (MOON, tag(279, "<I", 4000), ("StripByteCounts[0] = 4000", "4356")),
    # float32 elevations read as int32: a billion metres.
    "sampleformat-int": (MOON, tag(339, "<H", 2), ("elevation", "100000 m")),
    # Found by sweeping every numeric field (not quoted): a numpy warning before the refusal
    # (two lines), a division by zero (exit 1) and a world of size 0 on a sphere of 1e-300 m.
    "pixelscale-inf": (MOON, tag(PIXEL_SCALE, "<d", math.inf), ("ModelPixelScale = (inf, ",)),
    "sfbay-semimajor-denormal": (
        SFBAY,
        tag(34736, "<d", 5e-324, index=1),
        ("GeogSemiMajorAxisGeoKey = 4.94066e-324 m", "10..1e+08 m"),
    ),
    "sfbay-semimajor-tiny": (
        SFBAY,
        tag(34736, "<d", 1e-300, index=1),
        ("GeogSemiMajorAxisGeoKey = 1e-300 m",),
    ),
    "sfbay-semimajor-negative": (
        SFBAY,
        tag(34736, "<d", -6378137.0, index=1),
        ("GeogSemiMajorAxisGeoKey = -6.37814e+06 m",),
    ),
    "sfbay-inverse-flattening-tiny": (
        SFBAY,
        both(tag(34736, "<d", 1e-300), tag(34736, "<d", 1737400.0, index=1)),
        ("semi-minor axis (from GeogInvFlatteningGeoKey = 1e-300) = ",),
    ),
}


def _one_line_refusal(
    source: Path, work: Path, code: int, stdout: str, err: str, *wanted: str
) -> None:
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"scan2terrain: error: {source}: "), lines[0]
    for text in wanted:
        assert text in lines[0], lines[0]
    assert stdout == "" and list(work.iterdir()) == []


def run(capsys: pytest.CaptureFixture[str], *args: object) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("name", sorted(QUOTED))
def test_quoted_dem_is_refused_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str
) -> None:
    fixture, edit, wanted = QUOTED[name]
    source = tmp_path / f"{name}.tif"
    source.write_bytes(edit(fixture.read_bytes()))
    work = tmp_path / "work"
    work.mkdir()
    code, stdout, err = run(capsys, "dem2world", source, "-o", work / "out")
    _one_line_refusal(source, work, code, stdout, err, *wanted)


# --- what stays accepted -----------------------------------------------------------------------


def test_genuine_packbits_dem_is_read(tmp_path: Path) -> None:
    path = tmp_path / "packbits.tif"
    path.write_bytes(packbits_dem(MOON.read_bytes()))
    with tifffile.TiffFile(path) as tif:
        assert tif.pages[0].compression == 32773
    np.testing.assert_array_equal(read_dem(path).heights, read_dem(MOON).heights)


@pytest.mark.parametrize(
    "how",
    [
        {"compression": "zlib"},
        {"compression": "lzma"},
        {"tile": (16, 16)},
        {"tile": (16, 16), "compression": "zlib"},
        {"rowsperstrip": 8},
        {"rowsperstrip": 8, "compression": "zlib"},
    ],
    ids=["deflate", "lzma", "tiled", "tiled-deflate", "strips", "strips-deflate"],
)
def test_strips_tiles_and_codecs_are_read(tmp_path: Path, how: dict[str, Any]) -> None:
    raster = (np.arange(35 * 37, dtype=np.float32).reshape(35, 37) - 600) * 1.5
    tags = [
        (33550, "d", 3, (2.0, 2.0, 0.0), True),
        (33922, "d", 6, (0.0, 0.0, 0.0, 5e5, 4e6, 0.0), True),
        (34735, "H", 16, (1, 1, 0, 3, 1024, 0, 1, 1, 1025, 0, 1, 1, 3076, 0, 1, 9001), True),
    ]
    path = tmp_path / "d.tif"
    tifffile.imwrite(path, raster, extratags=tags, **how)
    np.testing.assert_array_equal(read_dem(path).heights, raster[::-1])


def test_int16_with_a_predictor_is_read(tmp_path: Path) -> None:
    raster = (np.arange(40 * 30).reshape(40, 30) % 700 - 300).astype(np.int16)
    path = tmp_path / "d.tif"
    tifffile.imwrite(
        path,
        raster,
        compression="zlib",
        predictor=True,
        extratags=[
            (33550, "d", 3, (1.0, 1.0, 0.0), True),
            (33922, "d", 6, (0.0,) * 6, True),
            (34735, "H", 8, (1, 1, 0, 1, 1024, 0, 1, 1), True),
        ],
    )
    np.testing.assert_array_equal(read_dem(path).heights, raster[::-1])


def test_limits_at_their_edges_are_accepted(tmp_path: Path) -> None:
    """Micrometre pixels and pixels of about a degree in metres (projected), a corner just
    inside 1e9 m, the deepest and highest elevations a planet has."""
    raster = np.array([[-1e4, 2.2e4], [0.0, 8848.0]], np.float32)
    fine = read_dem(write_geotiff(tmp_path / "a.tif", raster, scale=(1e-6, 1e-6)))
    assert fine.pixel_size == (1e-6, 1e-6)
    coarse = write_geotiff(tmp_path / "b.tif", raster, scale=(1.2e5, 1.2e5), tie=(9e8, 9e8))
    assert read_dem(coarse).origin == (9e8, 9e8 - 2.4e5)


# --- elevations and --max-elevation ----------------------------------------------------------


def _tall(tmp: Path, top: float) -> Path:
    raster = np.array([[0.0, 10.0, 20.0], [5.0, top, -9999.0], [1.0, 2.0, 3.0]], np.float32)
    return write_geotiff(tmp / "tall.tif", raster, nodata="-9999")


def test_elevation_beyond_the_limit_is_refused_and_max_elevation_widens_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    source = _tall(tmp_path, 1.5e5)
    work = tmp_path / "work"
    work.mkdir()
    code, stdout, err = run(capsys, "dem2world", source, "-o", work / "out")
    _one_line_refusal(
        source,
        work,
        code,
        stdout,
        err,
        "elevation (column 1, row 1) = 150000 m",
        "0..100000 m",
        "--max-elevation",
    )
    code, stdout, err = run(
        capsys, "dem2world", source, "-o", work / "out", "--max-elevation", "2e5"
    )
    assert code == 0, err
    written = yaml.safe_load((work / "out/scan2terrain.yaml").read_text())
    assert written["dem"]["max_elevation"] == 2e5
    conf = tmp_path / "c.yaml"
    conf.write_text("dem:\n  max_elevation: 160000\n")
    code, _, err = run(capsys, "dem2world", source, "-o", tmp_path / "w2", "--config", conf)
    assert code == 0, err


def test_nodata_is_not_an_elevation(tmp_path: Path) -> None:
    """GDAL's nodata of -FLT_MAX, and a -1e30 marker, are far below any planet's floor."""
    raster = np.array([[-1e30, 5.0], [6.0, 7.0]], np.float32)
    dem = read_dem(write_geotiff(tmp_path / "d.tif", raster, nodata="-1e30"))
    assert dem.z_min == 5.0 and int(dem.valid.sum()) == 3


def test_max_elevation_must_be_a_positive_number(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    for bad in ("0", "-5", "nan", "inf", "1e300"):
        try:
            code = main(["dem2world", str(MOON), "-o", str(tmp_path / "w"), "--max-elevation", bad])
        except SystemExit as exc:
            code = int(str(exc.code))
        err = capsys.readouterr().err
        assert code == 2 and "--max-elevation" in err and len(err.strip().splitlines()) == 1, err
        assert not (tmp_path / "w").exists()


# --- the seeded fuzz of the directory ----------------------------------------------------------

#: Cases per fixture; a 2-core machine runs the 48 in about 20 s.
FLIPS = 24
SEED = 28


def directory_flips(data: bytes, rng: random.Random, n: int) -> list[tuple[str, bytes]]:
    """``n`` copies with 1, 2 or 4 bytes of the first IFD (the directory itself for half of
    them, its tags' values too for the rest) set to random values."""
    ifd = struct.unpack_from("<I", data, 4)[0]
    end = ifd + 2 + 12 * struct.unpack_from("<H", data, ifd)[0] + 4
    first_strip = struct.unpack_from("<I", data, values_at(data, 273))[0]
    out = []
    for k in range(n):
        hi = end if k % 2 == 0 else first_strip
        b = bytearray(data)
        for _ in range(rng.choice((1, 2, 4))):
            b[rng.randrange(ifd, hi)] = rng.randrange(256)
        out.append((f"flip{k}", bytes(b)))
    return out


def _numbers(text: str) -> list[float]:
    found = []
    for token in text.split():
        try:
            found.append(float(token))
        except ValueError:
            continue
    return found


def insane(folder: Path) -> list[str]:
    """What is wrong with the numbers of a written DEM world (empty: nothing)."""
    found = []
    for sdf in [*folder.glob("*.sdf"), *folder.glob("*.world"), *folder.glob("models/*/model.sdf")]:
        root = etree.parse(str(sdf)).getroot()
        for el in root.iter():
            if not isinstance(el.tag, str) or el.text is None:
                continue
            values = _numbers(el.text)
            if any(not math.isfinite(v) or abs(v) > MAX_COORDINATE_M for v in values):
                found.append(f"{sdf.name} <{el.tag}> {el.text.strip()[:80]}")
            parent = el.getparent()
            if el.tag == "size" and parent is not None and parent.tag == "heightmap":
                if len(values) != 3 or not (values[0] > 0 and values[1] > 0 and values[2] >= 0):
                    found.append(f"{sdf.name} heightmap size {values}")
                elif values[2] > 2 * MAX_ELEVATION_M:
                    found.append(f"{sdf.name} heightmap size.z {values[2]}")
            if el.tag in ("pose", "pos") and len(values) >= 3 and abs(values[2]) > MAX_ELEVATION_M:
                found.append(f"{sdf.name} <{el.tag}> z {values[2]}")
    for png in folder.glob("models/*/materials/textures/heightmap.png"):
        with Image.open(png) as image:
            pixels = np.asarray(image)
        full = 65535 if pixels.dtype == np.uint16 else 255
        if pixels.max() not in (0, full):  # size.z is the brightest pixel's height
            found.append(f"{png.name}: brightest pixel {pixels.max()} of {full}")
    spawn = yaml.safe_load((folder / "spawn.yaml").read_text())
    for key, world in spawn.items():
        if isinstance(world, dict):
            pose = world.get("pose", [])
            if not all(math.isfinite(v) and abs(v) <= MAX_COORDINATE_M for v in pose):
                found.append(f"spawn.yaml {key} pose {pose}")
    return found


def test_flipped_directory_bytes_refuse_or_give_a_sane_world(tmp_path: Path) -> None:
    rng = random.Random(SEED)
    cases, sources = [], {}
    for fixture in (MOON, SFBAY):
        for name, data in directory_flips(fixture.read_bytes(), rng, FLIPS):
            label = f"{fixture.stem}-{name}"
            folder = tmp_path / label
            folder.mkdir()
            source = folder / f"{label}.tif"
            source.write_bytes(data)
            sources[label] = source
            argv = ["dem2world", str(source), "-o", str(folder / "out"), "-q"]
            cases.append(Case(label, argv, str(folder)))
    outcomes = run_cases(cases, limit_bytes=3 << 30, workdir=tmp_path / "_runner", timeout_s=60)
    problems: list[str] = []
    refused = 0
    for o in outcomes:
        problems += [f"{o.name}: {p}" for p in _problems(o, sources[o.name])]
        refused += o.exit == 2
    assert not problems, "\n".join(problems)
    assert refused >= len(cases) // 4  # most flips break something a reader must see


def _problems(o: Outcome, source: Path) -> list[str]:
    lines = o.stderr.strip().splitlines()
    if o.exit == 2:
        found = []
        if len(lines) != 1 or not lines[0].startswith(f"scan2terrain: error: {source}: "):
            found.append(f"refusal is not one line naming the file: {lines}")
        if o.new_files:
            found.append(f"refused but wrote {o.new_files[:3]}")
        return found
    if o.exit != 0:
        return [o.describe()]
    if any("encountered" in line for line in lines):  # numpy's floating-point warnings
        return [f"warnings: {lines}"]
    return insane(source.parent / "out")


# --- every numeric field at its extremes (slow: CI) -------------------------------------------

_FORMATS = {1: "<B", 3: "<H", 4: "<I", 11: "<f", 12: "<d", 16: "<Q", 6: "<b", 8: "<h", 9: "<i"}
_FLOATS = {
    "zero": 0.0,
    "denormal": 5e-324,
    "tiny": 1e-300,
    "huge": 1e300,
    "neghuge": -1e300,
    "nan": math.nan,
    "inf": math.inf,
    "minus1": -1.0,
}


def field_extremes(data: bytes) -> list[tuple[str, bytes]]:
    """Copies with one value of one numeric tag (its first, second, fourth, fifth and last)
    set to 0, 1, 2, half and all of its type's range (integers) or 0, a denormal, 1e-300,
    +-1e300, NaN, infinity and -1 (floats)."""
    out = []
    for code, entry in entries(data).items():
        kind, count = struct.unpack_from("<HI", data, entry + 2)
        if kind not in _FORMATS:
            continue
        fmt = _FORMATS[kind]
        step = struct.calcsize(fmt)
        at = values_at(data, code)
        if fmt in ("<f", "<d"):
            values: dict[str, float] = _FLOATS
        else:
            signed = fmt[1].islower()  # b, h, i
            top = (1 << (8 * step - signed)) - 1
            values = {"zero": 0, "one": 1, "two": 2, "half": top // 2, "max": top}
        for index in sorted({0, 1, 3, 4, count - 1} & set(range(count))):
            for name, value in values.items():
                out.append((f"{code}-{index}-{name}", put(data, at + index * step, fmt, value)))
    return out


@pytest.mark.slow
def test_every_numeric_field_at_its_extremes_refuses_or_gives_a_sane_world(
    tmp_path: Path,
) -> None:
    """About 380 runs, 45 s on two cores. Found: an infinite pixel scale warned before its
    refusal (two lines), an ellipsoid's semi-major axis of 5e-324 m divided by zero (exit 1)
    and one of 1e-300 m made a world of size 0."""
    cases, sources = [], {}
    for fixture in (MOON, SFBAY):
        for name, data in field_extremes(fixture.read_bytes()):
            label = f"{fixture.stem}-{name}"
            folder = tmp_path / label
            folder.mkdir()
            source = folder / f"{label}.tif"
            source.write_bytes(data)
            sources[label] = source
            argv = ["dem2world", str(source), "-o", str(folder / "out"), "-q"]
            cases.append(Case(label, argv, str(folder)))
    outcomes = run_cases(cases, limit_bytes=3 << 30, workdir=tmp_path / "_runner", timeout_s=60)
    problems = [f"{o.name}: {p}" for o in outcomes for p in _problems(o, sources[o.name])]
    assert not problems, "\n".join(problems)
    assert sum(o.exit == 2 for o in outcomes) > len(cases) // 3
