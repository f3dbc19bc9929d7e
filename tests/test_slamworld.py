"""The synthetic SLAM recordings themselves (tests/slamworld.py): scans agree with the scene,
odometry drifts as asked, the bag reads back with scan2terrain's reader, same seed same bytes."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from scan2terrain.cli import main
from scan2terrain.config import load_config
from scan2terrain.readers.bag import open_bag
from scan2terrain.readers.scans import plan_bag, posed_scans
from scan2terrain.readers.tracks import read_tum
from scan2terrain.types import ScanCounts
from tests.bagmaker import Fmt, cast_rays
from tests.slamworld import (
    SCENES,
    TRUTH,
    Drift,
    Floats,
    Laser,
    TumFrame,
    make_scene,
    simulate,
)


@pytest.mark.parametrize("name", sorted(SCENES))
def test_truth_posed_scans_lie_on_the_walls(name: str) -> None:
    """Every return of a truth-posed scan lies on a wall within the range noise; the culled
    caster gives the brute-force caster's distances; drifted poses do not fit the walls."""
    sigma = 0.01
    rec = simulate(name, laser=Laser(noise=sigma))
    assert 300 <= len(rec.stamps_ns) <= 1100, len(rec.stamps_ns)
    pts, k = rec.hits()
    assert len(pts) > 0.5 * rec.ranges.size  # the scenes are closed enough to see walls
    d = rec.scene.distance(pts[k % 4 == 0])
    assert d.max() <= 6 * sigma and 0.3 * sigma < math.sqrt(np.mean(d**2)) <= sigma

    exact = simulate(name, laser=Laser(noise=0.0))
    pts0, k0 = exact.hits()
    assert exact.scene.distance(pts0[k0 % 4 == 1]).max() < 1e-5  # float32 ranges
    every = slice(None, None, 37)
    poses = exact.laser_poses[every]
    brute = cast_rays(
        poses[:, :2], poses[:, 2:3] + exact.laser.angles[None, :], exact.scene.segments
    )
    got = exact.ranges[every].astype(np.float64)
    seen = brute <= exact.laser.range_max
    assert np.array_equal(np.isfinite(got), seen)  # no return: +inf
    np.testing.assert_allclose(got[seen], brute[seen], rtol=1e-6)

    drifted, _ = rec.hits(rec.odom_laser_poses)
    far = rec.scene.distance(drifted[k % 4 == 0])
    assert np.mean(far > 0.1) > 0.3


def test_scene_options() -> None:
    """Scale grows the scene and the route; laps lengthen the recording; beams and fov are
    what the laser says."""
    small, big = make_scene("corridor_loop", 0.4), make_scene("corridor_loop", 1.0)
    assert small.bounds[2] - small.bounds[0] < big.bounds[2] - big.bounds[0]
    assert small.lap_length < big.lap_length
    a = simulate(small, laps=1.0)
    b = simulate(small, laps=1.5)
    assert 1.4 < len(b.stamps_ns) / len(a.stamps_ns) < 1.6
    laser = Laser(beams=720, fov_deg=270.0)
    c = simulate(small, laps=0.2, laser=laser)
    assert c.ranges.shape == (len(c.stamps_ns), 720) and c.ranges.dtype == np.float32
    assert laser.angles[0] == pytest.approx(-math.radians(135))
    assert laser.angles[-1] == pytest.approx(math.radians(135))
    full = Laser(beams=360)
    assert full.angles[-1] + full.angle_increment == pytest.approx(math.pi)
    # No return: +inf, or past range_max with no_return="over" (REP 117 allows both).
    over = Laser(range_max=8.0, no_return="over")
    rooms = simulate("rooms", laps=0.2, laser=over)
    gone = np.isinf(rooms.ranges)
    assert gone.mean() > 0.01 and np.all(rooms.ranges[~gone] < 8.0)
    scans = [m[3] for m in rooms.messages() if m[0] == "/scan"]
    written = np.array([s["ranges"] for s in scans])
    assert np.all(written[gone] == np.float32(9.0)) and np.array_equal(
        written[~gone], rooms.ranges[~gone]
    )
    with pytest.raises(ValueError, match="scale"):
        make_scene("corridor_loop", 0.05)
    with pytest.raises(KeyError, match="no scene"):
        make_scene("castle")


def test_odometry_drifts_as_asked() -> None:
    scene = make_scene("corridor_loop")
    truth = simulate(scene, drift=TRUTH)
    assert np.array_equal(truth.odom, truth.truth)
    assert truth.odom_error() == (0.0, 0.0)
    trans, yaw = truth.pose_errors(truth.odom)
    assert trans.max() == 0.0 and yaw.max() == 0.0
    drifted = simulate(scene, odom_start=(0.0, 0.0, 0.0))
    trans, yaw = drifted.pose_errors(drifted.odom)
    assert (trans[-1], yaw[-1]) == pytest.approx(
        (drifted.odom_error()[0], abs(drifted.odom_error()[1]))
    )
    assert trans[0] == 0.0 and trans.max() > 0.5

    # A pure scale error stretches the path about its start; a pure yaw bias per metre turns
    # the end by the bias times the distance driven.
    s = 0.02
    scaled = simulate(scene, drift=Drift(scale=s, yaw_bias_deg_per_m=0, trans_noise=0, yaw_noise=0))
    start = scaled.truth[0, :2]
    np.testing.assert_allclose(scaled.odom[:, :2], start + (1 + s) * (scaled.truth[:, :2] - start))
    np.testing.assert_allclose(scaled.odom[:, 2], scaled.truth[:, 2], atol=1e-12)
    bias = 1.0
    biased = simulate(
        scene, drift=Drift(scale=0, yaw_bias_deg_per_m=bias, trans_noise=0, yaw_noise=0)
    )
    _, yaw_err = biased.odom_error()
    assert 20 < bias * biased.distance < 170
    assert yaw_err == pytest.approx(bias * biased.distance, rel=1e-6)

    # The end-point error grows with the scale error and with the bias (noise fixed by the seed).
    errors = [
        simulate(scene, drift=Drift(scale=k, yaw_bias_deg_per_m=0.0)).odom_error()[0]
        for k in (0.01, 0.03)
    ]
    assert errors[0] < errors[1]
    errors = [
        simulate(scene, drift=Drift(scale=0.0, yaw_bias_deg_per_m=k)).odom_error()[0]
        for k in (0.25, 1.0)
    ]
    assert errors[0] < errors[1]
    # Seconds count too, and the noise follows the seed.
    per_s = simulate(scene, drift=Drift(scale=0, yaw_bias_deg_per_m=0, yaw_bias_deg_per_s=0.2))
    assert per_s.odom_error()[1] > 0.1 * per_s.duration
    n1 = simulate(scene, seed=1).odom
    assert np.array_equal(n1, simulate(scene, seed=1).odom) and not np.array_equal(
        n1, simulate(scene, seed=2).odom
    )


def _read(bag: Path, **cfg: object) -> tuple[str, str, np.ndarray]:
    config = load_config(None, dict(cfg))
    with open_bag(bag) as b:
        plan = plan_bag(b, config.scans)
        poses = [
            (s.origin[0], s.origin[1], s.heading)
            for s in posed_scans(b, config.scans, plan, ScanCounts())
        ]
    return plan.poses, plan.fixed_frame, np.array(poses)


@pytest.mark.parametrize("fmt", ["ros1", "mcap"])
def test_bag_reads_back(tmp_path: Path, capsys: pytest.CaptureFixture[str], fmt: Fmt) -> None:
    """inspect sees the topics; without a map frame the scans are posed by odometry, with one
    by tf in 'map' at the truth; the odometry's tf gives the odometry's poses."""
    rec = simulate("corridor_loop", laps=0.3, odom_per_scan=2, odom_start=(0.0, 0.0, 0.0))
    assert np.array_equal(rec.odom[0], [0.0, 0.0, 0.0])
    k = len(rec.stamps_ns)
    plain = rec.write_bag(tmp_path / ("plain.bag" if fmt == "ros1" else "plain"), fmt)
    assert main(["inspect", str(plain)]) == 0
    out = capsys.readouterr().out
    counts = {tuple(line.split()[:2]) for line in out.splitlines() if line.startswith("    /")}
    assert {("/scan", str(k)), ("/odom", str(2 * k - 1)), ("/tf_static", "1")} <= counts
    assert "/tf " not in out and "poses: odometry on /odom" in out

    how, fixed, got = _read(plain)
    assert (how, fixed) == ("odom", "odom")
    np.testing.assert_allclose(got[:, :2], rec.odom_laser_poses[:, :2], atol=1e-6)

    tf_bag = rec.write_bag(tmp_path / ("tf.bag" if fmt == "ros1" else "tf"), fmt, tf=True)
    how, fixed, got = _read(tf_bag)
    assert (how, fixed) == ("tf", "odom")
    np.testing.assert_allclose(got[:, :2], rec.odom_laser_poses[:, :2], atol=1e-6)

    slam = rec.write_bag(tmp_path / ("map.bag" if fmt == "ros1" else "map"), fmt, map_frame=True)
    how, fixed, got = _read(slam)
    assert (how, fixed) == ("tf", "map")
    np.testing.assert_allclose(got[:, :2], rec.laser_poses[:, :2], atol=1e-6)
    dyaw = (got[:, 2] - rec.laser_poses[:, 2] + np.pi) % (2 * np.pi) - np.pi
    assert np.abs(dyaw).max() < 1e-6
    assert np.abs(rec.odom_laser_poses[:, :2] - rec.laser_poses[:, :2]).max() > 0.05


def test_same_seed_same_bytes(tmp_path: Path) -> None:
    a = simulate("rooms", laps=0.2, seed=3).write_bag(tmp_path / "a.bag", "ros1", map_frame=True)
    b = simulate("rooms", laps=0.2, seed=3).write_bag(tmp_path / "b.bag", "ros1", map_frame=True)
    c = simulate("rooms", laps=0.2, seed=4).write_bag(tmp_path / "c.bag", "ros1", map_frame=True)
    assert a.read_bytes() == b.read_bytes() != c.read_bytes()


def test_truth_files(tmp_path: Path) -> None:
    """The TUM files read back as the truth (base_link and laser); the occupancy grid holds the
    walls: every return of an exact scan falls in or next to an occupied cell."""
    rec = simulate("rooms", laps=0.3, laser=Laser(noise=0.0))
    truths: dict[TumFrame, tuple[Floats, float]] = {
        "base_link": (rec.truth, 0.0),
        "laser": (rec.laser_poses, 0.3),
    }
    for frame, (poses, z) in truths.items():
        track = read_tum(rec.write_tum(tmp_path / f"{frame}.tum", frame=frame))
        assert np.array_equal(track.times_ns, rec.stamps_ns)
        np.testing.assert_allclose(track.translations[:, :2], poses[:, :2], atol=1e-12)
        assert np.all(track.translations[:, 2] == z)
    odom = read_tum(rec.write_tum(tmp_path / "odom.tum", poses="odom"))
    np.testing.assert_allclose(odom.translations[:, :2], rec.odom[:, :2], atol=1e-12)

    res = 0.05
    occ = rec.scene.occupancy(res)
    pts, _ = rec.hits()
    col = np.floor((pts[:, 0] - occ.origin[0]) / res).astype(int)
    row = np.floor((pts[:, 1] - occ.origin[1]) / res).astype(int)
    assert occ.grid[row, col].mean() > 0.95  # walls lie on cell centres
    near = np.zeros_like(occ.grid)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            near |= np.roll(occ.grid, (dr, dc), axis=(0, 1))
    assert near[row, col].all()
    # Occupied cells hold walls: their centres lie within half a diagonal of one.
    rr, cc = np.nonzero(occ.grid)
    centres = np.column_stack([occ.origin[0] + (cc + 0.5) * res, occ.origin[1] + (rr + 0.5) * res])
    assert rec.scene.distance(centres).max() <= res * math.sqrt(0.5) + 1e-9
    assert occ.grid.sum() > 1000


def test_parallel_corridors_look_alike() -> None:
    """In the middle of the two corridors, a scan sees the same thing 4 m apart: the trap for a
    careless loop closer."""
    rec = simulate("parallel_corridors", laser=Laser(noise=0.0), laps=1.0)
    scene = rec.scene
    x_mid = 0.5 * (scene.route[:, 0].min() + scene.route[:, 0].max())
    a = np.array([[x_mid, scene.route[0, 1], 0.0]])  # the middle of the southern corridor
    b = a + np.array([[0.0, 4.0, 0.0]])
    for yaw in (0.0, math.pi):
        ra, rb = (
            cast_rays(p[:, :2], yaw + rec.laser.angles[None, :], scene.segments) for p in (a, b)
        )
        same = np.isclose(ra, rb, atol=1e-6) | (np.minimum(ra, rb) > 25.0)
        assert same.mean() > 0.9
