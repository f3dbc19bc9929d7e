"""Gazebo's own code checks our worlds.

Every generated world is loaded by SDFormat's parser in strict mode and its terrain rebuilt by
gz-common's heightmap loader (tests/gazebo/heightmap_probe.cpp, see tests/gazebo_harness.py).
At the centre of every map cell whose neighbourhood is uniform, the ground must be at the wall
height where the map is occupied and at the floor where it is free, within 1% of the wall height,
at the map-frame position of that cell: (x, y) in gz-sim, (x - cx, y - cy) in Gazebo Classic.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from types import MappingProxyType

import numpy as np
import pytest
from PIL import Image

from scan2terrain import grids
from scan2terrain.commands import maps
from scan2terrain.config import load_config
from scan2terrain.readers import read_map_yaml
from scan2terrain.readers.world import SIMULATORS
from scan2terrain.world.folder import Result, WrittenWorld
from tests.conftest import write_map
from tests.fixtures import IMAGES, MAPS
from tests.gazebo_harness import probe_world, terrain_height
from tests.world_checks import H, check_world


def build(
    source: Path,
    out: Path,
    overrides: Mapping[str, object] = MappingProxyType({}),
    *,
    command: str = "map2world",
) -> Result:
    """The world of ``source`` with config ``overrides`` (dotted keys, as ``--set`` takes)."""
    cfg = load_config(None, {"terrain.height": H, "world.geometry": "heightmap", **overrides})
    run = maps.map2world if command == "map2world" else maps.image2world
    return run(source, out, cfg)


@pytest.mark.parametrize("name", sorted(MAPS))
def test_real_map_unfiltered_lands_in_the_map_frame(tmp_path: Path, name: str) -> None:
    """Raw map cells (no filter) against the world, through the ORIGINAL map YAML."""
    result = build(MAPS[name], tmp_path / "w", {"filter.enabled": False})
    _, grid = read_map_yaml(MAPS[name])
    meta_thresholds = grids.to_trinary(grid.data)
    checked = check_world(result, grid.with_data(meta_thresholds), tmp_path)
    assert checked["gz"] > 1000 and checked["classic"] == checked["gz"]


@pytest.mark.parametrize("name", sorted(MAPS))
def test_filtered_map_export_lines_up_with_the_world(tmp_path: Path, name: str) -> None:
    """The default filter, checked through the map_server YAML we write for each simulator."""
    result = build(
        MAPS[name], tmp_path / "w", {"terrain.unknown": "height", "terrain.unknown_height": 0.5}
    )
    for w in result.worlds:
        assert w.map_yaml is not None
        _, exported = read_map_yaml(w.map_yaml)
        # The exported map is already in this simulator's world frame: offset (0, 0).
        single = Result(
            out=result.out,
            worlds=[
                WrittenWorld(
                    w.placement.__class__(**{**w.placement.__dict__, "offset": (0.0, 0.0)}),
                    w.world,
                    w.models,
                    w.map_yaml,
                )
            ],
        )
        check_world(single, exported, tmp_path / w.placement.simulator, unknown_level=0.5)


@pytest.mark.parametrize("yaw_deg", [90, -90, 180])
def test_quarter_turn_yaw_lands_rotated(tmp_path: Path, yaw_deg: int) -> None:
    rng = np.random.default_rng(yaw_deg + 1000)
    pixels = np.full((40, 60), 254, dtype=np.uint8)
    pixels[5:8, :] = 0  # a long wall
    pixels[10:35, 20:23] = 0  # a cross wall
    pixels[rng.random(pixels.shape) < 0.02] = 0
    pixels[30:38, 40:55] = 205  # unknown patch
    yaml_path = write_map(
        tmp_path / "m", pixels, resolution=0.1, origin=f"[2.5, -1.25, {math.radians(yaw_deg)!r}]"
    )
    result = build(yaml_path, tmp_path / "w", {"filter.enabled": False})
    _, grid = read_map_yaml(yaml_path)
    assert grid.origin.yaw != 0
    checked = check_world(result, grid, tmp_path)
    assert checked["gz"] > 1000


def test_arbitrary_yaw_lands_rotated(tmp_path: Path) -> None:
    pixels = np.full((50, 70), 254, dtype=np.uint8)
    pixels[10:16, 5:65] = 0
    pixels[20:45, 30:36] = 0
    yaml_path = write_map(tmp_path / "m", pixels, resolution=0.05, origin="[1.0, 2.0, 0.5236]")
    result = build(yaml_path, tmp_path / "w", {"filter.enabled": False})
    _, grid = read_map_yaml(yaml_path)
    # Resampled, not permuted: cells well inside uniform areas must still be right.
    checked = check_world(result, grid, tmp_path, radius=2)
    assert checked["gz"] > 1500


def test_upsampled_sixteen_bit_gz(tmp_path: Path) -> None:
    result = build(
        MAPS["tb3"],
        tmp_path / "w",
        {
            "filter.enabled": False,
            "terrain.upsample": 2,
            "terrain.bit_depth": 16,
            "world.simulator": "gz",
        },
    )
    _, grid = read_map_yaml(MAPS["tb3"])
    checked = check_world(result, grid, tmp_path)
    assert checked["gz"] > 1000


def test_image_world_heights(tmp_path: Path) -> None:
    result = build(
        IMAGES["winding_valley"],
        tmp_path / "w",
        {"filter.enabled": False, "image.resolution": 0.5, "terrain.height": 12.0},
        command="image2world",
    )
    with Image.open(IMAGES["winding_valley"]) as im:
        src = np.flipud(np.asarray(im.convert("L"), dtype=float))
    rows, cols = np.indices(src.shape)
    x = -src.shape[1] * 0.25 + (cols + 0.5) * 0.5
    y = -src.shape[0] * 0.25 + (rows + 0.5) * 0.5
    for w in result.worlds:
        _, probes = probe_world(w.world, [w.models], tmp_path / w.placement.simulator)
        (col,) = [p for p in probes if p.kind == "collision"]
        ox, oy = w.placement.offset
        assert w.placement.simulator in SIMULATORS
        got = terrain_height(col, x - ox, y - oy, w.placement.simulator)
        np.testing.assert_allclose(got, src / 255 * 12.0, atol=0.01 * 12.0)


#: The systems a robot needs in a gz-sim world (gz-sim's examples/worlds/sensors.sdf and its
#: default server.config), by file and class name. A world that lists any system gets only
#: those, so physics, commands and the scene broadcaster are listed with the sensors. gz-sim 7+
#: reads these names, and Fortress from 6.16 maps ``gz-sim-`` to ``ignition-gazebo-``
#: (SystemLoader.cc) and aliases every ``gz::sim::systems::`` class.
ROBOT_SYSTEMS = {
    "gz-sim-physics-system": "gz::sim::systems::Physics",
    "gz-sim-user-commands-system": "gz::sim::systems::UserCommands",
    "gz-sim-scene-broadcaster-system": "gz::sim::systems::SceneBroadcaster",
    "gz-sim-sensors-system": "gz::sim::systems::Sensors",
    "gz-sim-imu-system": "gz::sim::systems::Imu",
}


@pytest.mark.parametrize("geometry", ["heightmap", "mesh", "boxes", "polylines"])
def test_gz_worlds_load_the_systems_a_robot_needs(tmp_path: Path, geometry: str) -> None:
    """Issue 25 item 11: a spawned robot's lidar published nothing (no Sensors system)."""
    from lxml import etree

    result = build(MAPS["tb3"], tmp_path / "w", {"world.geometry": geometry})
    for w in result.worlds:
        world = etree.parse(str(w.world)).getroot().find("world")
        assert world is not None
        plugins = {p.get("filename"): p for p in world.findall("plugin")}
        if w.placement.simulator == "classic":
            assert plugins == {}  # Classic loads its sensors and physics itself
            continue
        assert {f: p.get("name") for f, p in plugins.items()} == ROBOT_SYSTEMS
        assert plugins["gz-sim-sensors-system"].findtext("render_engine") == "ogre2"
        probe_world(w.world, [w.models], tmp_path)  # SDFormat's parser still takes it
