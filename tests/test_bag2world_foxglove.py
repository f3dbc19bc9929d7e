"""Foxglove's own schemas in MCAP through the command line (issue 16): the same recording as a
ROS1 bag and re-encoded as Foxglove protobuf and JSON schemas (LaserScan or PointCloud, and
FrameTransform(s)) gives the same world, byte for byte but for the names taken from the input
file; a ``foxglove.Grid`` occupancy grid gives the world of the equivalent map_server map;
``inspect`` and ``convert`` read them; bad Foxglove input is one line, exit 2, nothing written.

The re-encoding is :func:`tests.bagmaker.ros_bag_to_foxglove_mcap` (the ``mcap`` writer, the
``foxglove-schemas-protobuf`` classes and their descriptors as ``mcap-protobuf-support``
writes them, or JSON).
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from scan2terrain.cli import main
from scan2terrain.readers.mapserver import read_map_yaml
from tests.bagmaker import (
    FoxgloveEncoding,
    McapCompression,
    foxglove_message_bytes,
    ros_bag_to_foxglove_mcap,
    synthetic_room,
    write_foxglove_mcap,
)
from tests.fixtures import EMBARK_ROS1, MAPS
from tests.world_checks import STATIONARY, normalised_outputs


def run(capsys: pytest.CaptureFixture[str], *args: object) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def same_world(
    capsys: pytest.CaptureFixture[str],
    tmp: Path,
    want_cmd: list[object],
    want_source: Path,
    got_source: Path,
    options: list[object],
) -> None:
    """``want_cmd`` (a command and its input) and ``bag2world got_source`` with ``options``
    write the same files (names from the input replaced) and print the same report."""
    code, want_stdout, want_err = run(capsys, *want_cmd, "-o", tmp / "want", *options)
    assert code == 0, want_err
    want = normalised_outputs(tmp / "want", want_source)
    assert "map/map.pgm" in want
    code, got_stdout, err = run(capsys, "bag2world", got_source, "-o", tmp / "got", *options)
    assert code == 0 and err == want_err, err  # the same replay warning, if any
    got = normalised_outputs(tmp / "got", got_source)
    assert sorted(got) == sorted(want)
    assert [k for k in want if got[k] != want[k]] == []

    def report(text: str, out: Path, source: Path) -> str:
        return text.replace(str(out), "OUT").replace(source.name, "SOURCE")

    if want_cmd[0] == "bag2world":
        assert report(got_stdout, tmp / "got", got_source) == report(
            want_stdout, tmp / "want", want_source
        )
    shutil.rmtree(tmp / "got")
    shutil.rmtree(tmp / "want")


# id -> (encoding, compression, summary, split_tf)
ENCODINGS: dict[str, tuple[FoxgloveEncoding, McapCompression, bool, bool]] = {
    "protobuf": ("protobuf", "zstd", True, False),
    "json": ("json", "lz4", True, False),
    "protobuf-no-summary-frame-transform": ("protobuf", "none", False, True),
}


def foxglove(bag: Path, tmp: Path, case: str) -> Path:
    encoding, compression, summary, split_tf = ENCODINGS[case]
    folder = tmp / case
    folder.mkdir()
    return ros_bag_to_foxglove_mcap(
        bag,
        folder / f"{bag.stem}.mcap",
        encoding,
        compression=compression,
        summary=summary,
        split_tf=split_tf,
    )


@pytest.fixture(scope="module")
def room_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    room = synthetic_room("tf", n_scans=60)
    return room.write(tmp_path_factory.mktemp("room") / "room.bag", "ros1")


ROOM_OPTIONS = {
    "octree": ["--resolution", "0.05", "--geometry", "heightmap", "--no-preview"],
    "stream": ["--resolution", "0.05", "--stream", "--no-preview"],
}
#: The room's LaserScans' range_max, which a foxglove.LaserScan lacks (without it the Foxglove
#: plan notes that +inf readings clear nothing; the room has none).
RANGE_MAX = ["--max-range", "30"]


@pytest.mark.parametrize(
    ("case", "mode"), [*((c, "octree") for c in ENCODINGS), ("protobuf", "stream")]
)
def test_foxglove_laserscan_and_transforms_give_the_world_of_the_bag(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], room_bag: Path, case: str, mode: str
) -> None:
    mcap = foxglove(room_bag, tmp_path, case)
    options: list[object] = [*ROOM_OPTIONS[mode], *RANGE_MAX]
    same_world(capsys, tmp_path, ["bag2world", room_bag], room_bag, mcap, options)


def open_side_bag(tmp: Path, range_max: float) -> Path:
    """A stationary laser (at the origin, --pose) beside a wall: beams towards y < 0 meet it at
    y = -3 for |x| <= 6, past its ends they read 10 m (beyond ``range_max``: they only clear),
    beams towards y > 0 have no return (+inf); some NaN (invalid) and -inf (too close) readings
    in both halves."""
    from tests.bagmaker import LASER_SCAN, laserscan_msg, write_bag

    beams = 360
    inc = 2 * np.pi / beams
    angles = -np.pi + inc * np.arange(beams)
    with np.errstate(divide="ignore"):
        wall = -3.0 / np.sin(angles)
    below = np.sin(angles) < -1e-9
    ranges = np.where(below, np.where(np.abs(wall * np.cos(angles)) <= 6.0, wall, 10.0), np.inf)
    ranges[7::41] = np.nan
    ranges[11::53] = -np.inf
    t0 = 1_700_000_000_000_000_000
    messages = [
        ("/scan", LASER_SCAN, t0 + k * 100_000_000,
         laserscan_msg(t0 + k * 100_000_000, "laser", -np.pi, inc, ranges, 0.05, range_max))
        for k in range(3)
    ]  # fmt: skip
    assert np.isinf(ranges).sum() > 100 and (np.isfinite(ranges) & (ranges >= range_max)).any()
    return write_bag(tmp / "open.bag", "ros1", messages)


OPEN_OPTIONS = [*STATIONARY, "--resolution", "0.1", "--geometry", "heightmap", "--no-preview"]


@pytest.mark.parametrize("mode", ["octree", "stream"])
@pytest.mark.parametrize("case", ["protobuf", "json"])
def test_no_return_readings_give_the_same_world_in_both_containers(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str, mode: str
) -> None:
    """REP 117 on both paths: a ROS LaserScan's +inf clears up to its range_max; a Foxglove
    LaserScan's up to --max-range, which stands for the range_max it lacks. The same readings
    then give the same world (and report), byte for byte."""
    bag = open_side_bag(tmp_path, range_max=8.0)
    mcap = foxglove(bag, tmp_path, case)
    options: list[object] = [*OPEN_OPTIONS, "--max-range", "8"]
    options += ["--stream"] if mode == "stream" else []
    same_world(capsys, tmp_path, ["bag2world", bag], bag, mcap, options)
    if mode == "octree":  # the ROS bag without --max-range: its own range_max, the same world
        code, _, err = run(capsys, "bag2world", bag, "-o", tmp_path / "ros", *OPEN_OPTIONS)
        assert code == 0, err
        code, _, err = run(capsys, "bag2world", mcap, "-o", tmp_path / "fg", *options)
        assert code == 0, err
        want = normalised_outputs(tmp_path / "ros", bag)
        got = normalised_outputs(tmp_path / "fg", mcap)
        assert got.pop("scan2terrain.yaml") != want.pop("scan2terrain.yaml")  # octree.max_range
        assert got == want
        # and the no-return half is known free: the +inf beams cleared it
        _, grid = read_map_yaml(tmp_path / "fg/map/map_gz.yaml")
        ys = grid.origin.y + (np.arange(grid.data.shape[0]) + 0.5) * grid.resolution
        upper = grid.data[ys > 1.0]
        semicircle = np.pi * 8**2 / 2 / 0.1**2  # cells within range_max on the open side
        assert (upper == 0).sum() > 0.5 * semicircle


def test_foxglove_laserscan_without_max_range_says_its_no_return_readings_clear_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = open_side_bag(tmp_path, range_max=8.0)
    mcap = foxglove(bag, tmp_path, "protobuf")
    code, stdout, err = run(capsys, "bag2world", mcap, "-o", tmp_path / "fg", *OPEN_OPTIONS)
    assert code == 0, err
    note = "/scan: foxglove.LaserScan has no range_max: its no-return (+inf) readings clear "
    assert note + "nothing; give --max-range" in stdout
    _, grid = read_map_yaml(tmp_path / "fg/map/map_gz.yaml")
    ys = grid.origin.y + (np.arange(grid.data.shape[0]) + 0.5) * grid.resolution
    assert not (grid.data[ys > 1.0] == 0).any()  # nothing cleared the no-return half
    code, stdout, err = run(capsys, "inspect", mcap, *STATIONARY)
    assert code == 0 and note in stdout, err
    code, stdout, err = run(capsys, "inspect", bag, *STATIONARY)  # a ROS scan has its range_max
    assert code == 0 and "no range_max" not in stdout, err
    code, stdout, err = run(capsys, "inspect", mcap, *STATIONARY, "--max-range", "8")
    assert code == 0 and note not in stdout, err  # inspect takes it as bag2world does


@pytest.mark.parametrize("case", ["protobuf", "json"])
def test_foxglove_pointcloud_gives_the_world_of_the_bag(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str
) -> None:
    # as the ROS1 MCAP twin: 0.5 m voxels, one fixed pose
    options: list[object] = ["--topic", "/luminar_pointcloud", *STATIONARY]
    options += ["--resolution", "0.5", "--no-preview"]
    mcap = foxglove(EMBARK_ROS1, tmp_path, case)
    same_world(capsys, tmp_path, ["bag2world", EMBARK_ROS1], EMBARK_ROS1, mcap, options)


def grid_messages(yaml: Path) -> list[tuple[str, str, int, Any]]:
    """A map_server map as one foxglove.Grid message (INT8 occupancy, row 0 at the origin)."""
    _, grid = read_map_yaml(yaml)
    w = grid.data.shape[1]
    res = float(grid.resolution)
    o = grid.origin
    value = {
        "timestamp": {"sec": 1_700_000_000, "nsec": 0},
        "frame_id": "map",
        "pose": {
            "position": {"x": o.x, "y": o.y, "z": 0.0},
            "orientation": {"x": 0.0, "y": 0.0, "z": np.sin(o.yaw / 2), "w": np.cos(o.yaw / 2)},
        },
        "column_count": w,
        "cell_size": {"x": res, "y": res},
        "row_stride": w,
        "cell_stride": 1,
        "fields": [{"name": "occupancy", "offset": 0, "type": 2}],
        "data": np.ascontiguousarray(grid.data, dtype=np.int8).tobytes(),
    }
    return [("/map", "foxglove.Grid", 1_700_000_000_000_000_000, value)]


@pytest.mark.parametrize("encoding", ["protobuf", "json"])
def test_foxglove_grid_gives_the_world_of_the_map_server_map(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], encoding: FoxgloveEncoding
) -> None:
    yaml = MAPS["tb3"]
    mcap = write_foxglove_mcap(tmp_path / f"{yaml.stem}.mcap", grid_messages(yaml), encoding)
    same_world(capsys, tmp_path, ["map2world", yaml], yaml, mcap, ["--no-preview"])


def test_inspect_foxglove_mcap(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], room_bag: Path
) -> None:
    code, want, err = run(capsys, "inspect", room_bag)
    assert code == 0, err
    mcap = foxglove(room_bag, tmp_path, "json")
    code, got, err = run(capsys, "inspect", mcap)
    assert code == 0 and err == "", err
    assert "MCAP, profile '', read with mcap" in got
    assert (
        "json / jsonschema foxglove.LaserScan, decoded as JSON, read as scans (laser; no "
        "range_max: --max-range stands for it)" in got
    )
    assert "read as tf" in got
    # the same tf tree, and the same plan, but for what a missing range_max means
    note = "    /scan: foxglove.LaserScan has no range_max: its no-return (+inf) readings clear "
    lines = got[got.index("  tf tree:") :].splitlines()
    assert [line for line in lines if line.startswith(note)] != []
    tail = want[want.index("  tf tree:") :]
    assert "\n".join(line for line in lines if not line.startswith(note)) + "\n" == tail


def test_convert_foxglove_mcap_gives_the_cloud_of_the_bag(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], room_bag: Path
) -> None:
    code, _, err = run(capsys, "convert", room_bag, tmp_path / "bag.ply")
    assert code == 0, err
    mcap = foxglove(room_bag, tmp_path, "protobuf")
    code, _, err = run(capsys, "convert", mcap, tmp_path / "fg.ply")
    assert code == 0, err
    assert (tmp_path / "fg.ply").read_bytes() == (tmp_path / "bag.ply").read_bytes()


# --- bad input ----------------------------------------------------------------------------------


def _raw_mcap(path: Path, schema: tuple[str, str, bytes], encoding: str, payload: bytes) -> Path:
    from mcap.writer import CompressionType
    from mcap.writer import Writer as McapWriter

    with path.open("wb") as f:
        w = McapWriter(f, compression=CompressionType.NONE)
        w.start(profile="", library="test")
        sid = w.register_schema(*schema)
        cid = w.register_channel("/scan", encoding, sid)
        w.add_message(cid, 1000, payload, 1000)
        w.finish()  # type: ignore[no-untyped-call]
    return path


def _bad(tmp: Path) -> dict[str, tuple[Path, str]]:
    from tests.bagmaker import foxglove_schema

    scan = {"frame_id": "laser", "start_angle": 0.0, "end_angle": 1.0, "ranges": [1.0, 2.0]}
    pb = foxglove_schema("foxglove.LaserScan", "protobuf")
    good = foxglove_message_bytes("foxglove.LaserScan", scan, "protobuf")
    return {
        "unknown schema": (
            _raw_mcap(tmp / "unknown.mcap", ("foxglove.Nothing", *pb), "protobuf", good),
            "no channel of this MCAP file can be read: /scan: the protobuf schema of "
            "foxglove.Nothing cannot be used (its FileDescriptorSet does not define "
            "foxglove.Nothing)",
        ),
        "protobuf that does not parse": (
            _raw_mcap(tmp / "garbage.mcap", ("foxglove.LaserScan", *pb), "protobuf", b"\xff" * 9),
            "message on /scan at 0.000 s cannot be decoded as foxglove.LaserScan",
        ),
        "JSON not an object": (
            _raw_mcap(
                tmp / "list.mcap",
                ("foxglove.LaserScan", "jsonschema", b"{}"),
                "json",
                b"[1, 2, 3]",
            ),
            "cannot be decoded as foxglove.LaserScan (a JSON message is an object, not list)",
        ),
        "JSON that is not JSON": (
            _raw_mcap(
                tmp / "text.mcap", ("foxglove.LaserScan", "jsonschema", b"{}"), "json", b"{nope"
            ),
            "cannot be decoded as foxglove.LaserScan (Expecting property name",
        ),
    }


BAD = ["unknown schema", "protobuf that does not parse", "JSON not an object",
       "JSON that is not JSON"]  # fmt: skip


@pytest.mark.parametrize("stream", [False, True], ids=["octree", "stream"])
@pytest.mark.parametrize("case", BAD)
def test_bad_foxglove_mcap_one_line_exit_2_nothing_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str, stream: bool
) -> None:
    (tmp_path / "in").mkdir()
    named, message = _bad(tmp_path / "in")[case]
    outs = tmp_path / "outs"
    outs.mkdir()
    extra = ["--stream"] if stream else []
    code, stdout, err = run(capsys, "bag2world", named, "-o", outs / "w", *STATIONARY, *extra)
    assert code == 2 and stdout == ""
    assert err.count("\n") == 1 and err.startswith(f"scan2terrain: error: {named}: "), err
    assert message in err
    assert list(outs.iterdir()) == []


def elevation_grid(heights: np.ndarray, res: float, x0: float, y0: float, z0: float) -> Any:
    """One foxglove.Grid message of FLOAT32 ``elevation`` cells (row 0 at the origin)."""
    cols = heights.shape[1]
    return {
        "timestamp": {"sec": 1_700_000_000, "nsec": 0},
        "frame_id": "map",
        "pose": {
            "position": {"x": x0, "y": y0, "z": z0},
            "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
        },
        "column_count": cols,
        "cell_size": {"x": res, "y": res},
        "row_stride": 4 * cols,
        "cell_stride": 4,
        "fields": [{"name": "elevation", "offset": 0, "type": 7}],
        "data": np.ascontiguousarray(heights, dtype="<f4").tobytes(),
    }


@pytest.mark.parametrize("encoding", ["protobuf", "json"])
def test_foxglove_elevation_grid_becomes_terrain_at_its_heights(
    tmp_path: Path, encoding: FoxgloveEncoding
) -> None:
    """A grid_map-style elevation layer: Gazebo's ground (gz-common's loader, the collision
    placement gz-sim uses) is at the grid's heights at its cell centres, in the grid's frame."""
    from scan2terrain.cli import COMMAND_DEFAULTS
    from scan2terrain.commands.scans import bag2world
    from scan2terrain.config import load_config
    from tests.world_checks import ground

    res, x0, y0, z0 = 0.25, 3.0, -2.0, 0.5
    rows, cols = 48, 64
    yy, xx = np.mgrid[0:rows, 0:cols] * res
    heights = 1.0 + 0.5 * np.sin(xx / 2) + 0.3 * np.cos(yy / 3)
    holes = heights.copy()
    holes[:3, :4] = np.nan  # no height: sits at the lowest known one
    messages = [("/elevation", "foxglove.Grid", 1_700_000_000_000_000_000,
                 elevation_grid(holes, res, x0, y0, z0))]  # fmt: skip
    mcap = write_foxglove_mcap(tmp_path / "grid.mcap", messages, encoding)
    cfg = load_config(
        None, {"world.simulator": "gz"}, defaults=COMMAND_DEFAULTS.get("bag2world", {})
    )
    result = bag2world([mcap], tmp_path / "w", cfg)
    assert "height grid: 64 x 48 cells" in result.notes
    x = x0 + (np.arange(cols) + 0.5) * res
    y = y0 + (np.arange(rows) + 0.5) * res
    gx, gy = np.meshgrid(x, y)
    got = ground(result, tmp_path, gx, gy)
    want = heights + z0
    inner = np.ones_like(want, bool)
    inner[:4, :5] = False  # next to the holes the ground bends down to them
    span = float(want.max() - want.min())
    err = np.abs(got - want)
    # Gazebo's grid is the heights resampled to 2^n + 1 samples a side (bilinear): within a
    # centimetre (0.6 % of the 1.6 m span) inside, a little more on the outermost cells.
    assert err[inner].max() < 0.02 * span, err[inner].max()
    inside = inner.copy()
    inside[[0, -1], :] = inside[:, [0, -1]] = False
    assert err[inside].max() < 0.01 * span and err[inside].mean() < 0.003 * span
    assert got[0, 0] == pytest.approx(float(np.nanmin(holes)) + z0, abs=0.02 * span)


def test_tilted_or_empty_elevation_grid_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    flat = np.zeros((4, 5))
    tilted = elevation_grid(flat, 0.5, 0.0, 0.0, 0.0)
    tilted["pose"]["orientation"] = {"x": 0.2, "y": 0.0, "z": 0.0, "w": 0.98}
    empty = elevation_grid(np.full((4, 5), np.nan), 0.5, 0.0, 0.0, 0.0)
    for name, value, problem in [
        ("tilted", tilted, "a height grid must lie level"),
        ("empty", empty, "holds no finite height"),
    ]:
        mcap = write_foxglove_mcap(
            tmp_path / f"{name}.mcap", [("/e", "foxglove.Grid", 1000, value)], "json"
        )
        code, out, err = run(capsys, "bag2world", mcap, "-o", tmp_path / name)
        assert code == 2 and out == "", err
        assert err.count("\n") == 1 and f"{mcap}: /e: " in err and problem in err, err
        assert not (tmp_path / name).exists()
