"""The physics harness on small hand-written worlds (ign-physics 5 / dartsim, bullet detector).

Each world is SDF 1.9 with ``<dart><collision_detector>bullet</collision_detector>``, as
scan2terrain writes them. Expected values come from the geometry written here, not from
the harness: a plane at z = 0, a box wall whose top and face are known, a heightmap laid
out by gz-physics' rule (spacing ``size / vertSize``, image row 0 at +y), an STL block and
an extruded polyline.
"""

from __future__ import annotations

import math
import signal
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from tests.physics_harness import (
    ROBOT_FRONT,
    Scenario,
    SimulationCrashed,
    Sphere,
    drive_robot,
    drop_probes,
    simulate,
    spawn_robot,
)

#: The physics harness against analytic cases: `pytest -m 'not slow'` leaves it out, CI runs it.
pytestmark = pytest.mark.slow

HEAD = """<?xml version="1.0"?>
<sdf version="1.9">
  <world name="test">
    <physics name="dart_bullet" type="dart">
      <max_step_size>0.001</max_step_size>
      <real_time_factor>1</real_time_factor>
      <dart><collision_detector>bullet</collision_detector></dart>
    </physics>
"""
TAIL = "  </world>\n</sdf>\n"

PLANE = """
    <model name="ground">
      <static>true</static>
      <link name="link">
        <collision name="plane">
          <geometry><plane><normal>0 0 1</normal><size>100 100</size></plane></geometry>
        </collision>
      </link>
    </model>
"""

WALL_X = 3.0  # centre of the wall; its face towards -x is at WALL_X - 0.1
WALL_TOP = 1.0
WALL = f"""
    <model name="wall">
      <static>true</static>
      <pose>{WALL_X} 0 {WALL_TOP / 2} 0 0 0</pose>
      <link name="link">
        <collision name="box">
          <geometry><box><size>0.2 4 {WALL_TOP}</size></box></geometry>
        </collision>
      </link>
    </model>
"""


def _world(path: Path, *models: str) -> Path:
    path.write_text(HEAD + "".join(models) + TAIL)
    return path


def _mesh_model(name: str, uri: str, x: float) -> str:
    return f"""
    <model name="{name}">
      <static>true</static>
      <pose>{x} 0 0 0 0 0</pose>
      <link name="link">
        <collision name="mesh">
          <geometry><mesh><uri>{uri}</uri></mesh></geometry>
        </collision>
      </link>
    </model>
"""


def _write_block_stl(path: Path, sx: float, sy: float, sz: float) -> None:
    """A closed box mesh [-sx/2, sx/2] x [-sy/2, sy/2] x [0, sz] as ASCII STL."""
    x, y = sx / 2, sy / 2
    v = np.array(
        [[-x, -y, 0], [x, -y, 0], [x, y, 0], [-x, y, 0],
         [-x, -y, sz], [x, -y, sz], [x, y, sz], [-x, y, sz]]
    )  # fmt: skip
    faces = [
        (0, 2, 1), (0, 3, 2), (4, 5, 6), (4, 6, 7), (0, 1, 5), (0, 5, 4),
        (1, 2, 6), (1, 6, 5), (2, 3, 7), (2, 7, 6), (3, 0, 4), (3, 4, 7),
    ]  # fmt: skip
    lines = ["solid block"]
    for a, b, c in faces:
        n = np.cross(v[b] - v[a], v[c] - v[a])
        n = n / np.linalg.norm(n)
        lines.append(f"facet normal {n[0]} {n[1]} {n[2]}")
        lines.append("outer loop")
        lines += [f"vertex {p[0]} {p[1]} {p[2]}" for p in (v[a], v[b], v[c])]
        lines += ["endloop", "endfacet"]
    lines.append("endsolid block")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")


def test_sphere_on_plane_first_touches_at_radius(tmp_path: Path) -> None:
    world = _world(tmp_path / "plane.sdf", PLANE)
    r = 0.1
    result = simulate(
        world, [], Scenario(bodies=[Sphere("s", r, 1.0, 0.5, -0.5, r + 0.2)], steps=600), tmp_path
    ).check()
    assert result.collision_detector == "bullet"
    assert result.world_collision_detector == "bullet"
    contact = result.body("s").first_contact
    assert contact is not None and contact.other == "ground/plane"
    # It falls 0.2 m (2 m/s at impact, 2 mm per 1 ms step): the detector sees the centre
    # at most one step's fall below r, and the depth it reports puts it back at r.
    v_dt = math.sqrt(2 * 9.8 * 0.2) * result.dt
    assert r - v_dt <= contact.pose_before[2] <= r
    assert abs(contact.pose_before[2] + contact.depth - r) < 1e-3
    assert contact.normal[2] == pytest.approx(1.0, abs=1e-3)
    # The helper's refined drop (1 cm fall) gives the plane's height within 1 mm.
    (drop,) = drop_probes(world, [], [(0.5, -0.5)], tmp_path, z=r + 0.5, radius=r)
    assert drop.height is not None and abs(drop.height) < 1e-3
    assert drop.drift < 1e-3
    assert result.times is not None and result.times.load_s > 0
    assert result.rtf > 0 and result.steps_run == 600


def test_sphere_on_box_wall_touches_its_top(tmp_path: Path) -> None:
    world = _world(tmp_path / "wall.sdf", PLANE, WALL)
    drops = drop_probes(world, [], [(WALL_X, 0.0), (WALL_X, 1.5), (0.0, 0.0)], tmp_path, z=1.5)
    for drop in drops[:2]:
        assert drop.other == "wall/box"
        assert drop.height is not None and abs(drop.height - WALL_TOP) < 1e-3
    assert drops[2].other == "ground/plane"
    assert drops[2].height is not None and abs(drops[2].height) < 1e-3


def test_robot_driven_at_wall_stops_at_its_face(tmp_path: Path) -> None:
    world = _world(tmp_path / "wall.sdf", PLANE, WALL)
    face = WALL_X - 0.1
    stop = drive_robot(world, [], (0.0, 0.0, 0.0), tmp_path, speed=0.5, distance=3.0)
    assert stop.front_initial[0] == pytest.approx(ROBOT_FRONT, abs=1e-3)
    assert abs(stop.front[0] - face) < 0.01
    # Never through it: the farthest the front face got is the face plus DART's contact
    # penetration (well under a millimetre here).
    assert ROBOT_FRONT + stop.max_advance < face + 1e-3
    assert stop.speed < 0.05


def test_robot_spawned_on_plane_rests_level(tmp_path: Path) -> None:
    world = _world(tmp_path / "plane.sdf", PLANE)
    rest = spawn_robot(world, [], (1.0, -2.0, 0.3), tmp_path, duration=1.0)
    assert abs(rest.roll) < 2e-3 and abs(rest.pitch) < 2e-3
    assert rest.final_pose[5] == pytest.approx(0.3, abs=2e-3)
    assert abs(rest.final_pose[2]) < 2e-3
    assert math.hypot(rest.final_pose[0] - 1.0, rest.final_pose[1] + 2.0) < 5e-3
    assert rest.speed < 0.01


def test_heightmap_heights_and_orientation(tmp_path: Path) -> None:
    # 33 x 33 px, size 3.3 m, sampling 1: vertSize 33, spacing 0.1 m (gz-physics
    # CustomHeightmapShape.cc), pixel (row, col) at local (col - 16, 16 - row) * 0.1.
    px = np.zeros((33, 33), dtype=np.uint8)
    px[12:21, 12:21] = 255  # a plateau around the centre: full scale, size.z = 0.5
    px[2:7, 2:7] = 128  # top-left (+y, -x): 128/255 of full scale
    models = tmp_path / "models"
    (models / "terrain").mkdir(parents=True)
    Image.fromarray(px, mode="L").save(models / "terrain" / "hm.png")
    ox, oy = 1.0, 2.0  # collision pose offset, as scan2terrain places gz-sim terrain
    terrain = f"""
    <model name="terrain">
      <static>true</static>
      <link name="link">
        <collision name="hm">
          <pose>{ox} {oy} 0 0 0 0</pose>
          <geometry><heightmap>
            <uri>model://terrain/hm.png</uri><size>3.3 3.3 0.5</size><sampling>1</sampling>
          </heightmap></geometry>
        </collision>
      </link>
    </model>
"""
    world = _world(tmp_path / "hm.sdf", terrain)
    points = [(ox, oy), (ox - 1.2, oy + 1.2), (ox - 1.2, oy - 1.2), (ox + 1.2, oy + 1.2)]
    drops = drop_probes(world, [models], points, tmp_path, z=1.0, radius=0.05)
    expected = [0.5, 0.5 * 128 / 255, 0.0, 0.0]
    for drop, want in zip(drops, expected, strict=True):
        assert drop.other == "terrain/hm"
        assert drop.height is not None and abs(drop.height - want) < 1e-3, (drop, want)


def test_mesh_and_polyline_tops(tmp_path: Path) -> None:
    models = tmp_path / "models"
    _write_block_stl(models / "block" / "meshes" / "block.stl", 1.0, 1.0, 0.5)
    polyline = """
    <model name="prism">
      <static>true</static>
      <pose>-2 0 0 0 0 0</pose>
      <link name="link">
        <collision name="poly">
          <geometry><polyline>
            <point>-0.5 -0.5</point><point>0.5 -0.5</point>
            <point>0.5 0.5</point><point>-0.5 0.5</point>
            <height>0.4</height>
          </polyline></geometry>
        </collision>
      </link>
    </model>
"""
    world = _world(
        tmp_path / "shapes.sdf",
        PLANE,
        _mesh_model("block", "model://block/meshes/block.stl", 2.0),
        polyline,
    )
    result = simulate(world, [models], Scenario(steps=1), tmp_path).check()
    assert result.shapes_failed == 0, result.failures
    assert result.built_by_type == {"mesh": 1, "plane": 1, "polyline": 1}
    drops = drop_probes(world, [models], [(2.0, 0.0), (-2.0, 0.0), (0.0, 2.0)], tmp_path, z=1.0)
    assert [d.other for d in drops] == ["block/mesh", "prism/poly", "ground/plane"]
    for drop, want in zip(drops, [0.5, 0.4, 0.0], strict=True):
        assert drop.height is not None and abs(drop.height - want) < 1e-3, (drop, want)


def test_broken_mesh_uri_is_one_failed_shape(tmp_path: Path) -> None:
    world = _world(
        tmp_path / "broken.sdf", PLANE, _mesh_model("ghost", "model://missing/meshes/x.stl", 2.0)
    )
    scenario = Scenario(bodies=[Sphere("s", 0.1, 1.0, 2.0, 0.0, 0.5)], steps=500)
    result = simulate(world, [tmp_path], scenario, tmp_path).check()
    assert result.shapes_failed == 1
    (failure,) = result.failures
    assert (failure.type, failure.model, failure.collision) == ("mesh", "ghost", "mesh")
    assert "model://missing/meshes/x.stl" in failure.reason
    # The rest of the world is built and runs: the sphere lands on the plane, not the mesh.
    contact = result.body("s").first_contact
    assert contact is not None and contact.other == "ground/plane"


def test_crash_is_a_result_with_its_signal(tmp_path: Path) -> None:
    world = _world(tmp_path / "plane.sdf", PLANE)
    scenario = Scenario(bodies=[Sphere("s", 0.1, 1.0, 0, 0, 1)], raise_signal=signal.SIGSEGV)
    result = simulate(world, [], scenario, tmp_path)
    assert result.crashed and result.signal == signal.SIGSEGV
    assert "SIGSEGV" in result.crash_summary()
    assert "raise_signal" in result.crash_summary()  # the stage it was in
    with pytest.raises(SimulationCrashed, match="SIGSEGV"):
        result.check()
