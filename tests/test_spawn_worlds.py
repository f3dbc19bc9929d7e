"""Every world folder says where a robot can start (spawn.yaml, a comment in each world, the
report), in each world's own frame; a bag's spawn is where its robot started, on every path."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from scan2terrain.cli import main
from tests.bagmaker import synthetic_room
from tests.conftest import FIXTURES, IMAGES, MAPS
from tests.readers.test_dem import SFBAY

HDL_PCD = FIXTURES / "clouds/pc_hdl32_scan_pcd_ply_twin/251370668.pcd"
GEB079 = FIXTURES / "octomap/geb079.bt"


def run(capsys: pytest.CaptureFixture[str], *args: object) -> str:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    assert code == 0, err
    return out


def spawn(out: Path) -> dict[str, object]:
    doc: dict[str, object] = yaml.safe_load((out / "spawn.yaml").read_text())
    return doc


def pose(doc: dict[str, object], sim: str) -> np.ndarray:
    entry = doc[sim]
    assert isinstance(entry, dict)
    return np.array(entry["pose"], dtype=np.float64)


CASES = {
    "map2world mesh": ["map2world", MAPS["willow"]],
    "map2world heightmap": ["map2world", MAPS["willow"], "--geometry", "heightmap"],
    "map2world boxes": ["map2world", MAPS["tb3"], "--geometry", "boxes"],
    "image2world": ["image2world", IMAGES["bowl_rgb"], "--resolution", "0.25"],
    "dem2world": ["dem2world", SFBAY],
    "octree2world": ["octree2world", GEB079, "--z-min", "0.1", "--z-max", "1.8"],
    "cloud2world height": ["cloud2world", HDL_PCD, "--grid", "height", "--resolution", "0.2"],
}


@pytest.mark.parametrize("case", list(CASES))
def test_every_world_has_a_spawn_pose(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str
) -> None:
    out = tmp_path / "w"
    stdout = run(capsys, *CASES[case], "-o", out)
    doc = spawn(out)
    sims = [s for s in ("gz", "classic") if s in doc]
    assert sims and isinstance(doc["why"], str) and doc["why"]
    for sim in sims:
        entry = doc[sim]
        assert isinstance(entry, dict)
        world = out / entry["world"]
        p = pose(doc, sim)
        assert p.shape == (6,) and np.isfinite(p).all() and p[3] == p[4] == 0.0
        x, y, z = (f"{v:g}" for v in p[:3])
        assert f"Spawn a robot at x={x} y={y} z={z}" in world.read_text()
        assert f"spawn a robot at x={x} y={y} z={z}" in stdout
    if "classic" in doc and "heightmap" in case:
        # Classic centres the heightmap on its origin: the same spot, shifted by the centre.
        sx, sy = pose(doc, "gz")[:2] - pose(doc, "classic")[:2]
        assert f"a map point (x, y) is world (x - {sx:g}, y - {sy:g})" in stdout


def test_bag_spawn_is_the_recorded_start_on_every_path(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The robot's first scan pose (sensor position and heading) is where it spawns, and the
    octree path and --stream agree on it (the same end-point map)."""
    room = synthetic_room("tf", n_scans=60)
    bag = room.write(tmp_path / "r.bag", "ros1")
    x0, y0, yaw0 = room.sensor_poses[0]
    docs = []
    for name, options in (
        ("octree", ["--insert", "endpoints"]),
        ("stream", ["--stream"]),
        ("raycast", []),
    ):
        out = tmp_path / name
        run(capsys, "bag2world", bag, "-o", out, *options)
        doc = spawn(out)
        assert "from the recorded start (/scan at" in str(doc["why"])
        p = pose(doc, "gz")
        assert np.hypot(p[0] - x0, p[1] - y0) < 0.5, (p, x0, y0)
        assert p[5] == pytest.approx(yaw0, abs=1e-3)
        docs.append((out / "spawn.yaml").read_bytes())
    assert docs[0] == docs[1]  # octree end points == streamed end points
