"""--geometry voxels: the occupied voxels themselves as the world, checked with trimesh, with
Gazebo's own parser and mesh loader (tests/gazebo_harness.py) and in gz-sim's physics
(tests/physics_harness.py) on a synthetic place with a table, an overhang, a doorway and two
floors; and the refusals."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import trimesh
import yaml

from scan2terrain.cli import main
from scan2terrain.world.folder import write_world_folder
from tests.fixtures import BOWL, CCNY, FR079, FUSE, FUSE_DIR, GEB079, HDL_PCD, TB3_MAP
from tests.gazebo_harness import probe_shapes
from tests.physics_harness import drive_robot, drop_probes

R = 0.1  # voxel side of the synthetic scene


def _mesh(stl: Path) -> trimesh.Trimesh:
    """An STL as trimesh loads it: one mesh (not a scene)."""
    mesh = trimesh.load(stl)
    assert isinstance(mesh, trimesh.Trimesh), stl.name
    return mesh


def _box(x: tuple[float, float], y: tuple[float, float], z: tuple[float, float]) -> np.ndarray:
    """Voxel keys (on the R lattice) filling a box given in metres."""
    axes = [np.arange(round(a / R), round(b / R)) for a, b in (x, y, z)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)


def scene() -> np.ndarray:
    """A floor (top at z = 0), a table (top 0.7-0.8 m), an overhang (1.2-1.3 m, nothing under
    it), a wall at x = 5 with a doorway 1.2 m wide and 2 m high, and a second floor at 3 m."""
    parts = [
        _box((0, 6), (0, 4), (-0.1, 0)),  # floor
        _box((1, 2), (1, 2), (0.7, 0.8)),  # table top
        *[_box((x, x + 0.1), (y, y + 0.1), (0, 0.7)) for x in (1, 1.9) for y in (1, 1.9)],
        _box((3, 4.5), (0, 1), (1.2, 1.3)),  # overhang, held by a post at its far corner
        _box((4.4, 4.5), (0.9, 1), (0, 1.2)),
        _box((5, 5.1), (0, 1.4), (0, 2.5)),  # wall, doorway y 1.4-2.6 under 2 m
        _box((5, 5.1), (2.6, 4), (0, 2.5)),
        _box((5, 5.1), (1.4, 2.6), (2.0, 2.5)),
        _box((0, 2), (2.5, 4), (3.0, 3.1)),  # second floor
    ]
    return np.unique(np.concatenate(parts), axis=0)


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, np.ndarray]:
    tmp = tmp_path_factory.mktemp("voxels")
    keys = scene()
    cloud = tmp / "scene.xyz"
    np.savetxt(cloud, (keys + 0.5) * R, fmt="%.3f")
    out = tmp / "world"
    args = ["cloud2world", str(cloud), "-o", str(out), "--geometry", "voxels"]
    assert main([*args, "--resolution", str(R), "--simulator", "gz", "--chunk", "2", "-q"]) == 0
    return out, keys


def _stls(out: Path) -> list[Path]:
    """The chunks of the gz-sim model (with --simulator both, Classic's model repeats them)."""
    return sorted(
        p for p in (out / "models").glob("*/meshes/*.stl") if not p.parts[-3].endswith("_classic")
    )


def test_the_meshes_hold_exactly_the_voxels(built: tuple[Path, np.ndarray]) -> None:
    out, keys = built
    stls = _stls(out)
    assert len(stls) > 1  # cut into 2 m chunks
    volume = 0.0
    inside = np.zeros(len(keys), bool)
    probe = np.array([[1.5, 1.5, 0.4], [3.7, 0.5, 0.6], [5.05, 2.0, 1.0], [1.0, 3.0, 1.5]])
    outside = np.zeros(len(probe), bool)
    for stl in stls:
        m = _mesh(stl)
        assert m.is_watertight and m.is_winding_consistent, stl.name
        volume += m.volume
        inside |= m.contains((keys + 0.5) * R)
        outside |= m.contains(probe)
    assert volume == pytest.approx(len(keys) * R**3, rel=1e-3)
    assert inside.all()  # every voxel centre is inside a chunk
    assert not outside.any()  # under the table, under the overhang, the doorway, between floors
    # The spawn pose stands on the scene's floor (top z = 0, the world frame is the map frame
    # here), inside it, clear of every voxel 1.5 m above across the 1.5 m footprint.
    x, y, z, roll, pitch, _ = yaml.safe_load((out / "spawn.yaml").read_text())["gz"]["pose"]
    assert (roll, pitch) == (0, 0) and z == pytest.approx(0.0, abs=1e-6)
    assert 0.75 <= x <= 6 - 0.75 and 0.75 <= y <= 4 - 0.75
    centres = (keys + 0.5) * R
    above = centres[:, 2] > 0
    near = (np.abs(centres[:, 0] - x) < 0.75) & (np.abs(centres[:, 1] - y) < 0.75)
    assert not (above & near & (centres[:, 2] < 1.5)).any()


def test_gazebo_parses_the_world_and_loads_every_chunk(
    built: tuple[Path, np.ndarray], tmp_path: Path
) -> None:
    out, _ = built
    _, shapes = probe_shapes(out / "world_gz.sdf", [out / "models"], tmp_path)
    meshes = [s for s in shapes if s.type == "mesh"]
    assert len(meshes) == 2 * len(_stls(out))  # a collision and a visual per chunk
    assert all(s.mesh_loaded for s in meshes)
    collisions = [s for s in meshes if s.kind == "collision"]
    mins = [s.mesh_min for s in collisions if s.mesh_min is not None]
    maxs = [s.mesh_max for s in collisions if s.mesh_max is not None]
    assert len(mins) == len(maxs) == len(collisions)
    lo, hi = np.min(mins, axis=0), np.max(maxs, axis=0)
    assert lo == pytest.approx([0, 0, -0.1], abs=2e-3)
    assert hi == pytest.approx([6, 4, 3.1], abs=2e-3)


def test_in_gz_sim_physics(built: tuple[Path, np.ndarray], tmp_path: Path) -> None:
    out, _ = built
    world, models = out / "world_gz.sdf", [out / "models"]
    # On the table, beside it, under the overhang (dropped from below it), on the overhang.
    points = [(1.5, 1.5), (0.5, 0.5), (3.7, 0.5), (2.5, 3.0)]
    drops = drop_probes(world, models, points, tmp_path, z=0.95)
    table, floor, under, beside = (d.height for d in drops)
    assert table == pytest.approx(0.8, abs=0.01)
    assert floor == pytest.approx(0.0, abs=0.01)
    assert under == pytest.approx(0.0, abs=0.01)  # the overhang above does not stop it
    assert beside == pytest.approx(0.0, abs=0.01)
    assert min(d.min_z for d in drops) > -0.1  # nothing below the ground
    (roof,) = drop_probes(world, models, [(3.7, 0.5)], tmp_path, z=2.0)
    assert roof.height == pytest.approx(1.3, abs=0.01)
    # A robot driven at the doorway passes it; one driven at the wall beside it stops.
    through = drive_robot(world, models, (3.9, 2.0, 0.0), tmp_path, distance=2.5)
    assert through.advance > 2.0
    blocked = drive_robot(world, models, (3.9, 0.6, 0.0), tmp_path, distance=2.5)
    assert blocked.advance < 5.0 - (3.9 + 0.495) + 0.02
    assert through.result.shapes_failed == 0 and blocked.result.shapes_failed == 0


def test_geb079_voxel_world(tmp_path: Path) -> None:
    out = tmp_path / "geb"
    assert main(["octree2world", str(GEB079), "-o", str(out), "--geometry", "voxels", "-q"]) == 0
    stls = _stls(out)
    triangles = 0
    for stl in stls:
        m = _mesh(stl)
        assert m.is_watertight and m.is_winding_consistent, stl.name
        triangles += len(m.faces)
    voxels = 185673  # geb079's occupied voxels, runs expanded
    assert triangles < 12 * voxels / 4  # far fewer than a cube per voxel
    cfg = yaml.safe_load((out / "scan2terrain.yaml").read_text())
    assert cfg["world"]["geometry"] == "voxels"


def _refused(capsys: pytest.CaptureFixture[str], args: list[str], out: Path, match: str) -> None:
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and match in err[0], err
    assert not out.exists()


@pytest.mark.parametrize(
    ("extra", "match"),
    [
        (["--max-triangles", "100"], "over world.max_triangles 100"),
        (["--z-min", "50", "--z-max", "60"], "no occupied voxel in the z band"),
        (["--grid", "height"], "octree.grid"),
        (["--unknown", "obstacle"], "terrain.unknown"),
        (["--min-voxels", "10000000"], "world.min_voxels"),
        (["--chunk", "0.08"], "more than 4096"),
    ],
)
def test_refusals(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], match: str
) -> None:
    out = tmp_path / "w"
    args = ["octree2world", str(GEB079), "-o", str(out), "--geometry", "voxels", *extra]
    _refused(capsys, args, out, match)


def test_voxels_refused_where_there_are_none(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "w"
    yaml_path = TB3_MAP
    with pytest.raises(SystemExit):  # not offered: a usage error naming the choices
        main(["map2world", str(yaml_path), "-o", str(out), "--geometry", "voxels"])
    assert "invalid choice: 'voxels'" in capsys.readouterr().err and not out.exists()
    cfg = tmp_path / "c.yaml"
    cfg.write_text("world:\n  geometry: voxels\n")
    _refused(capsys, ["map2world", str(yaml_path), "-o", str(out), "--config", str(cfg)], out,
             "no third dimension")  # fmt: skip
    image = BOWL
    _refused(capsys, ["image2world", str(image), "-o", str(out), "--config", str(cfg)], out,
             "no third dimension")  # fmt: skip
    cloud = HDL_PCD
    _refused(capsys, ["cloud2world", str(cloud), "-o", str(out), "--geometry", "voxels",
                      "--stream"], out, "streaming keeps no voxels")  # fmt: skip


def test_outliers_are_dropped_from_cloud_files(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--outliers: far scattered points leave no voxel; the same in cloud2world and convert."""
    rng = np.random.default_rng(4)
    plane = np.column_stack([rng.uniform(0, 4, 20000), rng.uniform(0, 4, 20000), np.zeros(20000)])
    far = rng.uniform(-30, 30, (20, 3)) + np.array([0.0, 0.0, 40.0])
    cloud = tmp_path / "c.xyz"
    np.savetxt(cloud, np.concatenate([plane, far]), fmt="%.4f")
    out = tmp_path / "w"
    args = ["cloud2world", str(cloud), "-o", str(out), "--geometry", "voxels", "--resolution",
            "0.1", "--outliers", "2", "--simulator", "gz"]  # fmt: skip
    assert main(args) == 0
    assert "20 statistical outliers removed" in capsys.readouterr().out
    top = max(_mesh(s).bounds[1][2] for s in _stls(out))
    assert top <= 0.1 + 1e-6  # only the plane's voxels are left
    target = tmp_path / "clean.xyz"
    assert main(["convert", str(cloud), str(target), "--outliers", "2", "-q"]) == 0
    assert len(np.loadtxt(target, ndmin=2)) == 20000
    bag = CCNY
    _refused(capsys, ["convert", str(bag), str(tmp_path / "b.xyz"), "--outliers", "2"],
             tmp_path / "b.xyz", "scans.outliers")  # fmt: skip


def test_coarser_voxels_are_octomaps_inner_nodes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--voxel-size 0.16 on a 0.08 m tree: a coarse voxel wherever any of its 8 voxels is
    occupied (OctoMap's max rule), and the meshes hold exactly those."""
    from scan2terrain.grids.occupied import occupied_voxels
    from scan2terrain.grids.projection import leaf_columns
    from scan2terrain.octree.bt import read_bt

    bt = read_bt(GEB079)
    keys, occ, runs = leaf_columns(bt.keys, bt.depth, bt.occupied)
    fine = occupied_voxels(keys, occ, runs, GEB079, why="test").astype(np.int64)
    coarse = np.unique(fine >> 1, axis=0)
    out = tmp_path / "w"
    args = ["octree2world", str(GEB079), "-o", str(out), "--geometry", "voxels",
            "--voxel-size", "0.16", "--simulator", "gz"]  # fmt: skip
    assert main(args) == 0
    assert f"{len(coarse)} occupied voxels of 0.16 m" in capsys.readouterr().out
    volume = sum(_mesh(s).volume for s in _stls(out))
    assert volume == pytest.approx(len(coarse) * 0.16**3, rel=1e-3)
    _refused(capsys, [*args[:2], "-o", str(tmp_path / "x"), "--geometry", "voxels",
                      "--voxel-size", "0.1"], tmp_path / "x", "times a power of two")  # fmt: skip


def test_colours_from_a_coloured_cloud_reach_gazebo(tmp_path: Path) -> None:
    """A PLY with RGB: each voxel takes the mean colour of its points, and gz-common's loader
    sees one submesh per colour with that diffuse colour; the collision stays uncoloured."""
    red = _box((0, 0.3), (0, 0.2), (0, 0.1))  # 6 voxels
    blue = _box((0.5, 0.7), (0, 0.1), (0, 0.1))  # 2 voxels
    pts = np.concatenate([(red + 0.5) * R, (blue + 0.5) * R, [[0.95, 0.05, 0.05]] * 2])
    rgb = np.concatenate(
        [[[255, 0, 0]] * len(red), [[0, 0, 255]] * len(blue), [[255, 255, 0], [0, 0, 0]]]
    ).astype(np.uint8)  # the last voxel: yellow and black points, mean (128, 128, 0)
    cloud = tmp_path / "c.ply"
    header = (
        f"ply\nformat ascii 1.0\nelement vertex {len(pts)}\nproperty float x\nproperty float y\n"
        "property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
        "end_header\n"
    )
    rows = [
        f"{x:.3f} {y:.3f} {z:.3f} {r} {g} {b}"
        for (x, y, z), (r, g, b) in zip(pts, rgb, strict=True)
    ]
    cloud.write_text(header + "\n".join(rows) + "\n")
    out = tmp_path / "w"
    args = ["cloud2world", str(cloud), "-o", str(out), "--geometry", "voxels", "--resolution",
            str(R), "--simulator", "gz", "-q"]  # fmt: skip
    assert main(args) == 0
    _, shapes = probe_shapes(out / "world_gz.sdf", [out / "models"], tmp_path / "probe")
    (visual,) = [s for s in shapes if s.type == "mesh" and s.kind == "visual"]
    assert visual.submeshes is not None
    seen = {tuple(round(c * 255) for c in s.diffuse[:3]) for s in visual.submeshes if s.diffuse}
    assert seen == {(255, 0, 0), (0, 0, 255), (128, 128, 0)}
    (collision,) = [s for s in shapes if s.type == "mesh" and s.kind == "collision"]
    assert collision.mesh_loaded


def test_an_octree_without_occupied_voxels_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from scan2terrain.octree.bt import bt_bytes

    tree = tmp_path / "free.bt"
    keys = np.array([[32768, 32768, 32768], [32769, 32768, 32768]], np.uint16)
    tree.write_bytes(bt_bytes(resolution=0.1, keys=keys, occupied=np.zeros(2, bool)))
    out = tmp_path / "w"
    _refused(capsys, ["octree2world", str(tree), "-o", str(out), "--geometry", "voxels"], out,
             "holds no occupied voxel")  # fmt: skip


def test_fr079_scans_become_a_closed_voxel_world(tmp_path: Path) -> None:
    """OctoMap's FR-079 corridor scans, ray cast at 0.1 m, then meshed."""
    out = tmp_path / "fr079"
    scans = FR079
    args = ["octree2world", str(scans), "-o", str(out), "--resolution", "0.1", "--geometry",
            "voxels", "--simulator", "gz", "-q"]  # fmt: skip
    assert main(args) == 0
    from scan2terrain.grids.occupied import occupied_voxels
    from scan2terrain.grids.projection import leaf_columns
    from scan2terrain.octree.bt import read_bt

    bt = read_bt(out / "octree.bt")
    keys, occ, runs = leaf_columns(bt.keys, bt.depth, bt.occupied)
    solid = occupied_voxels(keys, occ, runs, out, why="test").astype(np.float64)
    occupied = len(solid)
    # A sample of voxel centres (trimesh.contains casts rays: all 23,537 took 23 GB).
    centres = (
        solid[np.random.default_rng(0).choice(occupied, 300, replace=False)] - 32768 + 0.5
    ) * 0.1
    volume = area = 0.0
    inside = np.zeros(len(centres), bool)
    for stl in _stls(out):
        m = _mesh(stl)
        assert m.is_watertight and m.is_winding_consistent, stl.name
        volume += m.volume
        area += m.area
        near = np.all((centres >= m.bounds[0]) & (centres <= m.bounds[1]), axis=1)
        inside[near] |= m.contains(centres[near])
    assert inside.all()  # the sampled voxels' centres are inside the meshes
    # Exact up to the 1 mm hair where voxels touch only at an edge or corner (many, in a
    # sparse scan): no vertex moves farther, so the volume moves by at most 1 mm x the area.
    assert abs(volume - occupied * 0.1**3) <= 1e-3 * area


def test_bag2world_makes_voxel_worlds_too(tmp_path: Path) -> None:
    """A LaserScan bag ray cast into the octree, its occupied voxels meshed."""
    bag = FUSE_DIR
    out = tmp_path / "w"
    args = ["bag2world", str(bag), "-o", str(out), "--geometry", "voxels", "--simulator", "gz",
            "--resolution", "0.05", "-q"]  # fmt: skip
    assert main(args) == 0
    stls = _stls(out)
    assert stls
    for stl in stls:
        m = _mesh(stl)
        assert m.is_watertight and m.is_winding_consistent
    assert (out / "octree.bt").is_file() and (out / "map" / "map_gz.yaml").is_file()


# --- trees swept by a 2D laser: one scan plane, walls extruded -----------------------------------


def _walls(out: Path) -> tuple[float, float, float]:
    """The voxel meshes' lowest and highest z and their volume."""
    meshes = [_mesh(s) for s in _stls(out)]
    assert all(m.is_watertight and m.is_winding_consistent for m in meshes)
    lo = min(float(m.bounds[0][2]) for m in meshes)
    hi = max(float(m.bounds[1][2]) for m in meshes)
    return lo, hi, sum(float(m.volume) for m in meshes)


def _map(out: Path) -> np.ndarray:
    from scan2terrain.readers import read_map_yaml

    return read_map_yaml(out / "map/map_gz.yaml")[1].data


def _check_2d_laser_world(out: Path, height: float, res: float) -> np.ndarray:
    """Walls ``height`` high (at least) from z = 0 over every occupied map cell, nothing else;
    map/ holds walls and free space."""
    grid = _map(out)
    walls = int((grid == 100).sum())
    assert walls > 0 and (grid == 0).sum() > walls  # not all unknown: walls and free space
    lo, hi, volume = _walls(out)
    assert lo == pytest.approx(0.0, abs=1e-6)  # STL holds float32
    assert hi >= height - 1e-6
    layers = math.ceil(height / res - 1e-9)
    # Each occupied column of map/ is one wall column of `layers` voxels (up to the 1 mm hair
    # where wall voxels touch only at an edge).
    assert volume == pytest.approx(walls * layers * res**3, rel=2e-3)
    return grid


def test_a_2d_laser_bag_becomes_walls_of_the_wall_height(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A LaserScan bag ray cast into the octree is one scan plane (here two voxel layers: the
    odometry's z wavers around 0): its hits become walls --height high from z = 0, as the
    other geometries make them, and map/ is the projection of the whole tree (walls and the
    free space the laser saw), not the empty band 0.3-2 m above a floor it never saw. The same
    from the octree.bt it wrote."""
    out = tmp_path / "bag"
    args = ["bag2world", str(FUSE), "-o", str(out), "--geometry", "voxels", "--simulator", "gz",
            "--height", "1.2"]  # fmt: skip
    assert main(args) == 0
    printed = capsys.readouterr().out
    grid = _check_2d_laser_world(out, 1.2, 0.05)
    assert "one scan plane" in printed
    bt = tmp_path / "bt"
    args = ["octree2world", str(out / "octree.bt"), "-o", str(bt), "--geometry", "voxels",
            "--simulator", "gz", "--height", "1.2", "-q"]  # fmt: skip
    assert main(args) == 0
    np.testing.assert_array_equal(_check_2d_laser_world(bt, 1.2, 0.05), grid)


def _room_scan_file(path: Path, every: int = 5) -> Path:
    """The synthetic room's 2D scans (laser 0.3 m above the floor) as an OctoMap scan file."""
    from tests.bagmaker import synthetic_room

    room = synthetic_room("tf", n_scans=100)
    lines = []
    for k in range(0, len(room.hits), every):
        origin = room.sensor_origins()[k]
        lines.append("NODE {:.6f} {:.6f} {:.6f} 0 0 0".format(*origin))
        lines += ["{:.6f} {:.6f} {:.6f}".format(*p) for p in room.hits[k] - origin]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_a_2d_laser_scan_file_becomes_walls(tmp_path: Path) -> None:
    """octree2world on OctoMap scans of one plane (0.3 m up): walls 2 m high (terrain.height)
    from z = 0, map/ with walls and free space."""
    scans = _room_scan_file(tmp_path / "room.dat")
    out = tmp_path / "w"
    args = ["octree2world", str(scans), "-o", str(out), "--geometry", "voxels", "--resolution",
            "0.1", "--simulator", "gz", "-q"]  # fmt: skip
    assert main(args) == 0
    _check_2d_laser_world(out, 2.0, 0.1)


def test_floors_are_not_taken_for_scan_planes(tmp_path: Path) -> None:
    """A floor seen from 0.2 m above (free voxels over it) and a floor of end points only (no
    free voxel) stay floors, one voxel thick; map/ shows their columns as free, never all
    unknown."""
    from scan2terrain.commands.voxels import voxels_folder
    from scan2terrain.config import load_config

    xs, ys = np.meshgrid(np.arange(32760, 32780), np.arange(32760, 32780))
    floor = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, 32767)])
    above = np.concatenate([floor + np.array([0, 0, dz]) for dz in (1, 2)])  # 0.2 m free
    cfg = load_config(None, {"world.geometry": "voxels", "world.simulator": "gz"})
    for name, keys, occupied in (
        ("seen", np.concatenate([floor, above]), np.arange(len(floor) + len(above)) < len(floor)),
        ("endpoints", floor, np.ones(len(floor), bool)),
    ):
        out = tmp_path / name
        folder = voxels_folder(keys.astype(np.uint16), occupied, 0.1, source=GEB079, cfg=cfg)
        write_world_folder(folder, out, overwrite=False)
        lo, hi, _ = _walls(out)
        assert (lo, hi) == pytest.approx((-0.1, 0.0), abs=1e-6), name
        grid = _map(out)
        assert (grid == 0).sum() == len(floor) and (grid == 100).sum() == 0, name


def test_a_robot_cannot_drive_through_the_walls_of_a_2d_laser_world(tmp_path: Path) -> None:
    """The synthetic room's LaserScan bag (laser 0.3 m up) as --geometry voxels, in gz-sim's
    physics: a robot driven at a wall stops at it; one driven along the free room does not."""
    from tests.bagmaker import synthetic_room

    bag = synthetic_room("tf", n_scans=60).write(tmp_path / "room.bag", "ros1")
    out = tmp_path / "w"
    args = ["bag2world", str(bag), "-o", str(out), "--geometry", "voxels", "--simulator", "gz",
            "-q"]  # fmt: skip
    assert main(args) == 0
    world, models = out / "world_gz.sdf", [out / "models"]
    # On the ground, as spawn.yaml says (z: the floor's height in this world).
    z = yaml.safe_load((out / "spawn.yaml").read_text())["gz"]["pose"][2]
    # The wall at x = 5.025: its voxels' inner face is x = 5.0.
    blocked = drive_robot(world, models, (3.5, 2.0, 0.0), tmp_path, distance=2.5, z=z)
    assert blocked.advance < 5.0 - (3.5 + 0.495) + 0.02
    free = drive_robot(world, models, (-3.5, 2.5, 0.0), tmp_path, distance=2.5, z=z)
    assert free.advance > 2.0
    assert blocked.result.shapes_failed == 0 and free.result.shapes_failed == 0
