"""The ready robot every world folder holds (``robot/``, exporters/robot.py): its model files
parse in SDFormat's strict mode, the report's spawn commands name them, and in gz-sim's own
physics (tests/physics_harness.py: the model file built as gz-sim builds a spawned model, driven
through the joints its DiffDrive plugin names) it comes to rest at spawn.yaml's pose and drives
2 m without falling through the ground or tipping, on a map's walls, a map's heightmap, a DEM's
terrain and a voxel world."""

from __future__ import annotations

import math
import shlex
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from lxml import etree

from scan2terrain.cli import main
from scan2terrain.exporters.robot import LIDAR_HEIGHT, MODEL_FILES, robot_files
from scan2terrain.grids.spawn import FOOTPRINT, LEVEL_RISE, LEVEL_SLOPE
from tests.fixtures import GEB079, MAPS, SFBAY
from tests.gazebo_harness import SdfParseError, probe_shapes
from tests.physics_harness import BodyResult, ModelRobot, Scenario, simulate
from tests.spawn_check import spawn_doc

#: One world of each kind (command line without -o). The DEM in 8 bits: Fortress's gz-common
#: cannot scale a 16-bit image (tests/test_physics_worlds.py).
KINDS: dict[str, list[object]] = {
    "map walls": ["map2world", MAPS["tb3"]],
    "map heightmap": ["map2world", MAPS["tb3"], "--geometry", "heightmap"],
    "terrain": ["dem2world", SFBAY, "--bit-depth", "8"],
    "voxels": ["octree2world", GEB079, "--geometry", "voxels"],
}

SETTLE = 1.0  #: s braked at the spawn pose
SPEED = 0.4  #: m/s forward once it has settled
DRIVE = 5.5  #: s driving: 0.4 s ramping up at 1 m/s^2, then 2 m take 4.8 s more
DT = 0.001
#: How far below spawn.yaml's z (the highest ground under the spawn square) the ground under
#: the robot may be: the most a level square rises (grids/spawn.py).
RISE = max(LEVEL_RISE, LEVEL_SLOPE * FOOTPRINT)


@pytest.fixture(scope="module")
def worlds(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    built = {}
    for kind, args in KINDS.items():
        out = tmp_path_factory.mktemp("robot") / "w"
        assert main([*map(str, args), "-q", "-o", str(out)]) == 0
        built[kind] = out
    return built


def _sims(out: Path) -> list[str]:
    return [s for s in ("gz", "classic") if s in spawn_doc(out)]


@pytest.mark.parametrize("kind", list(KINDS))
def test_robot_models_parse_strictly(worlds: dict[str, Path], kind: str, tmp_path: Path) -> None:
    """robot/ holds a model file for each simulator the folder has a world for, and
    model.config names them; each parses in SDFormat's strict mode (unknown or deprecated
    elements and warnings are errors), with the same body in both: the same collisions at the
    same poses. The folder's robot/ is the package's, byte for byte."""
    out = worlds[kind]
    sims = _sims(out)
    assert sims
    files = {p.relative_to(out).as_posix() for p in (out / "robot").iterdir()}
    assert files == {"robot/model.config", *(f"robot/{MODEL_FILES[s]}" for s in sims)}
    for rel, data in robot_files(sims).items():
        assert (out / rel).read_bytes() == data, rel
    config = etree.parse(str(out / "robot/model.config")).getroot()
    assert [e.text for e in config.iter("sdf")] == [MODEL_FILES[s] for s in sims]
    bodies = []
    for sim in sims:
        version, shapes = probe_shapes(out / "robot" / MODEL_FILES[sim], [], tmp_path / sim)
        assert version == "1.9"
        collisions = sorted(
            (s.name, s.type, tuple(np.round(s.pose, 9))) for s in shapes if s.kind == "collision"
        )
        assert len(collisions) == 6  # chassis, four wheels, lidar housing
        bodies.append(collisions)
    assert all(b == bodies[0] for b in bodies)


def test_strict_parse_refuses_a_misspelled_element(tmp_path: Path) -> None:
    """The check above can fail: the same model with one unknown element is refused."""
    for sim, name in MODEL_FILES.items():
        text = robot_files([sim])[f"robot/{name}"].decode()
        bad = tmp_path / name
        bad.write_text(text.replace("<always_on>", "<colour>1</colour><always_on>", 1))
        with pytest.raises(SdfParseError, match="colour"):
            probe_shapes(bad, [], tmp_path / f"bad_{sim}")


def test_model_carries_the_drive_and_lidar_of_each_simulator() -> None:
    """gz-sim: the DiffDrive system naming the wheel joints and a gpu_lidar on /scan; Classic:
    gazebo_ros's diff drive (two wheel pairs) and a ray sensor with its plugin; the scan plane
    at LIDAR_HEIGHT above the model origin (the ground) in both."""
    for sim, sensor_type, drive in (
        ("gz", "gpu_lidar", "gz-sim-diff-drive-system"),
        ("classic", "ray", "libgazebo_ros_diff_drive.so"),
    ):
        root = etree.fromstring(robot_files([sim])[f"robot/{MODEL_FILES[sim]}"])
        model = root.find("model")
        assert model is not None
        (plugin,) = [p for p in model.findall("plugin") if p.get("filename") == drive]
        joints = {j.get("name") for j in model.findall("joint")}
        named = [e.text for e in plugin if e.tag in ("left_joint", "right_joint")]
        assert len(named) == 4 and set(named) <= joints
        (sensor,) = root.iter("sensor")
        assert sensor.get("type") == sensor_type
        assert sensor.findtext("pose") == "0.0 0.0 0.0 0.0 0.0 0.0"
        (link,) = [ln for ln in model.findall("link") if ln.find("sensor") is not None]
        assert float((link.findtext("pose") or "").split()[2]) == LIDAR_HEIGHT
        samples = sensor.findtext(".//horizontal/samples")
        assert samples == "360"
        if sim == "classic":
            assert sensor.find("plugin").get("filename") == "libgazebo_ros_ray_sensor.so"  # type: ignore[union-attr]
        else:
            assert sensor.findtext("topic") == "/scan"


def test_report_spawns_the_robot_written(
    worlds: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    """The printed spawn commands name the folder's own model file, by absolute path, and
    the file is there."""
    out = worlds["map walls"].parent / "again"
    assert main(["map2world", str(MAPS["tb3"]), "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "ROBOT.sdf" not in text
    gz, classic = (out / "robot" / MODEL_FILES[s] for s in ("gz", "classic"))
    assert f'sdf_filename: "{gz}"' in text
    assert f"ros2 run ros_gz_sim create -world scan2terrain -file {shlex.quote(str(gz))}" in text
    assert f"gz model --spawn-file={shlex.quote(str(classic))} --model-name=robot" in text
    assert gz.is_file() and classic.is_file()


@dataclass(frozen=True)
class Run:
    """The robot's run in one world: its pose after SETTLE s braked, relative to the spawn
    pose, and how the drive went."""

    rest_error_xy: float  #: m
    rest_dz: float  #: m, rest z less spawn z (the ground under it may be lower, by RISE)
    rest_tilt: float  #: degrees, the larger of roll and pitch
    advance: float  #: m along the spawn heading during the drive
    drift: float  #: m sideways
    max_tilt: float  #: degrees over the whole run
    lowest: float  #: m, lowest base z less spawn z


def drive(out: Path, tmp: Path) -> Run:
    x, y, z, _, _, yaw = (float(v) for v in spawn_doc(out)["gz"]["pose"])  # type: ignore[index]
    robot = ModelRobot("robot", out / "robot/model_gz.sdf", x, y, z, yaw, SPEED, 0.0, SETTLE)
    scenario = Scenario(bodies=[robot], dt=DT, steps=round((SETTLE + DRIVE) / DT), sample_every=10)
    result = simulate(out / "world_gz.sdf", [out / "models"], scenario, tmp).check()
    assert result.failures == []
    b: BodyResult = result.bodies["robot"]
    s = b.samples  # t, x, y, z, roll, pitch, yaw every 10 ms
    rest = s[np.argmin(np.abs(s[:, 0] - SETTLE))]
    heading = np.array([math.cos(yaw), math.sin(yaw)])
    moved = np.array(b.final_pose[:2]) - rest[1:3]
    return Run(
        rest_error_xy=float(np.hypot(rest[1] - x, rest[2] - y)),
        rest_dz=float(rest[3] - z),
        rest_tilt=math.degrees(float(np.abs(rest[4:6]).max())),
        advance=float(moved @ heading),
        drift=float(abs(moved @ np.array([-heading[1], heading[0]]))),
        max_tilt=math.degrees(float(np.abs(s[:, 4:6]).max())),
        lowest=b.min_z - z,
    )


@pytest.mark.parametrize("kind", list(KINDS))
def test_robot_rests_at_spawn_and_drives_2_m(
    worlds: dict[str, Path], kind: str, tmp_path: Path
) -> None:
    """Spawned at spawn.yaml's gz pose (its origin on the ground), braked for a second, it rests
    where it was put: within 3 cm, on the ground under it (at most RISE below spawn.yaml's z,
    never above it by more than a centimetre), level within 2 degrees. Driven forward at
    0.4 m/s for 5.5 s it covers 2 m along its heading, drifts under 10 cm sideways, never tilts
    past 15 degrees and never sinks more than 3 cm below that ground."""
    run = drive(worlds[kind], tmp_path)
    assert run.rest_error_xy < 0.03, run
    assert -RISE - 0.01 <= run.rest_dz <= 0.01, run
    assert run.rest_tilt < 2.0, run
    assert run.advance >= 2.0, run
    assert run.drift < 0.1, run
    assert run.max_tilt < 15.0, run
    assert run.lowest >= -RISE - 0.03, run
