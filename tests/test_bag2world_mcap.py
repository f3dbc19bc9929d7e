"""ROS1 in MCAP through the command line (issue 16): ``bag2world`` (octree and ``--stream``),
``convert`` and ``inspect`` on a fixture ROS1 bag and on that bag rewritten as ROS1 MCAP in
several layouts give the same outputs; bad MCAP files give one line, exit 2, nothing written.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from scan2terrain.cli import main
from tests.bagmaker import LAYOUTS, first_chunk_data, one_message_mcap, ros1_bag_to_mcap
from tests.fixtures import EMBARK_ROS1, FUSE
from tests.world_checks import STATIONARY, normalised_outputs


def run(capsys: pytest.CaptureFixture[str], *args: object) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def rewrite(bag: Path, tmp: Path, layout: str) -> Path:
    compression, summary, chunked = LAYOUTS[layout]
    out = tmp / f"{bag.stem}_{layout}.mcap"
    return ros1_bag_to_mcap(bag, out, compression=compression, summary=summary, chunked=chunked)


# id -> (bag, options, MCAP layouts)
CASES = {
    "fuse-laserscan-odometry": (
        FUSE,
        ["--end", "30", "--geometry", "heightmap"],
        ["zstd", "lz4-no-summary", "unchunked-no-summary"],
    ),
    "fuse-stream": (FUSE, ["--end", "30", "--stream"], ["zstd", "lz4-no-summary"]),
    # as the ROS 2 twin in test_bag2world: 0.5 m voxels keep the heightmap at 1025 px
    "embark-pointcloud2": (
        EMBARK_ROS1,
        ["--topic", "/luminar_pointcloud", *STATIONARY, "--grid", "height", "--resolution", "0.5"],
        ["zstd", "none"],
    ),
}


@pytest.mark.parametrize("case", list(CASES))
def test_ros1_mcap_gives_the_world_of_the_bag(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str
) -> None:
    bag, options, layouts = CASES[case]
    code, stdout, want_err = run(capsys, "bag2world", bag, "-o", tmp_path / "bag", *options)
    assert code == 0, want_err
    want = normalised_outputs(tmp_path / "bag", bag)
    assert "map/map.pgm" in want or "octree.bt" in want  # height grids write no map
    assert any(k.endswith(("heightmap.png", ".stl", ".dae")) for k in want)  # a terrain or walls
    for layout in layouts:
        mcap = rewrite(bag, tmp_path, layout)
        out = tmp_path / layout
        code, got_stdout, err = run(capsys, "bag2world", mcap, "-o", out, *options)
        assert code == 0 and err == want_err, err  # the same replay warning, if any
        got = normalised_outputs(out, mcap)
        assert sorted(got) == sorted(want)
        assert [k for k in want if got[k] != want[k]] == [], layout
        assert got_stdout.replace(str(out), "OUT").replace(mcap.name, "SOURCE").replace(
            mcap.stem, "STEM"
        ) == stdout.replace(str(tmp_path / "bag"), "OUT").replace(bag.name, "SOURCE").replace(
            bag.stem, "STEM"
        )


def test_convert_ros1_mcap_gives_the_cloud_of_the_bag(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    options = ["--end", "10"]
    code, _, err = run(capsys, "convert", FUSE, tmp_path / "bag.ply", *options)
    assert code == 0, err
    for layout in ("zstd", "unchunked-no-summary"):
        mcap = rewrite(FUSE, tmp_path, layout)
        code, _, err = run(capsys, "convert", mcap, tmp_path / f"{layout}.ply", *options)
        assert code == 0, err
        assert (tmp_path / f"{layout}.ply").read_bytes() == (tmp_path / "bag.ply").read_bytes()


def test_inspect_ros1_mcap(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, want, err = run(capsys, "inspect", FUSE)
    assert code == 0, err
    mcap = rewrite(FUSE, tmp_path, "lz4-no-summary")
    code, got, err = run(capsys, "inspect", mcap)
    assert code == 0 and err == "", err

    def same(report: str) -> list[str]:  # but for the file named, and how it is encoded
        kept = report.splitlines()[1:]
        return [x for x in kept if not any(w in x for w in ("read with", "decoded as"))]

    assert same(got) == same(want)


def _bad(tmp: Path) -> dict[str, tuple[Path, str]]:
    cases = {}
    data = rewrite(FUSE, tmp, "none").read_bytes()
    half = tmp / "half.mcap"
    half.write_bytes(data[: len(data) // 2])
    cases["truncated"] = (half, "the MCAP file is truncated or damaged: its end marker is missing")
    crc = bytearray(data)
    at = first_chunk_data(data) + 100
    crc[at] ^= 0xFF
    bad = tmp / "crc.mcap"
    bad.write_bytes(bytes(crc))
    cases["chunk crc"] = (bad, "fails its CRC check")
    flat = one_message_mcap(tmp / "flat.mcap", [("/scan", "flatbuffer", "flatbuffer", None)])
    cases["unknown schema encoding"] = (flat, "no channel of this MCAP file can be read: /scan:")
    lost = one_message_mcap(tmp / "lost.mcap", [("/scan", "ros1", "ros1msg", 9)])
    cases["missing schema"] = (lost, "names schema 9, which is missing")
    return cases


@pytest.mark.parametrize("stream", [False, True], ids=["octree", "stream"])
@pytest.mark.parametrize("case", ["truncated", "chunk crc", "unknown schema encoding",
                                  "missing schema"])  # fmt: skip
def test_bad_mcap_one_line_exit_2_nothing_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str, stream: bool
) -> None:
    (tmp_path / "in").mkdir()
    named, message = _bad(tmp_path / "in")[case]
    outs = tmp_path / "outs"
    outs.mkdir()
    extra = ["--stream"] if stream else []
    code, stdout, err = run(capsys, "bag2world", named, "-o", outs / "w", *extra)
    assert code == 2 and stdout == ""
    assert err.count("\n") == 1 and err.startswith(f"scan2terrain: error: {named}: "), err
    assert message in err
    assert list(outs.iterdir()) == []
