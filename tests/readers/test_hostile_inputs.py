"""Issue 13, "nothing lost, nothing hung, nothing absurd": inputs a tester fed the readers that
hung, ate memory or disk, crashed (exit 1) or were read as nonsense (exit 0), each refused now
with one line naming the file (exit 2).

What could hang or exhaust memory runs through the real commands in
:func:`tests.mutation_runner.run_cases` (forked children under an address-space limit and an
alarm), once for the module (:func:`commands`): a regression fails its test instead of hanging
the suite or killing the session. The rest is called in-process.
"""

from __future__ import annotations

import gzip
import math
import os
import re
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pytest

from scan2terrain.errors import InputError
from tests.fixtures import FIXTURES, MOON, NAV2, ROOT, SFBAY, SIMPLE_LAS
from tests.mutation_runner import Case, Outcome, run_cases

#: Address space of a command's child: a normal run takes ~1.2 GiB (see test_mutations).
LIMIT_BYTES = 3 << 30
#: Seconds before a command counts as hung.
TIMEOUT_S = 30


def one_line(o: Outcome) -> str:
    """The command's only stderr line, which must be an error line (exit 2)."""
    lines = o.stderr.strip().splitlines()
    assert o.exit == 2 and o.signal is None, o.describe()
    assert len(lines) == 1 and lines[0].startswith("scan2terrain: error: "), o.describe()
    return lines[0]


# --- the commands, run once for the module --------------------------------------------------------


def _room_bag(folder: Path) -> Path:
    from tests.seeds import room

    path = folder / "room.bag"
    room("tf").write(path, "ros1")
    return path


def _scan_bomb(path: Path, lines: int = 20_000_000) -> Path:
    """The tester's .dat.gz: 20 M lines of "0 0 0" (one scan, 0.5 MB compressed)."""
    block = b"0 0 0\n" * 1_000_000
    with gzip.open(path, "wb", compresslevel=1) as f:
        for _ in range(lines // 1_000_000):
            f.write(block)
    return path


def _pole_dem(path: Path) -> Path:
    """The SF Bay GeoTIFF with its tie point's latitude set to 89.99 degrees."""
    from tests.seeds import tiff_entries

    data = bytearray(SFBAY.read_bytes())
    ties = struct.unpack_from("<I", data, tiff_entries(bytes(data))[33922] + 8)[0]
    struct.pack_into("<d", data, ties + 32, 89.99)
    path.write_bytes(bytes(data))
    return path


@pytest.fixture(scope="module")
def commands(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, Outcome]]:
    """name -> (the hostile input, how its command ended)."""
    tmp = tmp_path_factory.mktemp("hostile")
    fifos = tmp / "fifos"
    fifos.mkdir()
    for name in ("t.bt", "scan.dat", "b.bag", "traj.txt", "d.tif", "i.png", "m.yaml", "c.pcd",
                 "c.las", "c.laz", "c.xyz", "img.pgm", "s.dat.gz"):  # fmt: skip
        os.mkfifo(fifos / name)
    (tmp / "folder.bt").mkdir()
    (tmp / "folder.tif").mkdir()
    (tmp / "zero.bt").symlink_to("/dev/zero")
    (tmp / "zero.las").symlink_to("/dev/zero")
    bag = _room_bag(tmp)
    map_yaml = tmp / "m.yaml"
    map_yaml.write_text(
        f"image: {fifos / 'img.pgm'}\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    rosbag2 = tmp / "rosbag2"  # a genuine metadata.yaml, and a FIFO where its .db3 should be
    rosbag2.mkdir()
    shutil.copyfile(FIXTURES / "bags/bag2_derived_sick_lms1xx_db3/metadata.yaml",
                    rosbag2 / "metadata.yaml")  # fmt: skip
    os.mkfifo(rosbag2 / "bag2_derived_sick_lms1xx_db3.db3")

    world = ["--simulator", "gz", "--no-preview"]
    inputs: dict[str, tuple[Path, list[str]]] = {
        "fifo-bt": (fifos / "t.bt", ["octree2world", "{in}", "-o", "{out}", *world]),
        "fifo-scan": (fifos / "scan.dat", ["octree2world", "{in}", "-o", "{out}", *world]),
        "fifo-scan-gz": (fifos / "s.dat.gz", ["octree2world", "{in}", "-o", "{out}", *world]),
        "dev-zero": (Path("/dev/zero"), ["octree2world", "{in}", "-o", "{out}", *world]),
        "link-zero-bt": (tmp / "zero.bt", ["octree2world", "{in}", "-o", "{out}", *world]),
        "folder-bt": (tmp / "folder.bt", ["octree2world", "{in}", "-o", "{out}", *world]),
        "fifo-bag": (fifos / "b.bag", ["bag2world", "{in}", "-o", "{out}", *world]),
        "fifo-bag-inspect": (fifos / "b.bag", ["inspect", "{in}"]),
        "fifo-rosbag2-storage": (rosbag2, ["inspect", "{in}"]),
        "fifo-trajectory": (
            fifos / "traj.txt",
            [
                "bag2world",
                str(bag),
                "-o",
                "{out}",
                "--poses",
                "trajectory",
                "--trajectory",
                "{in}",
                *world,
            ],
        ),
        "fifo-dem": (fifos / "d.tif", ["dem2world", "{in}", "-o", "{out}", *world]),
        "folder-dem": (tmp / "folder.tif", ["dem2world", "{in}", "-o", "{out}", *world]),
        "fifo-image": (
            fifos / "i.png",
            ["image2world", "{in}", "-o", "{out}", "--resolution", "0.1", *world],
        ),
        "fifo-map-yaml": (fifos / "m.yaml", ["map2world", "{in}", "-o", "{out}", *world]),
        "fifo-map-image": (fifos / "img.pgm", ["map2world", str(map_yaml), "-o", "{out}", *world]),
        "fifo-pcd": (fifos / "c.pcd", ["convert", "{in}", "{out}.xyz"]),
        "fifo-las": (fifos / "c.las", ["convert", "{in}", "{out}.xyz"]),
        "fifo-xyz": (fifos / "c.xyz", ["convert", "{in}", "{out}.ply"]),
        "fifo-laz-stream": (
            fifos / "c.laz",
            ["cloud2world", "{in}", "-o", "{out}", "--stream", "--resolution", "0.2", *world],
        ),
        "link-zero-las": (tmp / "zero.las", ["convert", "{in}", "{out}.xyz"]),
        "scan-bomb": (
            _scan_bomb(tmp / "bomb.dat.gz"),
            ["octree2world", "{in}", "-o", "{out}", "--resolution", "0.2", *world],
        ),
        "dem-pole": (_pole_dem(tmp / "pole.tif"), ["dem2world", "{in}", "-o", "{out}", *world]),
    }
    cases = []
    for name, (src, argv) in inputs.items():
        out = tmp / "out" / name
        out.mkdir(parents=True)
        filled = [a.replace("{in}", str(src)).replace("{out}", str(out / "o")) for a in argv]
        cases.append(Case(name, filled, str(out)))
    results = run_cases(
        cases, limit_bytes=LIMIT_BYTES, timeout_s=TIMEOUT_S, workdir=tmp / "_runner"
    )
    return {c.name: (inputs[c.name][0], o) for c, o in zip(cases, results, strict=True)}


# --- 1. only regular files are opened -------------------------------------------------------------


@pytest.mark.parametrize(
    ("case", "kind"),
    [
        ("fifo-bt", "a named pipe (FIFO)"),  # hung forever
        ("fifo-scan", "a named pipe (FIFO)"),
        ("fifo-scan-gz", "a named pipe (FIFO)"),
        ("dev-zero", "a character device"),  # read until memory ran out
        ("link-zero-bt", "a character device"),
        ("folder-bt", "a folder"),
        ("fifo-bag", "a named pipe (FIFO)"),  # hung forever
        ("fifo-bag-inspect", "a named pipe (FIFO)"),  # hung forever
        ("fifo-trajectory", "a named pipe (FIFO)"),  # hung forever
        ("fifo-dem", "a named pipe (FIFO)"),
        ("folder-dem", "a folder"),
        ("fifo-image", "a named pipe (FIFO)"),
        ("fifo-map-yaml", "a named pipe (FIFO)"),
        ("fifo-map-image", "a named pipe (FIFO)"),
        ("fifo-pcd", "a named pipe (FIFO)"),
        ("fifo-las", "a named pipe (FIFO)"),
        ("fifo-xyz", "a named pipe (FIFO)"),
        ("fifo-laz-stream", "a named pipe (FIFO)"),
        ("link-zero-las", "a character device"),
    ],
)
def test_what_is_not_a_regular_file_is_refused_before_it_is_opened(
    commands: dict[str, tuple[Path, Outcome]], case: str, kind: str
) -> None:
    src, o = commands[case]
    line = one_line(o)
    assert line.startswith(f"scan2terrain: error: {src}: is {kind}: cannot read it as a"), line
    assert o.seconds < 10 and not o.new_files, o.describe()


def test_a_rosbag2_folder_with_a_fifo_for_storage_is_refused(
    commands: dict[str, tuple[Path, Outcome]],
) -> None:
    src, o = commands["fifo-rosbag2-storage"]
    storage = src / "bag2_derived_sick_lms1xx_db3.db3"
    assert f"{storage}: is a named pipe (FIFO): cannot read it as a bag" in one_line(o)


def test_regular_file_names_what_the_path_is(tmp_path: Path) -> None:
    from scan2terrain.readers._files import regular_file

    (tmp_path / "f").write_bytes(b"abc")
    assert regular_file(tmp_path / "f", "scan file") == 3
    os.mkfifo(tmp_path / "p")
    (tmp_path / "loop").symlink_to(tmp_path / "loop")
    (tmp_path / "dangling").symlink_to(tmp_path / "gone")
    for path, problem in [
        (tmp_path / "p", "is a named pipe (FIFO): cannot read it as an image file"),
        (tmp_path, "is a folder: cannot read it as an image file"),
        (Path("/dev/null"), "is a character device: cannot read it as an image file"),
        (tmp_path / "gone", "image file not found"),
        (tmp_path / "dangling", "image file not found"),
        (tmp_path / "loop", "cannot open the image file (Too many levels of symbolic links)"),
        (tmp_path / ("x" * 300), "cannot open the image file (File name too long)"),
        (tmp_path / "a\0b", "the image file's name holds a NUL byte"),
        (tmp_path / "f" / "g", "cannot open the image file (Not a directory)"),
    ]:
        with pytest.raises(InputError) as info:
            regular_file(path, "image file")
        assert info.value.problem == problem and info.value.path == path


# --- 2. decompression streamed and capped ---------------------------------------------------------


def test_a_scan_file_inflating_to_20_million_points_is_refused_early(
    commands: dict[str, tuple[Path, Outcome]],
) -> None:
    """Seen: 54 s and 5.7 GB (a MemoryError, exit 1, under a 4 GB limit after 14 s)."""
    src, o = commands["scan-bomb"]
    line = one_line(o)
    assert f"{src}: line 10,000,001: more than 10,000,000 points in one scan" in line
    assert "MAX_SCAN_POINTS" in line
    assert o.maxrss_mb < 700 and o.seconds < 15, o.describe()


def test_scan_files_are_read_as_a_stream(tmp_path: Path) -> None:
    """The same scans whether compressed or not, split in blocks anywhere; every line's
    number in the errors is its own."""
    from scan2terrain.readers import octomap_scan
    from scan2terrain.readers.octomap_scan import read_scans

    text = (
        "# a comment\n\nNODE 1 2 0 0 0 0\n1 0 0\n  0 1 0 \n# inside\n\n0 0 1\n"
        "node 0 0 0 0 0 1.5707963267948966\n1 0 0\n2 0 0\n"
    )
    plain = tmp_path / "s.dat"
    plain.write_text(text)
    (tmp_path / "s.dat.gz").write_bytes(gzip.compress(text.encode()))
    want = list(read_scans(plain))
    assert [len(s.points) for s in want] == [3, 2]
    np.testing.assert_allclose(want[0].points, [[2, 2, 0], [1, 3, 0], [1, 2, 1]])
    np.testing.assert_allclose(want[1].points, [[0, 1, 0], [0, 2, 0]], atol=1e-12)
    for block in (1, 2, 3, 7, 1 << 20):
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(octomap_scan, "_BLOCK", block)
            for path in (plain, tmp_path / "s.dat.gz"):
                got = list(read_scans(path))
                assert len(got) == 2
                for a, b in zip(got, want, strict=True):
                    np.testing.assert_array_equal(a.points, b.points)
                    np.testing.assert_array_equal(a.origin, b.origin)
            bad = tmp_path / "bad.dat"
            bad.write_text(text.replace("\n2 0 0\n", "\n2 0 zero\n"))
            with pytest.raises(InputError, match="line 11: expected 'x y z', got '2 0 zero'"):
                list(read_scans(bad))
            bad.write_text(text.replace("\n0 0 1\n", "\ninf 0 1\n"))
            with pytest.raises(InputError, match="line 8: point 'inf 0 1' is not a finite"):
                list(read_scans(bad))


def test_a_scan_file_line_without_end_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "s.dat.gz"
    path.write_bytes(gzip.compress(b"1 2 3\n" + b"7" * (1 << 20)))
    from scan2terrain.readers.octomap_scan import read_scans

    with pytest.raises(InputError, match="line 2 is longer than 4096 bytes"):
        list(read_scans(path))


@pytest.fixture
def own_tmp(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The temporary folder the bag reader decompresses into and sweeps: a fresh one."""
    folder = tmp_path / "tmp"
    folder.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(folder))
    return folder


def _zstd_bomb(path: Path, inflated: int = 96 << 24, *, sized: bool = False) -> Path:
    """An MCAP magic and zeros, zstd-compressed; ``sized``: one frame that states its size."""
    from backports import zstd

    if sized:
        path.write_bytes(zstd.compress(b"\x89MCAP0\r\n" + bytes(inflated)))
        return path
    with zstd.open(path, "wb", level=19) as f:
        f.write(b"\x89MCAP0\r\n")
        zeros = bytes(1 << 24)
        for _ in range(inflated >> 24):
            f.write(zeros)
    return path


def test_a_zstd_bag_bomb_is_refused_at_the_cap(own_tmp: Path, tmp_path: Path) -> None:
    """Seen: a 49 KB .mcap.zstd inflated to 1.6 GB in /tmp before it was refused."""
    from scan2terrain.readers._bag_source import MAX_ZSTD_RATIO, MIN_ZSTD_BUDGET
    from scan2terrain.readers.bag import open_bag

    bomb = _zstd_bomb(tmp_path / "bomb.mcap.zstd")
    assert bomb.stat().st_size < 60_000
    with pytest.raises(InputError) as info, open_bag(bomb):
        pass
    assert info.value.path == bomb
    assert info.value.problem.startswith(f"decompresses to more than {MIN_ZSTD_BUDGET:,} bytes")
    assert f"{MAX_ZSTD_RATIO} times" in info.value.problem and "zstd -d" in info.value.problem
    assert list(own_tmp.iterdir()) == []


def test_a_zstd_frame_that_states_its_size_is_refused_before_decompressing(
    own_tmp: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from backports import zstd

    from scan2terrain.readers import bag

    bomb = _zstd_bomb(tmp_path / "sized.mcap.zstd", 1 << 27, sized=True)
    monkeypatch.setattr(zstd, "open", None)  # nothing may be decompressed
    with pytest.raises(InputError, match=r"its zstd frame holds 134,217,736 bytes, more than"):
        bag.open_bag(bomb)
    assert list(own_tmp.iterdir()) == []


def test_a_rosbag2_folder_compressed_per_file_is_capped_too(own_tmp: Path, tmp_path: Path) -> None:
    """rosbags decompressed compression_mode FILE folders into its own temporary folder,
    without a limit; they go through the same capped decompression now."""
    from scan2terrain.readers.bag import open_bag

    with open_bag(NAV2) as b:  # genuine: 20 KB -> 2.4 MB, 120 times
        assert b.message_count == 693
        staged = list(own_tmp.iterdir())
        assert len(staged) == 1 and staged[0].name.startswith(".s2t-bag-")
    assert list(own_tmp.iterdir()) == []
    folder = tmp_path / "bombed"
    shutil.copytree(NAV2, folder)
    _zstd_bomb(folder / "_tmp_cm_bag_0.mcap.zstd")
    with pytest.raises(InputError, match="decompresses to more than") as info, open_bag(folder):
        pass
    assert info.value.path == folder / "_tmp_cm_bag_0.mcap.zstd"
    assert list(own_tmp.iterdir()) == []


def test_a_genuine_zstd_bag_file_reads(own_tmp: Path, tmp_path: Path) -> None:
    from backports import zstd

    from scan2terrain.readers.bag import open_bag
    from tests.seeds import room

    room("tf").write(tmp_path / "r", "mcap")
    mcap = next((tmp_path / "r").glob("*.mcap")).read_bytes()
    for name, data in (
        ("sized.mcap.zstd", zstd.compress(mcap)),  # the frame states its size
        ("streamed.mcap.zstd", _streamed(mcap)),
    ):
        (tmp_path / name).write_bytes(data)
        with open_bag(tmp_path / name) as b:
            assert b.topics["/scan"].count == 6
    assert list(own_tmp.iterdir()) == []


def _streamed(data: bytes) -> bytes:
    from backports import zstd

    c = zstd.ZstdCompressor()
    frame: bytes = c.compress(data) + c.flush()
    return frame


_HOLD = """
import sys, time
from contextlib import ExitStack
from scan2terrain.readers._bag_source import _temp_folder
stack = ExitStack()
folder = _temp_folder(stack)
(folder / "bag.mcap").write_bytes(bytes(1000))
print(folder, flush=True)
time.sleep(60)
"""


def test_temporary_bag_folders_are_locked_and_swept_after_a_kill(own_tmp: Path) -> None:
    """Seen: a kill during decompression left 0.4-1.1 GB in /tmp/scan2terrain-bag-*."""
    from scan2terrain.readers.bag import open_bag

    stale = own_tmp / ".s2t-bag-stale.part"  # left by a killed run: nobody holds its lock
    stale.mkdir()
    (stale / "bag.mcap").write_bytes(bytes(1000))
    env = {**os.environ, "TMPDIR": str(own_tmp)}
    with subprocess.Popen(
        [sys.executable, "-c", _HOLD], stdout=subprocess.PIPE, text=True, cwd=ROOT, env=env
    ) as holder:
        try:
            assert holder.stdout is not None
            live = Path(holder.stdout.readline().strip())
            assert live.parent == own_tmp and live.name.startswith(".s2t-bag-")
            with open_bag(NAV2):
                pass
            assert not stale.exists()  # swept
            assert (live / "bag.mcap").exists()  # its owner is alive and holds the lock
            holder.send_signal(signal.SIGKILL)
            holder.wait(10)
            assert live.exists()  # a kill leaves it...
            with open_bag(NAV2):
                pass
            assert not live.exists()  # ...and the next bag read removes it
        finally:
            holder.kill()


# --- 3. values that make sense --------------------------------------------------------------------


def _bt_with_res(tmp_path: Path, res: str) -> Path:
    from tests.seeds import bt_file

    path, _ = bt_file(tmp_path)
    path.write_bytes(re.sub(rb"\nres \S+", b"\nres " + res.encode(), path.read_bytes(), count=1))
    return path


@pytest.mark.parametrize("res", ["1.7e308", "1e20", "1e-300", "1e-12", "2e5", "5e-5"])
def test_bt_resolution_outside_the_cell_range_is_refused(tmp_path: Path, res: str) -> None:
    """Seen: 1.7e308 and 1e-300 crashed later (exit 1), 1e20 and 1e-12 exited 0 with an
    absurd world."""
    from scan2terrain.octree.bt import read_bt

    path = _bt_with_res(tmp_path, res)
    with pytest.raises(InputError) as info:
        read_bt(path)
    assert info.value.path == path
    assert info.value.problem == (
        f"resolution 'res {res}' in the OctoMap header is outside 0.0001..100000 m"
    )


@pytest.mark.parametrize("res", ["0.0001", "100000", "0.05"])
def test_bt_resolutions_at_the_bounds_are_read(tmp_path: Path, res: str) -> None:
    from scan2terrain.octree.bt import read_bt

    assert read_bt(_bt_with_res(tmp_path, res)).resolution == float(res)


@pytest.mark.parametrize(
    ("offset", "value", "message"),
    [
        (131, 0.0, r"scale factors \(0, 0.01, 0.01\) must be positive"),  # exit 0: x all 0
        (139, -0.01, r"scale factors \(0.01, -0.01, 0.01\) must be positive"),  # mirrored y
        (147, math.inf, r"scale factors \(0.01, 0.01, inf\) must be positive"),
        (131, math.nan, r"scale factors \(nan, 0.01, 0.01\) must be positive"),
        (155, math.nan, r"offsets \(nan, 0, 0\) must be finite"),
        (171, -math.inf, r"offsets \(0, 0, -inf\) must be finite"),
    ],
)
def test_las_scales_and_offsets_that_make_no_sense_are_refused(
    tmp_path: Path, offset: int, value: float, message: str
) -> None:
    from scan2terrain.readers.cloudfile import read_cloud
    from scan2terrain.readers.las import iter_las, las_info

    data = bytearray(SIMPLE_LAS.read_bytes())
    struct.pack_into("<3d", data, 155, 0.0, 0.0, 0.0)  # simple.las has zero offsets already
    struct.pack_into("<d", data, offset, value)
    path = tmp_path / "s.las"
    path.write_bytes(bytes(data))
    for read in (read_cloud, las_info, lambda p: list(iter_las(p))):
        with pytest.raises(InputError, match="corrupt LAS header: " + message) as info:
            read(path)
        assert info.value.path == path


def _png(tmp_path: Path) -> tuple[Path, np.ndarray]:
    from PIL import Image

    y, x = np.mgrid[0:64, 0:64]
    pixels = np.kron((x * y) % 256, np.ones((4, 4), int)).astype(np.uint8)
    path = tmp_path / "a.png"
    Image.fromarray(pixels).save(path)
    return path, pixels


def test_png_with_a_bad_idat_crc_is_refused(tmp_path: Path) -> None:
    """Seen: read with 63% of the pixels wrong, exit 0 (Pillow does not check IDAT CRCs, and
    some corrupt deflate data still inflates)."""
    from PIL import Image

    from scan2terrain.readers.image import read_grey_image

    path, pixels = _png(tmp_path)
    data = bytearray(path.read_bytes())
    idat = data.index(b"IDAT")
    data[idat + 4 + 458] = 0  # a byte that still inflates, to other pixels
    path.write_bytes(bytes(data))
    with Image.open(path) as img:  # what made it dangerous: 66% of the pixels wrong
        assert (np.asarray(img) != pixels).mean() > 0.6
    with pytest.raises(InputError) as info:
        read_grey_image(path)
    assert info.value.path == path
    assert (
        info.value.problem
        == "cannot decode image: corrupt PNG: its IDAT chunk at byte 33 fails its CRC check"
    )


def test_png_chunk_damage_and_truncation_are_refused(tmp_path: Path) -> None:
    from scan2terrain.readers._pixels import open_pixels

    path, _ = _png(tmp_path)
    good = path.read_bytes()
    for data, problem in [
        (
            good[:-3],
            f"truncated PNG: its IEND chunk at byte {len(good) - 12} needs 12 bytes, the file "
            "ends 9 bytes into it",
        ),
        (good[:-12], "truncated PNG: it has no IEND chunk"),
        (good[:100], "truncated PNG: its IDAT chunk at byte 33 needs 2012 bytes, the file ends 67"),
        (good[:8] + b"\xff\xff\xff\xff" + good[12:], "corrupt PNG: a chunk length of 4294967295"),
    ]:
        path.write_bytes(data)
        with pytest.raises(InputError, match=re.escape(problem)):
            open_pixels(path)
    from PIL import ImageFile

    assert ImageFile.LOAD_TRUNCATED_IMAGES is False


def test_pgm_samples_above_maxval_are_refused(tmp_path: Path) -> None:
    """Seen: clamped to maxval, 138,733 unknown cells of a map became free."""
    from scan2terrain.readers.mapserver import read_map_yaml
    from tests.conftest import write_map

    pixels = np.full((30, 40), 254, np.uint8)
    pixels[:, :10] = 0
    pixels[20:, 20:] = 205
    yaml_path = write_map(tmp_path, pixels, name="m.pgm")
    pgm = tmp_path / "m.pgm"
    raw = pgm.read_bytes()
    assert raw.startswith(b"P5\n40 30\n255\n")
    pgm.write_bytes(raw.replace(b"\n255\n", b"\n200\n", 1))
    with pytest.raises(InputError) as info:
        read_map_yaml(yaml_path)
    assert info.value.path == pgm
    assert info.value.problem == "samples up to 254 exceed the PGM's maxval 200 (corrupt file)"


@pytest.mark.parametrize("maxval", [100, 255, 1000, 65535])
def test_pgm_samples_within_maxval_are_scaled_as_pillow_does(tmp_path: Path, maxval: int) -> None:
    from PIL import Image

    from scan2terrain.readers._pixels import open_pixels

    rng = np.random.default_rng(maxval)
    samples = rng.integers(0, maxval + 1, size=(7, 9))
    samples[0, :3] = (0, maxval, maxval // 2)
    dtype = ">u1" if maxval < 256 else ">u2"
    path = tmp_path / "a.pgm"
    path.write_bytes(f"P5\n9 7\n{maxval}\n".encode() + samples.astype(dtype).tobytes())
    got = open_pixels(path)
    with Image.open(path) as img:
        want = np.asarray(img)
    assert got.max_value == (255 if maxval < 256 else 65535)
    np.testing.assert_array_equal(got.colour[..., 0], want)
    path.write_bytes(path.read_bytes()[:-3])
    with pytest.raises(InputError, match="truncated"):
        open_pixels(path)


@pytest.mark.parametrize("fields", ["x y z x", "x x y z", "x y z z", "x y z intensity y"])
def test_duplicate_pcd_fields_are_refused(tmp_path: Path, fields: str) -> None:
    """Seen: z taken from intensity."""
    from scan2terrain.readers.cloudfile import read_cloud

    names = fields.split()
    k = len(names)
    head = (
        f"VERSION 0.7\nFIELDS {fields}\nSIZE {' 4' * k}\nTYPE {' F' * k}\nCOUNT {' 1' * k}\n"
        "WIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA ascii\n"
    )
    path = tmp_path / "d.pcd"
    path.write_text(head + " ".join(["1"] * k) + "\n" + " ".join(["2"] * k) + "\n")
    dup = next(n for i, n in enumerate(names) if n in names[:i])
    with pytest.raises(InputError, match=f"PCD header: field '{dup}' appears twice in FIELDS"):
        read_cloud(path)


def test_pcd_padding_fields_may_repeat(tmp_path: Path) -> None:
    """PCL names every padding field '_'."""
    from scan2terrain.readers.cloudfile import read_cloud

    head = (
        "VERSION 0.7\nFIELDS x y z _ rgb _\nSIZE 4 4 4 1 4 1\nTYPE F F F U F U\n"
        "COUNT 1 1 1 4 1 12\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA binary\n"
    )
    path = tmp_path / "p.pcd"
    path.write_bytes(head.encode() + struct.pack("<3f", 1, 2, 3) + bytes(4 + 4 + 12))
    np.testing.assert_array_equal(read_cloud(path).points, [[1, 2, 3]])


def test_duplicate_pointcloud2_fields_are_refused() -> None:
    from types import SimpleNamespace

    from scan2terrain.readers.pointcloud2 import pointcloud2_fields, pointcloud2_xyz

    def msg(*names: str) -> SimpleNamespace:
        fields = [
            SimpleNamespace(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate(names)
        ]
        step = 4 * len(names)
        return SimpleNamespace(
            height=1, width=2, fields=fields, is_bigendian=False, point_step=step,
            row_step=2 * step, data=bytes(2 * step),
        )  # fmt: skip

    for names in (("x", "y", "z", "x"), ("x", "y", "z", "intensity", "intensity")):
        with pytest.raises(InputError, match=f"two fields named '{names[-1]}'"):
            pointcloud2_xyz(msg(*names))
    assert pointcloud2_xyz(msg("x", "y", "z", "_", "_")).shape == (2, 3)
    with pytest.raises(InputError, match="two fields named 'intensity'"):
        pointcloud2_fields(msg("x", "y", "z", "intensity", "intensity"), ["intensity"])


# --- DEMs ---------------------------------------------------------------------------------------


def _tiff(
    src: Path, tmp_path: Path, name: str, edit: Mapping[int, tuple[str, int, object]]
) -> Path:
    """``src`` with values of its first IFD's entries (tag -> (format, offset in the entry,
    value)) replaced."""
    from tests.seeds import tiff_entries

    data = bytearray(src.read_bytes())
    entries = tiff_entries(bytes(data))
    for tag, (fmt, at, value) in edit.items():
        struct.pack_into(fmt, data, entries[tag] + at, value)
    path = tmp_path / name
    path.write_bytes(bytes(data))
    return path


def test_tiff_pixel_data_beyond_the_file_is_refused_before_decoding(tmp_path: Path) -> None:
    from scan2terrain.readers.dem import read_dem

    size = MOON.stat().st_size
    for name, edit in {
        "offset.tif": {273: ("<I", 8, size + 10)},
        "count.tif": {279: ("<I", 8, 1 << 30)},
    }.items():
        path = _tiff(MOON, tmp_path, name, edit)
        with pytest.raises(InputError, match=f"truncated: pixel data ends at byte .* has {size}"):
            read_dem(path)


@pytest.mark.parametrize(
    ("name", "edit", "problem"),
    [
        # zlib.error: "incorrect header check" (exit 1)
        (
            "deflate.tif",
            {259: ("<H", 8, 8)},
            "cannot decode the TIFF (corrupt?): zlib.error: Error -3",
        ),
        # NotImplementedError: "chroma subsampling not supported" (exit 1)
        ("ycbcr.tif", {262: ("<H", 8, 6)}, "photometric interpretation YCBCR is not a band"),
        ("cmyk.tif", {262: ("<H", 8, 5)}, "photometric interpretation SEPARATED is not"),
        # ImageWidth's count: a tuple where a number belongs (TypeError in our code, exit 1)
        ("width-count.tif", {256: ("<I", 4, 255)}, "corrupt TIFF directory: a tag holds"),
        # ImageLength's type byte: text (TypeError in tifffile, exit 1)
        ("length-type.tif", {257: ("<H", 2, 2)}, "cannot decode the TIFF (corrupt?): TypeError"),
        # GeoKeyDirectory's type: text, not numbers (ValueError in our code, exit 1)
        ("geokeys-type.tif", {34735: ("<H", 2, 2)}, "GeoKeyDirectory holds str values"),
        # GeoDoubleParams' type: text (ValueError in our code, exit 1)
        ("doubles-type.tif", {34736: ("<H", 2, 2)}, "GeoDoubleParams holds str values"),
    ],
)
def test_corrupt_tiff_directories_are_one_line(
    tmp_path: Path, name: str, edit: dict[int, tuple[str, int, object]], problem: str
) -> None:
    from scan2terrain.readers.dem import read_dem

    path = _tiff(MOON, tmp_path, name, edit)
    with pytest.raises(InputError) as info:
        read_dem(path)
    assert info.value.path == path and problem in info.value.problem, info.value.problem
    assert "\n" not in str(info.value)


def test_every_flipped_ifd_byte_is_read_or_refused(tmp_path: Path) -> None:
    """Each byte of the TIFF header and first IFD set to 0x00, 0xFF, or flipped in its lowest
    bit: 26 of them crashed (TypeError, IndexError, ValueError: exit 1)."""
    from scan2terrain.readers.dem import read_dem
    from tests.seeds import tiff_entries

    src = MOON.read_bytes()
    ifd = struct.unpack_from("<I", src, 4)[0]
    end = ifd + 2 + 12 * len(tiff_entries(src)) + 4
    path = tmp_path / "f.tif"
    refused = 0
    for pos in [*range(8), *range(ifd, end)]:
        for value in (0x00, 0xFF, src[pos] ^ 1):
            path.write_bytes(src[:pos] + bytes([value]) + src[pos + 1 :])
            try:
                read_dem(path)
            except InputError as exc:
                assert "\n" not in str(exc)
                refused += 1
    assert refused > 100


def _geotiff(tmp_path: Path, keys: dict[int, int] | None, **kw: object) -> Path:
    from tests.geotiff import write_geotiff

    raster = np.arange(20, dtype=np.float32).reshape(4, 5)
    return write_geotiff(tmp_path / "g.tif", raster, keys=keys, **kw)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("keys", "why"),
    [
        ({}, "ModelPixelScale and ModelTiepoint but no GeoKeyDirectory"),
        ({1025: 1, 2054: 9102}, "GeoKeys without a projected or geographic model type"),
        ({1024: 3, 1025: 1}, "GeoKeys without a projected or geographic model type"),
    ],
    ids=["no-geokeys", "angular-units-only", "geocentric"],
)
def test_incomplete_georeference_needs_a_resolution(
    tmp_path: Path, keys: dict[int, int], why: str
) -> None:
    """Seen: degree pixels of a GeoTIFF without GeoKeys read as metres (a terrain 3.6 cm
    wide), exit 0."""
    from scan2terrain.readers.dem import read_dem

    path = _geotiff(tmp_path, keys, scale=(0.000277, 0.000277), tie=(-122.2, 38.0))
    with pytest.raises(InputError) as info:
        read_dem(path)
    assert info.value.path == path
    assert info.value.problem == (
        f"its georeference is incomplete ({why}: metres or degrees?), so its pixel size is "
        "unknown: give it in metres with --resolution"
    )
    dem = read_dem(path, pixel_size=30.0)
    assert dem.crs == "local" and dem.pixel_size == (30.0, 30.0) and dem.shape == (4, 5)
    assert any("incomplete" in n for n in dem.notes)


def test_geotiff_georeference_that_is_complete_is_still_read(tmp_path: Path) -> None:
    from scan2terrain.readers.dem import read_dem

    assert read_dem(_geotiff(tmp_path, {1024: 1, 1025: 1}, scale=(2.0, 2.0))).crs == "projected"
    assert read_dem(SFBAY).crs == "geographic"
    assert read_dem(MOON).crs == "projected"


def test_dem_near_the_pole_is_refused_before_resampling(
    commands: dict[str, tuple[Path, Outcome]],
) -> None:
    """Seen: 2.1 billion pixels written (86 s, 4.3 GB); then a MemoryError (exit 1) under a
    3 GB limit, resampling 129 x 129 samples onto 257 x 524,289 (under max_pixels: the float64
    temporaries took 32 bytes a pixel)."""
    src, o = commands["dem-pole"]
    line = one_line(o)
    assert (
        f"{src}: its 0.015 x 30.9 m pixels, made square (0.00754 m), would be 257 x 524,289 "
        "pixels, 8,097 times its own 129 x 129, more than 64" in line
    )
    assert "--resolution" in line
    assert o.maxrss_mb < 400, o.describe()


def test_dem_resampling_limits(tmp_path: Path) -> None:
    from scan2terrain.readers.dem import read_dem

    path = _pole_dem(tmp_path / "pole.tif")
    with pytest.raises(InputError, match="8,097 times its own 129 x 129"):
        read_dem(path)
    assert read_dem(path, pixel_size=30.0).shape == (129, 129)  # --resolution: read as it is
    with pytest.raises(InputError, match=r"over the limit of 20000 pixels \(--max-pixels;"):
        read_dem(SFBAY, max_pixels=20_000)


# --- map YAML -----------------------------------------------------------------------------------


@pytest.fixture
def map_yaml(tmp_path: Path) -> Path:
    from tests.conftest import write_map

    return write_map(tmp_path, np.full((10, 12), 254, np.uint8), name="m.png")


@pytest.mark.parametrize(
    ("old", "new", "problem"),
    [
        ("resolution: 0.1", "resolution: " + "9" * 400, "'resolution' must be a finite number"),
        ("origin: [0.0, 0.0, 0.0]", "origin: [" + "9" * 400 + ", 0, 0]", "'origin' must hold"),
        ("occupied_thresh: 0.65", "occupied_thresh: 1" + "0" * 400, "'occupied_thresh' must be"),
        ("negate: 0", "negate: " + "9" * 400, "'negate' must be 0, 1, true or false, got 99"),
        ("resolution: 0.1", "resolution: " + "9" * 5000, "malformed YAML"),
        ("negate: 0", "negate: " + "[" * 5000 + "]" * 5000, "malformed YAML (nested too deeply)"),
        ("image: m.png", 'image: "m\\0.png"', "'image' holds a NUL byte"),
    ],
    ids=["int-resolution", "int-origin", "int-threshold", "int-negate", "digits", "deep", "nul"],
)
def test_absurd_map_yaml_values_are_one_line(
    map_yaml: Path, old: str, new: str, problem: str
) -> None:
    """Seen: OverflowError, RecursionError, ValueError (exit 1)."""
    from scan2terrain.readers.mapserver import read_map_yaml

    map_yaml.write_text(map_yaml.read_text().replace(old, new))
    with pytest.raises(InputError) as info:
        read_map_yaml(map_yaml)
    assert info.value.path == map_yaml and problem in info.value.problem
    assert len(str(info.value)) < 300


def test_map_image_paths_the_system_refuses_are_one_line(map_yaml: Path) -> None:
    """Seen: ENAMETOOLONG (OSError) and a symlink loop (RuntimeError), exit 1."""
    from scan2terrain.readers.mapserver import read_map_yaml

    folder = map_yaml.parent
    (folder / "loop1.png").symlink_to("loop2.png")
    (folder / "loop2.png").symlink_to("loop1.png")
    text = map_yaml.read_text()
    for image, problem in [
        ("a" * 300 + ".png", "cannot open the image file (File name too long)"),
        ("/".join(["b" * 200] * 30) + ".png", "cannot open the image file (File name too long)"),
        ("loop1.png", "cannot open the image file (Too many levels of symbolic links)"),
    ]:
        map_yaml.write_text(text.replace("image: m.png", f"image: {image}"))
        with pytest.raises(InputError) as info:
            read_map_yaml(map_yaml)
        assert info.value.problem == problem
    (folder / "self.yaml").symlink_to("self.yaml")
    with pytest.raises(InputError, match="Too many levels of symbolic links"):
        read_map_yaml(folder / "self.yaml")


def test_an_oversized_map_yaml_is_refused_unread(map_yaml: Path) -> None:
    from scan2terrain.readers.mapserver import MAX_YAML_BYTES, read_map_yaml

    with map_yaml.open("a") as f:
        f.write("# " + "x" * MAX_YAML_BYTES + "\n")
    with pytest.raises(InputError, match=f"larger than {MAX_YAML_BYTES:,} bytes"):
        read_map_yaml(map_yaml)


# --- PLY cut through Open3D -------------------------------------------------------------------


@pytest.mark.parametrize("fmt", ["binary_little_endian", "ascii"])
def test_a_ply_cut_at_90_percent_is_refused_the_same_way_every_time(
    tmp_path: Path, fmt: str
) -> None:
    """Seen before issue 12's fix: garbage points and exit 0 in 3 of 10 runs."""
    from scan2terrain.readers.cloudfile import read_cloud
    from tests.seeds import ply_list

    data = ply_list(fmt)()
    path = tmp_path / "cut.ply"
    path.write_bytes(data[: len(data) * 9 // 10])
    seen = set()
    for _ in range(10):
        with pytest.raises(InputError) as info:
            read_cloud(path)
        seen.add(str(info.value))
    assert len(seen) == 1
    assert "truncated: the data ends in row 134 of element vertex" in seen.pop()


def test_oversized_side_files_are_refused_unread(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A TUM trajectory and a rosbag2 metadata.yaml are read whole: their size is checked
    first."""
    from scan2terrain.readers import _bag_source, bag, tracks

    traj = tmp_path / "t.txt"
    traj.write_text("1 0 0 0 0 0 0 1\n2 0 0 0 0 0 0 1\n")
    monkeypatch.setattr(tracks, "MAX_TUM_BYTES", 16)
    with pytest.raises(InputError, match="a TUM trajectory of 32 bytes, more than the 16 read"):
        tracks.read_tum(traj)
    folder = tmp_path / "r"
    shutil.copytree(NAV2, folder)
    monkeypatch.setattr(_bag_source, "MAX_METADATA_BYTES", 100)
    with pytest.raises(InputError, match="larger than 100 bytes: not a rosbag2 metadata file"):
        bag.open_bag(folder)
