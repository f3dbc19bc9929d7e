"""CARMEN logs through the command line (issue 27 item 7): ``inspect``, ``convert`` and
``bag2world`` read the bundled MIT CSAIL log (and logs written in the tests) as they read a bag;
a damaged log is one line, exit 2, nothing written. The reader's own tests are in
tests/readers/test_carmen.py."""

from __future__ import annotations

import bz2
import gzip
from pathlib import Path

import numpy as np
import pytest

from scan2terrain.cli import main
from scan2terrain.config import ScansConfig
from scan2terrain.readers.bag import open_bag
from scan2terrain.readers.points import hits_of
from scan2terrain.readers.scans import plan_bag, posed_scans
from scan2terrain.readers.tracks import read_tum
from scan2terrain.types import ScanCounts
from tests.carmen import (
    DEFAULT_LOG,
    ODOM,
    RANGES,
    T0,
    compose,
    damaged_log,
    flaser,
    read_carmen,
    write,
)


def run(capsys: pytest.CaptureFixture[str], *args: object) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def test_inspect_the_bundled_log(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "inspect", DEFAULT_LOG)
    assert code == 0 and err == "", err
    assert "  CARMEN log (1,991 lines), read with scan2terrain (text, line by line)" in out
    assert "duration 423.997 s, 3977 messages, start 1134864629.895 (UNIX s)" in out
    lines = out.splitlines()
    assert "    /scan          1988  sensor_msgs/msg/LaserScan" in lines
    assert "    /odom          1988  nav_msgs/msg/Odometry" in lines
    assert "    base_link -> laser (static)" in lines
    assert (
        "(FLASER records, 361 readings, 0.5 deg apart from -90 deg (CARMEN's spacing for the "
        "count), range_max 80 m (CARMEN's default, no PARAM robot_front_laser_max))"
    ) in out
    plan = out[out.index("  bag2world would use:") :]
    assert "    poses: odometry on /odom plus the sensor mount" in plan
    assert "    raw CARMEN log: every laser pose is the odometry pose plus the mount" in plan


def test_convert_the_bundled_log(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "convert", DEFAULT_LOG, tmp_path / "csail.ply")
    assert code == 0, err
    cfg = ScansConfig()
    with open_bag(DEFAULT_LOG) as bag:
        plan = plan_bag(bag, cfg)
        want = np.concatenate([hits_of(s) for s in posed_scans(bag, cfg, plan, ScanCounts())])
    assert out.startswith(f"Wrote {tmp_path / 'csail.ply'} ({len(want):,} points)")
    assert "scans: 1988" in out
    # no no-return reading (81.91 m) became a point: all lie within 45 m of their laser
    log = read_carmen()
    assert log.ranges[log.ranges < 80].max() < 45
    assert len(want) == int((log.ranges < 80).sum())
    data = (tmp_path / "csail.ply").read_bytes()
    header, _, body = data.partition(b"end_header\n")
    assert f"element vertex {len(want)}".encode() in header
    assert len(body) == len(want) * 3 * (4 if b"property float x" in header else 8)


def test_bag2world_on_the_bundled_log(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """No --mount and no --pose: the log's records give the mount; poses from its odometry."""
    out = tmp_path / "csail"
    code, stdout, err = run(capsys, "bag2world", DEFAULT_LOG, "-o", out, "--correct", "off")
    assert code == 0, err
    for name in ("world_gz.sdf", "world_classic.world", "octree.bt", "trajectory.tum"):
        assert (out / name).is_file(), name
    assert "  scans: 1988 inserted (" in stdout
    assert "mount of laser on base_link (/tf_static): the records' laser pose less" in stdout
    assert "identity" not in stdout
    track = read_tum(out / "trajectory.tum")
    log = read_carmen()
    np.testing.assert_array_equal(track.times_ns, log.stamps_ns)
    np.testing.assert_allclose(track.translations[:, :2], log.laser_poses[:, :2], atol=1e-9)


def test_bag2world_streams_a_log(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """--stream opens the log once per slice of time: all of them are read (the parse is
    reused), and the result is the same run after run."""
    text = bz2.decompress(DEFAULT_LOG.read_bytes()).splitlines(keepends=True)
    small = tmp_path / "csail.clf.gz"  # a quarter of the bundled log's scans, gzipped
    small.write_bytes(gzip.compress(b"".join(text[3::4]), mtime=0))
    outs = []
    for k in range(2):
        out = tmp_path / f"w{k}"
        options = ["--stream", "--correct", "off", "--no-preview"]
        code, stdout, err = run(capsys, "bag2world", small, "-o", out, *options)
        assert code == 0, err
        assert "streamed: 2 piece(s) over 497 scan messages" in stdout
        outs.append(out)
    for p in sorted(outs[0].rglob("*")):
        if p.is_file() and p.suffix != ".yaml":
            assert p.read_bytes() == (outs[1] / p.relative_to(outs[0])).read_bytes(), p


def test_inspect_a_corrected_log(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    corrected = [compose((0.03 * k, 0.0, 0.02 * k), p) for k, p in enumerate(ODOM)]
    lines = [
        flaser(RANGES, c, p, T0 + 0.2 * k)
        for k, (c, p) in enumerate(zip(corrected, ODOM, strict=True))
    ]
    code, out, err = run(capsys, "inspect", write(tmp_path / "gfs.clf", lines))
    assert code == 0, err
    assert "    map -> odom (6 samples)" in out
    assert "    odom -> base_link (6 samples)" in out
    assert "    poses: tf, sensor frame(s) laser in fixed frame 'map'" in out


CLI_DAMAGED = [
    "cut short",
    "binary junk",
    "no laser lines",
    "empty log",
    "count that does not match",
]


@pytest.mark.parametrize(
    "command", ["bag2world", "bag2world --stream", "inspect", "convert"], ids=str.strip
)
@pytest.mark.parametrize("case", CLI_DAMAGED)
def test_damaged_log_one_line_exit_2_nothing_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str, command: str
) -> None:
    (tmp_path / "in").mkdir()
    path, message = damaged_log(tmp_path / "in", case)
    outs = tmp_path / "outs"
    outs.mkdir()
    words = command.split()
    if words[0] == "bag2world":
        args = [*words, path, "-o", outs / "w"]
    elif words[0] == "convert":
        args = [*words, path, outs / "c.ply"]
    else:
        args = [*words, path]
    code, stdout, err = run(capsys, *args)
    assert code == 2 and stdout == ""
    assert err.count("\n") == 1 and err.startswith(f"scan2terrain: error: {path}: "), err
    assert message in err
    assert list(outs.iterdir()) == []


def test_a_truncated_bz2_log_one_line_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cut = tmp_path / "cut.clf.bz2"
    cut.write_bytes(DEFAULT_LOG.read_bytes()[:200_000])
    code, stdout, err = run(capsys, "bag2world", cut, "-o", tmp_path / "w")
    assert code == 2 and stdout == ""
    assert err.startswith(f"scan2terrain: error: {cut}: the bzip2 stream is cut short after line ")
    assert not (tmp_path / "w").exists()
