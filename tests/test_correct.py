"""Pose correction (``--correct``, slam/): synthetic recordings with known truth made by
tests/slamworld.py (a laser ray-cast into a known scene, odometry drifting on purpose: 2% scale,
0.5 deg/m yaw bias, noise), a look-alike scene, a wrong closure injected by hand, a recording
with a SLAM map frame, and the same bytes on every run and path."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from numpy.typing import NDArray
from PIL import Image

from scan2terrain.cli import main
from scan2terrain.slam import planar, pose2
from scan2terrain.slam.graph import Closure, PoseGraph
from scan2terrain.types import PoseCorrection
from tests import slamworld as sw
from tests.fixtures import MIT_DIR

RES = 0.05


def run(capsys: pytest.CaptureFixture[str], *args: object) -> tuple[int, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out + err


@pytest.mark.parametrize("scene", ["corridor_loop", "rooms"])
def test_drifting_odometry_is_corrected_to_the_truth(scene: str) -> None:
    rec = sw.simulate(scene)
    raw, _ = sw.aligned_errors(rec.odom_laser_poses, rec.laser_poses)
    assert raw.max() > 0.5  # the odometry really drifts
    result = planar.correct(rec.odom_laser_poses, sw.flat_scans(rec))
    assert result.accepted >= 3  # the loop was closed
    err, yaw = sw.aligned_errors(result.poses, rec.laser_poses)
    assert np.percentile(err, 95) <= 0.02, (np.percentile(err, 95), err.max())
    assert err.mean() <= 0.015
    assert yaw.max() <= 0.5
    # Every kept closure is a true one: its relative pose is the truth's.
    for c in result.closures:
        if c.kept:
            truth = pose2.between(rec.laser_poses[c.earlier], rec.laser_poses[c.later])
            assert np.hypot(*(c.relative[:2] - truth[:2])) < 0.1


def test_look_alike_corridors_are_not_closed() -> None:
    """Two corridors 4 m apart with the same niches at the same places: a closure between
    them would pull one onto the other. None is kept, and the trajectory stays true."""
    rec = sw.simulate("parallel_corridors")
    result = planar.correct(rec.odom_laser_poses, sw.flat_scans(rec))
    assert result.candidates > 0  # searches were made
    for c in result.closures:
        truth = pose2.between(rec.laser_poses[c.earlier], rec.laser_poses[c.later])
        wrong = np.hypot(*(c.relative[:2] - truth[:2])) > 0.5
        assert not (wrong and c.kept), (c, truth)
    err, yaw = sw.aligned_errors(result.poses, rec.laser_poses)
    assert err.max() <= 0.1 and yaw.max() <= 1.0


def test_a_wrong_closure_injected_by_hand_is_dropped() -> None:
    """A square loop driven twice: true closures between the laps, and one wrong closure (the
    second lap's corner put 3 m off) that the robust graph must refuse."""
    side = np.linspace(0, 10, 41)[:-1]
    lap = np.concatenate(
        [
            np.c_[side, 0 * side, 0 * side],
            np.c_[10 + 0 * side, side, 0 * side + math.pi / 2],
            np.c_[10 - side, 10 + 0 * side, 0 * side + math.pi],
            np.c_[0 * side, 10 - side, 0 * side - math.pi / 2],
        ]
    )
    truth = np.concatenate([lap, lap])
    rng = np.random.default_rng(3)
    steps = pose2.between(truth[:-1], truth[1:])
    steps[:, 2] += rng.normal(0, 0.004, len(steps)) + 0.002  # drifting heading
    drifted = [truth[0]]
    for st in steps:
        drifted.append(pose2.compose(drifted[-1], st))
    sigmas = np.tile([0.02, 0.02, 0.005], (len(steps), 1))
    n = len(lap)
    graphs = [PoseGraph(np.array(drifted), sigmas) for _ in range(2)]
    for graph in graphs:
        for k in range(0, n, 10):
            graph.add(Closure(k, n + k, pose2.between(truth[k], truth[n + k]), 0.9))
    wrong = pose2.between(truth[20], truth[n + 20]) + np.array([3.0, 0.0, 0.0])
    graphs[1].add(Closure(20, n + 20, wrong, 0.9))
    clean, poses = graphs[0].final(), graphs[1].final()
    assert not graphs[1].closures[-1].kept
    assert all(c.kept for c in graphs[1].closures[:-1])
    # The same poses as without the wrong closure; the second lap lies on the first.
    assert np.hypot(*(poses[:, :2] - clean[:, :2]).T).max() < 0.01
    # (where the closures hold it: its last corner has none after it).
    last = n - 10
    assert np.hypot(*(poses[n : n + last, :2] - poses[:last, :2]).T).max() < 0.05


def test_pose_correction_moves_poses_between_its_stamps() -> None:
    prior = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    corrected = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.1]])
    c = PoseCorrection(
        np.array([0, 10], np.int64), prior, corrected, np.zeros((2, 3)), np.zeros((2, 4))
    )
    d = c.deltas(np.array([-5, 0, 5, 10, 20], np.int64))
    assert np.allclose(d[:2], 0) and np.allclose(d[2, 2], 0.05)
    assert np.allclose(d[3], d[4])  # held after the last stamp
    # The corrected scan's own pose comes out exactly.
    r, t = c.apply(np.array([10], np.int64), np.eye(3)[None], np.array([[1.0, 0.0, 0.3]]))
    assert np.allclose(t, [[1.0, 0.0, 0.3]]) and math.isclose(
        math.atan2(r[0, 1, 0], r[0, 0, 0]), 0.1
    )


@pytest.fixture(scope="module")
def loop_bag(tmp_path_factory: pytest.TempPathFactory) -> tuple[sw.Recording, Path]:
    rec = sw.simulate("corridor_loop")
    return rec, rec.write_bag(tmp_path_factory.mktemp("loop") / "loop.bag")


def occupied_distances(out: Path, scene: sw.Scene) -> NDArray[np.float64]:
    """Distance from each occupied cell's centre of OUT's map to the nearest true wall."""
    meta = yaml.safe_load((out / "map/map_gz.yaml").read_text())
    img = np.asarray(Image.open(out / "map" / meta["image"]))
    rows, cols = np.nonzero(img == 0)
    res, (ox, oy) = meta["resolution"], meta["origin"][:2]
    centres = np.c_[ox + (cols + 0.5) * res, oy + (img.shape[0] - rows - 0.5) * res]
    return scene.distance(centres)


def test_bag2world_world_matches_the_truth_within_a_cell(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], loop_bag: tuple[sw.Recording, Path]
) -> None:
    rec, bag = loop_bag
    worlds = {}
    for mode in ("auto", "off"):
        out = worlds[mode] = tmp_path / mode
        code, report = run(
            capsys, "bag2world", bag, "-o", out, "--correct", mode, "--resolution", RES
        )
        assert code == 0, report
        if mode == "auto":
            assert "correction (the poses are odometry)" in report
            assert "closures kept" in report and "poses moved" in report
            was, now = (float(v) for v in _agreement(report))
            assert now > was + 30
    # Every occupied cell of the corrected world touches a true wall's cell; raw odometry's
    # world is a smear metres off.
    near = occupied_distances(worlds["auto"], rec.scene)
    assert np.mean(near <= 1.5 * RES) >= 0.995 and near.max() <= 2.01 * RES
    assert occupied_distances(worlds["off"], rec.scene).max() > 0.5
    # trajectory.tum holds the corrected poses, trajectory_raw.tum the recorded ones.
    got = np.loadtxt(worlds["auto"] / "trajectory.tum")
    raw = np.loadtxt(worlds["auto"] / "trajectory_raw.tum")
    assert np.allclose(raw[:, 1:3], rec.odom_laser_poses[:, :2], atol=1e-4)
    err, _ = sw.aligned_errors(np.c_[got[:, 1:3], np.zeros(len(got))], rec.laser_poses * [1, 1, 0])
    assert np.percentile(err, 95) <= 0.02
    assert not (worlds["off"] / "trajectory_raw.tum").exists()


def test_fidelity_poses_the_recording_as_bag2world_does(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], loop_bag: tuple[sw.Recording, Path]
) -> None:
    """``fidelity WORLD BAG`` corrects a raw recording's poses as bag2world did when it wrote
    the world (``--correct`` is shared): the same beams, the same figure; ``--correct off``
    replays the odometry's smear in it."""
    _, bag = loop_bag
    code, report = run(capsys, "bag2world", bag, "-o", tmp_path / "w", "--insert", "endpoints")
    assert code == 0, report
    world = tmp_path / "w" / "world_gz.sdf"
    figures = {}
    for mode in ("auto", "off"):
        code, got = run(capsys, "fidelity", world, bag, "-o", tmp_path / mode, "--correct", mode)
        assert code == 0, got
        line = next(x for x in got.splitlines() if "recorded beams replayed" in x)
        figures[mode] = float(line.split("replayed: ")[1].split("%")[0])
    assert figures["auto"] == _within_10cm(report)
    assert figures["off"] < figures["auto"] - 30, figures
    assert (tmp_path / "auto" / "trajectory.tum").read_bytes() == (
        tmp_path / "w" / "trajectory.tum"
    ).read_bytes()


def _agreement(report: str) -> tuple[str, str]:
    line = next(x for x in report.splitlines() if "beams agreeing" in x)
    was, now = line.split(": ")[-1].split(" -> ")
    return was.split("%")[0], now.split("%")[0]


def test_a_recording_with_a_map_frame_is_left_alone(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rec = sw.simulate("corridor_loop", laps=0.5)
    bag = rec.write_bag(tmp_path / "slam.bag", map_frame=True)
    outs = {}
    for mode in ("auto", "off"):
        outs[mode] = tmp_path / mode
        code, report = run(capsys, "bag2world", bag, "-o", outs[mode], "--correct", mode)
        assert code == 0, report
        if mode == "auto":
            assert "correction: none (tf has the map frame 'map'" in report
    files = sorted(p.relative_to(outs["off"]) for p in outs["off"].rglob("*") if p.is_file())
    assert files == sorted(
        p.relative_to(outs["auto"]) for p in outs["auto"].rglob("*") if p.is_file()
    )
    for f in files:
        if f.name != "scan2terrain.yaml":  # records --correct itself
            assert (outs["auto"] / f).read_bytes() == (outs["off"] / f).read_bytes(), f


def _tree_bytes(out: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(out)): p.read_bytes()
        for p in sorted(out.rglob("*"))
        if p.is_file() and p.name != "scan2terrain.yaml"
    }


def test_same_bytes_on_rerun_one_thread_and_stream(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], loop_bag: tuple[sw.Recording, Path]
) -> None:
    _, bag = loop_bag
    args = ["bag2world", str(bag), "--insert", "endpoints", "--no-fidelity"]
    for name in ("a", "b"):
        code, report = run(capsys, *args, "-o", tmp_path / name)
        assert code == 0, report
    env = {**os.environ, "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    done = subprocess.run(
        [sys.executable, "-m", "scan2terrain", *args, "-o", str(tmp_path / "one")],
        env=env, capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    code, report = run(capsys, *args, "--stream", "-o", tmp_path / "stream")
    assert code == 0, report
    a = _tree_bytes(tmp_path / "a")
    assert "trajectory_raw.tum" in a
    assert a == _tree_bytes(tmp_path / "b") == _tree_bytes(tmp_path / "one")
    streamed = _tree_bytes(tmp_path / "stream")
    for name in ("trajectory.tum", "trajectory_raw.tum", "spawn.yaml"):
        assert streamed[name] == a[name], name


def test_correct_on_refines_given_poses_and_off_is_as_recorded(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rec = sw.simulate("corridor_loop", laps=0.5)
    bag = rec.write_bag(tmp_path / "slam.bag", map_frame=True)
    code, report = run(capsys, "bag2world", bag, "-o", tmp_path / "on", "--correct", "on")
    assert code == 0, report
    assert "correction (--correct on)" in report
    assert (tmp_path / "on" / "trajectory_raw.tum").exists()
    # A stationary sensor's one pose is never corrected.
    code, report = run(
        capsys, "bag2world", bag, "-o", tmp_path / "fixed", "--pose", "0", "0", "0", "0", "0", "0",
        "--correct", "on",
    )  # fmt: skip
    assert code == 0, report
    assert "correction: none (one fixed pose" in report


def _within_10cm(report: str) -> float:
    line = next(x for x in report.splitlines() if "fidelity (world_gz.sdf)" in x)
    return float(line.split("replayed: ")[1].split("%")[0])


def test_mit_csail_replays_clearly_better_corrected(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The real MIT CSAIL log (raw odometry, 1,988 scans): the corrected world reproduces
    far more of the recorded beams than the odometry's."""
    log = MIT_DIR
    code, report = run(capsys, "inspect", log / "mit-csail.clf.bz2")
    assert (
        code == 0
        and "correction: scan matching and loop closure (the poses are odometry)" in report
    )
    within = {}
    for mode in ("auto", "off"):
        code, report = run(
            capsys, "bag2world", log / "mit-csail.clf.bz2", "-o", tmp_path / mode,
            "--correct", mode,
        )  # fmt: skip
        assert code == 0, report
        within[mode] = _within_10cm(report)
    assert within["auto"] >= within["off"] + 10, within


def test_branch_and_bound_finds_the_exhaustive_best_in_a_wide_window() -> None:
    """The search's answer is the best placement of all, even in a window wider than the
    points (its lowest placements start below them: their bounds must still hold)."""
    from scan2terrain.slam.matching import LikelihoodGrid, thin

    t = np.linspace(0, 1, 300)
    walls = np.concatenate(
        [
            np.c_[12 * t, 0 * t],
            np.c_[0 * t, 7 * t],
            np.c_[5 * t + 3, 7 + 0 * t],
            np.c_[12 + 0 * t, 4 * t],
        ]
    )
    grid = LikelihoodGrid(walls, 0.1, 0.1, margin=1.0)
    truth = np.array([3.0, 2.0, 0.4])
    scan = thin(pose2.apply(pose2.inverse(truth), walls), 0.05)
    found = grid.match(scan, truth + np.array([2.5, -1.5, 0.2]), 6.0, 0.5, 0.1)
    assert found is not None and found.score > 0.9
    assert np.hypot(*(found.pose[:2] - truth[:2])) <= 0.1 and abs(found.pose[2] - truth[2]) < 0.01
