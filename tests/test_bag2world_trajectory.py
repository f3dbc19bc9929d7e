"""A bag with poses but nothing to map (issue 25 item 13): odometry or tf, IMU, GPS, no scans.

bag2world writes the robot's trajectory, ``OUT/trajectory.tum`` (TUM: ``t x y z qx qy qz qw``,
the robot base in the fixed frame, what ``--trajectory`` reads), and no world, and says so;
``inspect`` says it would; a bag with neither scans nor poses is refused (one line, exit 2,
nothing written).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from scan2terrain.cli import main
from scan2terrain.readers.tracks import read_tum
from tests.bagmaker import Fmt, synthetic_room, write_bag

MOUNT = ["--mount", "0.2", "0", "0.3", "0", "0", "0"]  # bagmaker's default laser mount
T0 = 1_700_000_000_000_000_000


def run(capsys: pytest.CaptureFixture[str], *args: object) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def without_scans(messages: list[Any]) -> list[Any]:
    return [m for m in messages if m[0] != "/scan"]


def imu_and_gps(n: int = 10) -> list[Any]:
    out: list[Any] = []
    for k in range(n):
        t = T0 + k * 100_000_000
        stamp = {"stamp": t, "frame_id": "imu"}
        out.append(("/imu", "sensor_msgs/msg/Imu", t, {"header": stamp,
                    "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}))  # fmt: skip
        fix = {"header": {"stamp": t, "frame_id": "gps"}, "latitude": 47.0 + k * 1e-6,
               "longitude": 8.0, "altitude": 400.0}  # fmt: skip
        out.append(("/fix", "sensor_msgs/msg/NavSatFix", t, fix))
    return out


def odometry_poses(messages: list[Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(times ns, positions, quaternions xyzw) of the /odom messages, in time order."""
    rows = sorted(
        (m[3]["header"]["stamp"], m[3]["pose"]["pose"]) for m in messages if m[0] == "/odom"
    )
    t = np.array([r[0] for r in rows], dtype=np.int64)
    p = np.array([[r[1]["position"][a] for a in "xyz"] for r in rows])
    q = np.array([[r[1]["orientation"][a] for a in "xyzw"] for r in rows])
    return t, p, q


@pytest.mark.parametrize("fmt", ["ros1", "sqlite3"])
def test_odometry_bag_writes_its_trajectory_and_no_world(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], fmt: Fmt
) -> None:
    room = synthetic_room("odom", n_scans=40)
    messages = without_scans(room.messages) + imu_and_gps()
    bag = write_bag(tmp_path / ("odom.bag" if fmt == "ros1" else "odom"), fmt, messages)
    out = tmp_path / "w"
    code, stdout, err = run(capsys, "bag2world", bag, "-o", out)
    assert code == 0 and err == "", err
    assert sorted(p.name for p in out.iterdir()) == ["scan2terrain.yaml", "trajectory.tum"]
    first = stdout.splitlines()[0]
    assert first.startswith(f"Wrote {out}/ (no world: nothing to map") and "no scans" in first
    assert "trajectory.tum" in stdout and "40 poses of base_link in odom" in stdout
    # Exactly the odometry: times to the nanosecond, positions bit for bit (what --trajectory
    # reads back).
    track = read_tum(out / "trajectory.tum")
    t, p, q = odometry_poses(messages)
    assert np.array_equal(track.times_ns, t)
    assert np.array_equal(track.translations, p)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    got = track.quaternions_xyzw  # the same rotations, signs made continuous (q and -q are one)
    assert (np.einsum("ij,ij->i", got[1:], got[:-1]) >= 0).all()
    q *= np.sign(np.einsum("ij,ij->i", got, q))[:, None]
    np.testing.assert_allclose(got, q, rtol=0, atol=1e-15)
    lines = (out / "trajectory.tum").read_text().splitlines()
    assert lines[0].startswith("# base_link in odom (odometry /odom) from odom")
    assert len([line for line in lines if not line.startswith("#")]) == 40
    # the same folder, byte for byte, on the streamed path
    code, _, err = run(capsys, "bag2world", bag, "-o", tmp_path / "s", "--stream")
    assert code == 0, err
    assert (tmp_path / "s/trajectory.tum").read_bytes() == (out / "trajectory.tum").read_bytes()


def test_tf_bag_writes_the_base_in_the_map_frame(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """/tf map -> odom (every 4th sample) and odom -> base_link: base_link in map at every time
    both are known (no extrapolation past the last map -> odom sample)."""
    room = synthetic_room("tf", n_scans=40)
    bag = write_bag(tmp_path / "tf.bag", "ros1", without_scans(room.messages))
    out = tmp_path / "w"
    code, stdout, err = run(capsys, "bag2world", bag, "-o", out)
    assert code == 0 and err == "", err
    assert "poses of base_link in map (tf)" in stdout
    track = read_tum(out / "trajectory.tum")
    m2o = room.map_to_odom
    samples = []  # (t, x, y, yaw) of base_link in map, from each odom -> base_link sample
    for topic, _, _, msg in room.messages:
        if topic != "/tf":
            continue
        for tr in msg["transforms"]:
            if tr["child_frame_id"] == "base_link":
                v, r = tr["transform"]["translation"], tr["transform"]["rotation"]
                xy = m2o.rotation[:2, :2] @ [v["x"], v["y"]] + m2o.translation[:2]
                yaw = 2 * math.atan2(r["z"], r["w"]) + math.atan2(
                    m2o.rotation[1, 0], m2o.rotation[0, 0]
                )
                samples.append((tr["header"]["stamp"], *xy, yaw))
    last_m2o = max(
        tr["header"]["stamp"]
        for topic, _, _, msg in room.messages
        if topic == "/tf"
        for tr in msg["transforms"]
        if tr["child_frame_id"] == "odom"
    )
    times = np.array([s[0] for s in samples if s[0] <= last_m2o], dtype=np.int64)
    want = np.array([s for s in samples if s[0] <= last_m2o], dtype=np.float64)
    assert len(times) > 60 and np.array_equal(track.times_ns, times)
    np.testing.assert_allclose(track.translations[:, :2], want[:, 1:3], rtol=0, atol=1e-12)
    np.testing.assert_allclose(track.translations[:, 2], 0.0, atol=1e-12)
    q = track.quaternions_xyzw
    yaws = 2 * np.arctan2(q[:, 2], q[:, 3])
    np.testing.assert_allclose(np.angle(np.exp(1j * (yaws - want[:, 3]))), 0.0, atol=1e-12)


def test_the_written_trajectory_poses_the_scans_as_the_odometry_did(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--trajectory reads what bag2world writes: the scans of the same recording posed by the
    trajectory of its pose-only twin give the world the odometry gives."""
    room = synthetic_room("odom", n_scans=40)
    full = write_bag(tmp_path / "full.bag", "ros1", room.messages)
    poses = write_bag(tmp_path / "poses.bag", "ros1", without_scans(room.messages))
    code, _, err = run(capsys, "bag2world", poses, "-o", tmp_path / "t")
    assert code == 0, err
    tum = tmp_path / "t/trajectory.tum"
    options = [*MOUNT, "--resolution", "0.1", "--geometry", "heightmap", "--no-preview"]
    code, _, err = run(
        capsys,
        "bag2world",
        full,
        "-o",
        tmp_path / "a",
        "--poses",
        "odom",
        "--correct",
        "off",
        *options,
    )
    assert code == 0, err
    code, _, err = run(capsys, "bag2world", full, "-o", tmp_path / "b", "--trajectory", tum,
                       *options)  # fmt: skip
    assert code == 0, err
    a = {p.relative_to(tmp_path / "a"): p for p in (tmp_path / "a").rglob("*") if p.is_file()}
    b = {p.relative_to(tmp_path / "b"): p for p in (tmp_path / "b").rglob("*") if p.is_file()}
    assert sorted(a) == sorted(b)
    differ = sorted(str(k) for k in a if a[k].read_bytes() != b[k].read_bytes())
    # scans.poses and scans.trajectory; the replay's pose source, not its figures
    assert differ == ["fidelity.yaml", "scan2terrain.yaml"]
    replays = [yaml.safe_load((tmp_path / c / "fidelity.yaml").read_text()) for c in "ab"]
    assert replays[0]["worlds"] == replays[1]["worlds"]
    assert replays[0]["pose_source"] != replays[1]["pose_source"]


def test_inspect_says_there_is_nothing_to_map(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    room = synthetic_room("odom", n_scans=20)
    bag = write_bag(tmp_path / "odom.bag", "ros1", without_scans(room.messages))
    code, stdout, err = run(capsys, "inspect", bag)
    assert code == 0 and err == "", err
    plan = stdout[stdout.index("  bag2world would use:") :]
    assert "nothing to map" in plan and "OUT/trajectory.tum" in plan and "/odom" in plan


def test_no_scans_and_no_poses_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = write_bag(tmp_path / "imu.bag", "ros1", imu_and_gps())
    out = tmp_path / "outs"
    out.mkdir()
    code, stdout, err = run(capsys, "bag2world", bag, "-o", out / "w")
    assert code == 2 and stdout == ""
    (line,) = err.splitlines()
    assert line.startswith(f"scan2terrain: error: {bag}: nothing to map and no trajectory")
    assert "/imu (sensor_msgs/msg/Imu, 10)" in line and "/fix" in line
    assert list(out.iterdir()) == []
    code, stdout, _ = run(capsys, "inspect", bag)
    assert code == 0 and "bag2world would stop: nothing to map and no trajectory" in stdout


@pytest.mark.parametrize("poses", ["trajectory", "fixed"])
def test_poses_that_are_not_the_bags_give_no_trajectory(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], poses: str
) -> None:
    room = synthetic_room("odom", n_scans=20)
    bag = write_bag(tmp_path / "odom.bag", "ros1", without_scans(room.messages))
    tum = tmp_path / "given.tum"
    tum.write_text("1 0 0 0 0 0 0 1\n2 1 0 0 0 0 0 1\n")
    given = ["--trajectory", tum] if poses == "trajectory" else ["--pose", *"000000"]
    code, stdout, err = run(capsys, "bag2world", bag, "-o", tmp_path / "w", *given)
    assert code == 2 and stdout == "" and err.count("\n") == 1
    assert "nothing to map" in err and f"--poses {poses}" in err
    assert not (tmp_path / "w").exists()


def test_convert_says_there_are_no_scans(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    room = synthetic_room("odom", n_scans=20)
    bag = write_bag(tmp_path / "odom.bag", "ros1", without_scans(room.messages))
    code, _, err = run(capsys, "convert", bag, tmp_path / "c.ply")
    assert code == 2 and err.count("\n") == 1 and "no scans: nothing to convert" in err, err
    assert not (tmp_path / "c.ply").exists()
