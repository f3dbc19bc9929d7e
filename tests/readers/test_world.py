"""readers/world.py: a Gazebo world's collision geometry read back as triangles in the world
frame (issue 26's fidelity check), checked against Gazebo's own code.

Every world our commands write (map2world with each geometry, octree2world voxels, dem2world,
terrain tiles, bag2world), both world_gz.sdf and world_classic.world, is read back and compared
with what tests/gazebo/heightmap_probe.cpp reports (SDFormat 12 + gz-common 4, as gz-sim loads
the files): heightmap vertices and cell-edge midpoints at the probe's heights as each simulator
lays the field out (tests/gazebo_harness.py ``terrain_height``); boxes where the probe places
them; meshes as the same triangles gz-common loads; polylines as gz-common's extrusion (same cap
areas, wall areas and bounds; other triangles). A hand-written world gives analytic bounds and
areas, and every kind of bad input is one InputError naming the file at fault.
"""

from __future__ import annotations

import math
import os
import struct
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from scipy.spatial.transform import Rotation

from scan2terrain.cli import main
from scan2terrain.commands import maps
from scan2terrain.config import load_config
from scan2terrain.errors import InputError
from scan2terrain.exporters.meshfile import dae_bytes, obj_bytes, stl_bytes
from scan2terrain.geometry.mesh import Mesh, boxes_mesh
from scan2terrain.readers.world import MAX_TRIANGLES, Simulator, WorldGeometry, read_world
from scan2terrain.types import HeightGrid, Pose2D
from scan2terrain.world.folder import write_world_folder
from tests.conftest import write_map
from tests.fixtures import BOWL, FUSE, GEB079, MAPS, MOON, SFBAY
from tests.gazebo_harness import (
    HeightmapProbe,
    ShapeProbe,
    probe_shapes,
    probe_world,
    terrain_height,
    vertex_world_xy,
)

H = 2.0
WORLDS: tuple[tuple[str, Simulator], ...] = (
    ("world_gz.sdf", "gz"),
    ("world_classic.world", "classic"),
)


# --------------------------------------------------------------------------- helpers


def pose_matrix(pose: tuple[float, ...]) -> np.ndarray:
    """A probe's (x, y, z, roll, pitch, yaw) as a 4x4 transform (scipy's extrinsic xyz =
    Rz Ry Rx, independent of the reader's own code)."""
    out = np.eye(4)
    out[:3, :3] = Rotation.from_euler("xyz", pose[3:]).as_matrix()
    out[:3, 3] = pose[:3]
    return out


def transform(points: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    result: np.ndarray = points @ matrix[:3, :3].T + matrix[:3, 3]
    return result


def areas(tri: np.ndarray) -> np.ndarray:
    result: np.ndarray = 0.5 * np.linalg.norm(
        np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1
    )
    return result


def labelled(geo: WorldGeometry) -> dict[str, int]:
    """Part index by its label (model/link/collision)."""
    return {p.split(": ", 1)[0]: k for k, p in enumerate(geo.parts)}


def sorted_triangles(tri: np.ndarray) -> np.ndarray:
    """Triangles (T, 3, 3) in a canonical order: each one's vertices rotated (winding kept) to
    start at its lexicographically smallest, then the rows sorted."""
    flat = tri.reshape(len(tri), 3, 3)
    points = flat.reshape(-1, 3)
    rank = np.empty(len(points), dtype=np.int64)
    rank[np.lexsort(points.T[::-1])] = np.arange(len(points))
    first = np.argmin(rank.reshape(-1, 3), axis=1)
    turn = (first[:, None] + np.arange(3)) % 3
    rows = flat[np.arange(len(flat))[:, None], turn].reshape(len(tri), 9)
    result: np.ndarray = rows[np.lexsort(rows.T[::-1])]
    return result


def check_shapes(
    geo: WorldGeometry, shapes: list[ShapeProbe], mesh_atol: float = 1e-9
) -> dict[str, int]:
    """Every collision the probe reports that is not a heightmap is a part of ``geo`` with the
    same geometry; how many of each type were compared. ``mesh_atol``: 1e-6 for OBJ and COLLADA,
    which one of the two readers takes as float32."""
    index = labelled(geo)
    checked: dict[str, int] = {}
    for s in shapes:
        if s.kind != "collision":
            continue
        label = f"{s.model}/{s.link}/{s.name}"
        assert label in index, f"{label} not read; parts: {list(index)[:5]}"
        mine = geo.part(index[label])
        matrix = pose_matrix(s.pose)
        if s.type == "box":
            assert s.size is not None
            corners = np.array(
                [[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)]
            ) * np.array(s.size)
            want = transform(corners, matrix)
            got = mine.reshape(-1, 3)
            assert len(mine) == 12
            np.testing.assert_allclose(got.min(axis=0), want.min(axis=0), atol=1e-9)
            np.testing.assert_allclose(got.max(axis=0), want.max(axis=0), atol=1e-9)
            # Every vertex is one of the box's corners.
            d = np.linalg.norm(got[:, None, :] - want[None, :, :], axis=2).min(axis=1)
            assert d.max() < 1e-9
        elif s.type == "mesh":
            assert s.triangles is not None and s.scale is not None
            want = transform(s.triangles.reshape(-1, 3) * np.array(s.scale), matrix)
            np.testing.assert_allclose(
                sorted_triangles(mine), sorted_triangles(want.reshape(-1, 3, 3)), atol=mesh_atol
            )
        elif s.type == "polyline":
            assert s.extrusion == "ok" and s.triangles is not None, s.name
            want = transform(s.triangles.reshape(-1, 3), matrix).reshape(-1, 3, 3)
            compare_extrusions(mine, want, s.name)
        else:
            raise AssertionError(f"unexpected collision type {s.type} in our worlds")
        checked[s.type] = checked.get(s.type, 0) + 1
    return checked


def compare_extrusions(mine: np.ndarray, want: np.ndarray, name: str) -> None:
    """Two extrusions of the same polylines: the same bounds, top and bottom cap areas and wall
    area (the caps may be triangulated differently)."""
    np.testing.assert_allclose(
        mine.reshape(-1, 3).min(axis=0), want.reshape(-1, 3).min(axis=0), atol=1e-9
    )
    np.testing.assert_allclose(
        mine.reshape(-1, 3).max(axis=0), want.reshape(-1, 3).max(axis=0), atol=1e-9
    )

    def split(tri: np.ndarray) -> tuple[float, float, float]:
        z = tri[..., 2]
        top = np.all(np.isclose(z, z.max(), atol=1e-9), axis=1)
        bottom = np.all(np.isclose(z, z.min(), atol=1e-9), axis=1)
        a = areas(tri)
        return float(a[top].sum()), float(a[bottom].sum()), float(a[~top & ~bottom].sum())

    got, expected = split(mine), split(want)
    np.testing.assert_allclose(got, expected, rtol=1e-9, err_msg=name)


def heightmap_block(geo: WorldGeometry, k: int) -> np.ndarray:
    """The (V, V, 3) vertices of heightmap part ``k`` (row-major, row 0 = the image's top)."""
    start = sum(geo.part_triangles[:k])
    rows = geo.triangles[start : start + geo.part_triangles[k]]
    lo, hi = int(rows.min()), int(rows.max()) + 1
    n = math.isqrt(hi - lo)
    assert n * n == hi - lo
    block: np.ndarray = geo.vertices[lo:hi].reshape(n, n, 3)
    return block


def cast_down(vertices: np.ndarray, triangles: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """The z where a vertical ray down at each (x, y) first meets the triangles (Open3D, whose
    float32 would cost 0.5 mm at 4 km: everything is shifted to the points' centre first)."""
    import open3d as o3d

    centre = np.array([*xy.mean(axis=0), vertices[:, 2].mean()])
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor.from_numpy((vertices - centre).astype(np.float32)),
        o3d.core.Tensor.from_numpy(triangles.astype(np.uint32)),
    )
    top = float(vertices[:, 2].max() - centre[2]) + 1.0
    rays = np.zeros((len(xy), 6), dtype=np.float32)
    rays[:, :2] = xy - centre[:2]
    rays[:, 2], rays[:, 5] = top, -1.0
    hit = scene.cast_rays(o3d.core.Tensor.from_numpy(rays))["t_hit"].numpy().astype(np.float64)
    result: np.ndarray = top - hit + centre[2]
    return result


def check_heightmaps(geo: WorldGeometry, probes: list[HeightmapProbe], simulator: Simulator) -> int:
    """Every collision heightmap of the probe, at every vertex (x, y and z) and at the midpoints
    of (a sample of) cell edges: the reader's surface is the probe's within 1e-4 m. Returns how
    many heightmaps were compared."""
    index = labelled(geo)
    rng = np.random.default_rng(0)
    count = 0
    for p in probes:
        if p.kind != "collision":
            continue
        k = index[f"{p.model}/{p.link}/{p.name}"]
        block = heightmap_block(geo, k)
        n = block.shape[0]
        assert n == p.vert_size
        rows, cols = np.indices((n, n))
        wx, wy = vertex_world_xy(p, rows, cols, simulator)
        np.testing.assert_allclose(block[..., 0], wx, atol=1e-6)
        np.testing.assert_allclose(block[..., 1], wy, atol=1e-6)
        want = terrain_height(p, block[..., 0], block[..., 1], simulator)
        np.testing.assert_allclose(block[..., 2], want, atol=1e-4)
        # Midpoints of the inner cell edges of a window of up to 64 x 64 cells: along row r
        # between columns c and c + 1, along column c between rows r and r + 1 (not on the
        # window's rim, where a ray down the edge may slip past), cast into the window's
        # triangles.
        w = min(n, 65)
        r0, c0 = (int(v) for v in rng.integers(0, n - w + 1, 2))
        start = sum(geo.part_triangles[:k])
        tri = geo.triangles[start : start + geo.part_triangles[k]]
        local = tri - tri.min()
        rows_t, cols_t = local // n, local % n
        inside = np.all(
            (rows_t >= r0) & (rows_t < r0 + w) & (cols_t >= c0) & (cols_t < c0 + w), axis=1
        )
        r, c = np.meshgrid(np.arange(r0 + 1, r0 + w - 1), np.arange(c0, c0 + w - 1), indexing="ij")
        mid_row = (block[r, c] + block[r, c + 1]) / 2
        rc, cc = np.meshgrid(
            np.arange(r0, r0 + w - 1), np.arange(c0 + 1, c0 + w - 1), indexing="ij"
        )
        mid_col = (block[rc, cc] + block[rc + 1, cc]) / 2
        mid = np.concatenate([mid_row.reshape(-1, 3), mid_col.reshape(-1, 3)])
        got = cast_down(geo.vertices, tri[inside], mid[:, :2])
        want_mid = terrain_height(p, mid[:, 0], mid[:, 1], simulator)
        assert np.abs(got - want_mid).max() < 1e-4
        count += 1
    return count


def check_world_file(world: Path, simulator: Simulator, tmp: Path) -> dict[str, int]:
    """Read ``world`` and compare every collision with the probe's; what was compared."""
    geo = read_world(world, simulator=simulator)
    models = world.parent / "models"
    _, shapes = probe_shapes(world, [models], tmp / f"shapes_{simulator}")
    checked = check_shapes(geo, shapes)
    _, probes = probe_world(world, [models], tmp / f"heights_{simulator}")
    heightmaps = check_heightmaps(geo, probes, simulator)
    if heightmaps:
        checked["heightmap"] = heightmaps
    # Nothing read that the probe does not know of.
    assert len(geo.parts) == sum(checked.values())
    return checked


def map_world(source: Path, out: Path, geometry: str, **overrides: object) -> Path:
    cfg = load_config(None, {"terrain.height": H, "world.geometry": geometry, **overrides})
    maps.map2world(source, out, cfg)
    return out


# --------------------------------------------------------------------------- our worlds


@pytest.mark.parametrize("geometry", ["mesh", "boxes", "polylines", "heightmap"])
def test_map2world_worlds_read_back_as_gazebo_loads_them(tmp_path: Path, geometry: str) -> None:
    out = map_world(MAPS["tb3"], tmp_path / "out", geometry)
    for name, sim in WORLDS:
        checked = check_world_file(out / name, sim, tmp_path / sim)
        assert checked.get("box", 0) >= 1
        if geometry != "boxes":
            key = {"mesh": "mesh", "polylines": "polyline", "heightmap": "heightmap"}[geometry]
            assert checked[key] >= 1


def test_polylines_with_holes_and_islands(tmp_path: Path) -> None:
    """A wall ring around a free room with a pillar inside: one polygon with a hole, and an
    island in the hole (even-odd: solid again)."""
    pixels = np.full((40, 40), 254, dtype=np.uint8)
    pixels[5:35, 5:35] = 0
    pixels[8:32, 8:32] = 254
    pixels[17:23, 17:23] = 0
    pixels[12:14, 25:27] = 0
    yaml_path = write_map(tmp_path / "map", pixels, resolution=0.1)
    out = map_world(yaml_path, tmp_path / "out", "polylines", **{"filter.enabled": False})
    for name, sim in WORLDS:
        geo = read_world(out / name, simulator=sim)
        assert any("2 rings" in p for p in geo.parts), geo.parts
        checked = check_world_file(out / name, sim, tmp_path / sim)
        assert checked["polyline"] == 3


def test_one_polyline_geometry_with_an_island_in_a_hole(tmp_path: Path) -> None:
    """Three nested rings in one <geometry>: exterior, hole, island; even-odd as gz-common."""
    rings = [
        [(0, 0), (10, 0), (10, 10), (0, 10)],
        [(2, 2), (8, 2), (8, 8), (2, 8)],
        [(4, 4), (6, 4), (6, 6), (4, 6)],
    ]
    lines = "".join(
        "<polyline>"
        + "".join(f"<point>{x + 0.001 * k} {y - 0.0007 * k}</point>" for x, y in ring)
        + "<height>3</height></polyline>"
        for k, ring in enumerate(rings)
    )
    world = tmp_path / "w.sdf"
    world.write_text(
        world_sdf(
            f'<model name="p"><static>true</static><link name="l">'
            f'<collision name="c"><geometry>{lines}</geometry></collision></link></model>'
        )
    )
    geo = read_world(world)
    tri = geo.part(0)
    top = tri[np.all(np.isclose(tri[..., 2], 3.0), axis=1)]
    assert areas(top).sum() == pytest.approx(100 - 36 + 4, rel=1e-3)
    _, shapes = probe_shapes(world, [], tmp_path / "probe")
    assert check_shapes(geo, shapes) == {"polyline": 1}


def test_voxel_world_reads_back(tmp_path: Path) -> None:
    out = tmp_path / "out"
    geb079 = GEB079
    assert main(["octree2world", str(geb079), "-o", str(out), "--geometry", "voxels", "-q"]) == 0
    for name, sim in WORLDS:
        checked = check_world_file(out / name, sim, tmp_path / sim)
        assert checked["mesh"] >= 2 and checked["box"] == 1


def test_dem_worlds_read_back(tmp_path: Path) -> None:
    moon = MOON
    sfbay = SFBAY
    assert main(["dem2world", str(moon), "-o", str(tmp_path / "moon"), "-q"]) == 0
    checked = check_world_file(tmp_path / "moon/world_gz.sdf", "gz", tmp_path / "moon_probe")
    assert checked["heightmap"] == 1
    out = tmp_path / "sfbay"
    args = ["dem2world", str(sfbay), "-o", str(out), "--simulator", "both", "--bit-depth", "8"]
    assert main([*args, "-q"]) == 0
    for name, sim in WORLDS:
        assert check_world_file(out / name, sim, tmp_path / f"sfbay_{sim}")["heightmap"] == 1


def test_terrain_tiles_read_back(tmp_path: Path) -> None:
    yy, xx = np.mgrid[0:70, 0:90]
    heights = (np.sin(xx / 7.0) * 1.5 + np.cos(yy / 5.0) + 3).astype(np.float32)
    grid = HeightGrid(heights, np.ones(heights.shape, dtype=bool), 0.5, Pose2D(-3.0, 2.0, 0.3))
    cfg = load_config(
        None,
        {
            "terrain.max_side": 33,
            "filter.enabled": False,
            "world.simulator": "gz",
            "world.geometry": "heightmap",
        },
    )
    out = tmp_path / "out"
    write_world_folder(maps.height_folder(grid, Path("hills.xyz"), cfg), out, overwrite=False)
    checked = check_world_file(out / "world_gz.sdf", "gz", tmp_path / "probe")
    assert checked["heightmap"] >= 6


def test_image_world_with_sampling_reads_back(tmp_path: Path) -> None:
    """image2world from an RGB picture, gz sampling 2 (bilinear heights between pixels)."""
    cfg = load_config(
        None, {"terrain.height": 3.0, "world.geometry": "heightmap", "world.sampling": 2}
    )
    out = tmp_path / "out"
    maps.image2world(BOWL, out, cfg)
    for name, sim in WORLDS:
        assert check_world_file(out / name, sim, tmp_path / sim)["heightmap"] == 1


def test_bag_world_reads_back_and_from_bytes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    bag = FUSE
    out = tmp_path / "out"
    assert main(["bag2world", str(bag), "-o", str(out), "-q"]) == 0
    for name, sim in WORLDS:
        check_world_file(out / name, sim, tmp_path / sim)
        disk = read_world(out / name, simulator=sim)
        # The same world from bytes (a world folder before it is written), from elsewhere.
        files = {
            p.relative_to(out).as_posix(): p.read_bytes()
            for p in (out / "models").rglob("*")
            if p.is_file()
        }
        files[name] = (out / name).read_bytes()
        empty = tmp_path / "elsewhere"
        empty.mkdir(exist_ok=True)
        monkeypatch.chdir(empty)
        from_bytes = read_world(Path(name), simulator=sim, files=files)
        np.testing.assert_array_equal(from_bytes.vertices, disk.vertices)
        np.testing.assert_array_equal(from_bytes.triangles, disk.triangles)
        assert [p.split(": ")[1] for p in from_bytes.parts] == [
            p.split(": ")[1] for p in disk.parts
        ]


def test_our_mesh_formats_are_the_same_triangles(tmp_path: Path) -> None:
    """The STL, OBJ and DAE of one mesh (exporters/meshfile.py) read back as the same
    triangles, here and in gz-common (STL as float32)."""
    mesh = boxes_mesh(np.array([[1.25, -2.5, 0.4, 1.7, 0.3], [4.0, 1.0, 2.0, 0.5, 1.2]]), 2.5)
    models = tmp_path / "models"
    folder = models / "m"
    (folder / "meshes").mkdir(parents=True)
    (folder / "meshes/w.stl").write_bytes(stl_bytes(mesh))
    (folder / "meshes/w.obj").write_bytes(obj_bytes(mesh))
    (folder / "meshes/w.dae").write_bytes(dae_bytes(mesh, "w"))
    collisions = "".join(
        f'<collision name="{ext}"><pose>1 2 0.5 0.1 0 0.7</pose><geometry><mesh>'
        f"<uri>model://m/meshes/w.{ext}</uri></mesh></geometry></collision>"
        for ext in ("stl", "obj", "dae")
    )
    (folder / "model.sdf").write_text(
        f'<?xml version="1.0"?><sdf version="1.9"><model name="m"><static>true</static>'
        f'<link name="l">{collisions}</link></model></sdf>'
    )
    (folder / "model.config").write_text(
        '<?xml version="1.0"?><model><name>m</name><sdf version="1.9">model.sdf</sdf></model>'
    )
    world = tmp_path / "w.sdf"
    world.write_text(world_sdf("<include><uri>model://m</uri></include>"))
    geo = read_world(world)
    stl, obj, dae = (sorted_triangles(geo.part(k)) for k in range(3))
    # STL holds float32; pycollada reads COLLADA's text as float32 too (OBJ: float64).
    np.testing.assert_allclose(stl, obj, atol=1e-6)
    np.testing.assert_allclose(dae, obj, atol=1e-6)
    _, shapes = probe_shapes(world, [models], tmp_path / "probe")
    stl_probe, obj_probe, dae_probe = (s for s in shapes if s.kind == "collision")
    assert check_shapes(geo, [stl_probe]) == {"mesh": 1}
    # gz-common reads OBJ as float32 (tinyobjloader), COLLADA as float64; trimesh the opposite.
    assert check_shapes(geo, [obj_probe, dae_probe], mesh_atol=1e-6) == {"mesh": 2}


# --------------------------------------------------------------------------- a hand-made world


def world_sdf(body: str, version: str = "1.9") -> str:
    return f'<?xml version="1.0"?>\n<sdf version="{version}"><world name="w">{body}</world></sdf>\n'


def cube_stl(side: float = 1.0) -> bytes:
    """A binary STL cube of ``side`` metres centred on the origin."""
    mesh = boxes_mesh(np.array([[0.0, 0.0, side, side, 0.0]]), side, base=-side / 2)
    return stl_bytes(Mesh(mesh.vertices, mesh.faces))


def model_folder(parent: Path, name: str, mesh: str = "cube.stl", data: bytes = b"") -> Path:
    folder = parent / name
    (folder / "meshes").mkdir(parents=True)
    (folder / "meshes" / mesh).write_bytes(data or cube_stl())
    (folder / "model.config").write_text(
        f'<?xml version="1.0"?><model><name>{name}</name><sdf version="1.9">model.sdf</sdf></model>'
    )
    (folder / "model.sdf").write_text(
        f'<?xml version="1.0"?><sdf version="1.9"><model name="{name}"><static>true</static>'
        f'<pose>100 100 100 0 0 0</pose><link name="link"><collision name="col"><geometry>'
        f"<mesh><uri>model://{name}/meshes/{mesh}</uri><scale>2 2 2</scale></mesh>"
        f"</geometry></collision></link></model></sdf>"
    )
    return folder


HAND_WORLD = """
<model name="shapes"><static>true</static>
  <link name="l">
    <collision name="box"><pose>1 2 0.25 0 0 0.5235987755982988</pose>
      <geometry><box><size>2 1 0.5</size></box></geometry></collision>
    <collision name="cylinder"><pose>5 0 1 1.5707963267948966 0 0</pose>
      <geometry><cylinder><radius>0.5</radius><length>2</length></cylinder></geometry></collision>
    <collision name="sphere"><pose>0 5 2 0 0 0</pose>
      <geometry><sphere><radius>0.3</radius></sphere></geometry></collision>
    <collision name="plane"><pose>0 0 -1 0 0 0</pose>
      <geometry><plane><normal>0 0 1</normal><size>10 10</size></plane></geometry></collision>
  </link>
</model>
<include><uri>model://cube_a</uri><name>first</name>
  <pose degrees="true">-3 2 0.5 0 0 45</pose></include>
<include><uri>model://cube_b</uri></include>
"""


@pytest.fixture
def hand_world(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> tuple[Path, Path, Path]:
    """A world with a box, a cylinder, a sphere, a plane and two mesh includes: cube_a through
    a model path, cube_b through GZ_SIM_RESOURCE_PATH."""
    paths = tmp_path / "model_path"
    env = tmp_path / "env_path"
    model_folder(paths, "cube_a")
    model_folder(env, "cube_b")
    monkeypatch.setenv("GZ_SIM_RESOURCE_PATH", f"/nonexistent{os.pathsep}{env}")
    world = tmp_path / "hand.sdf"
    world.write_text(world_sdf(HAND_WORLD))
    return world, paths, env


@pytest.mark.parametrize("simulator", ["gz", "classic"])
def test_hand_written_world_gives_analytic_shapes(
    hand_world: tuple[Path, Path, Path], simulator: Simulator, tmp_path: Path
) -> None:
    world, paths, env = hand_world
    geo = read_world(world, simulator=simulator, model_paths=[paths])
    index = labelled(geo)
    assert list(index) == [
        "shapes/l/box",
        "shapes/l/cylinder",
        "shapes/l/sphere",
        "shapes/l/plane",
        "first/link/col",
        "cube_b/link/col",
    ]

    def bounds(label: str) -> np.ndarray:
        pts = geo.part(index[label]).reshape(-1, 3)
        return np.stack([pts.min(axis=0), pts.max(axis=0)])

    c, s = math.cos(math.pi / 6), math.sin(math.pi / 6)
    half = np.array([c * 1 + s * 0.5, s * 1 + c * 0.5, 0.25])
    centre = np.array([1, 2, 0.25])
    np.testing.assert_allclose(bounds("shapes/l/box"), [centre - half, centre + half])
    # The cylinder, turned 90 degrees about x, lies along y.
    np.testing.assert_allclose(
        bounds("shapes/l/cylinder"), [[4.5, -1, 0.5], [5.5, 1, 1.5]], atol=1e-12
    )
    tri = geo.part(index["shapes/l/cylinder"])
    n = int(geo.parts[index["shapes/l/cylinder"]].split(", ")[2].split()[0])
    polygon_area = n / 2 * 0.25 * math.sin(2 * math.pi / n)
    side = 2 * n * 0.5 * math.sin(math.pi / n) * 2
    assert areas(tri).sum() == pytest.approx(side + 2 * polygon_area, rel=1e-9)
    assert areas(tri).sum() == pytest.approx(2 * math.pi * 0.5 * 2 + 2 * math.pi * 0.25, rel=1e-4)
    sphere = geo.part(index["shapes/l/sphere"]).reshape(-1, 3) - [0, 5, 2]
    np.testing.assert_allclose(np.linalg.norm(sphere, axis=1), 0.3, atol=1e-12)
    assert areas(geo.part(index["shapes/l/sphere"])).sum() == pytest.approx(
        4 * math.pi * 0.09, rel=3e-3
    )
    plane = bounds("shapes/l/plane")
    if simulator == "gz":  # dartsim's 2100 m cube, its top face the plane
        np.testing.assert_allclose(plane, [[-1050, -1050, -2101], [1050, 1050, -1]])
    else:  # ODE's plane cut to 2100 m
        np.testing.assert_allclose(plane, [[-1050, -1050, -1], [1050, 1050, -1]])
    # The includes: a cube of 1 m scaled 2, at the include's pose (degrees) or its own.
    r = math.sqrt(2)
    np.testing.assert_allclose(
        bounds("first/link/col"), [[-3 - r, 2 - r, -0.5], [-3 + r, 2 + r, 1.5]], atol=1e-6
    )
    np.testing.assert_allclose(bounds("cube_b/link/col"), [[99, 99, 99], [101, 101, 101]])
    # And Gazebo places the boxes and meshes where the reader does.
    _, shapes = probe_shapes(world, [paths, env], tmp_path / f"probe_{simulator}")
    meshes_and_boxes = [s for s in shapes if s.type in ("box", "mesh")]
    assert check_shapes(geo, meshes_and_boxes) == {"box": 1, "mesh": 2}
    for shape in shapes:
        if shape.kind == "collision" and shape.type not in ("box", "mesh"):
            k = index[f"{shape.model}/{shape.link}/{shape.name}"]
            pts = geo.part(k).reshape(-1, 3)
            centre = (pts.min(axis=0) + pts.max(axis=0)) / 2
            if shape.name in ("cylinder", "sphere"):
                np.testing.assert_allclose(centre, shape.pose[:3], atol=1e-9)


def test_more_shapes_and_pose_forms(tmp_path: Path) -> None:
    """Capsule, ellipsoid; a pose in degrees, as a quaternion and in radians agree; nested
    models and an include inside a model compose their poses."""
    (tmp_path / "models").mkdir()
    model_folder(tmp_path / "models", "cube")
    world = tmp_path / "w.sdf"
    world.write_text(
        world_sdf("""
<model name="outer"><pose>10 0 0 0 0 1.5707963267948966</pose>
  <link name="l"><pose>1 0 0 0 0 0</pose>
    <collision name="capsule"><geometry>
      <capsule><radius>0.5</radius><length>1</length></capsule></geometry></collision>
    <collision name="ellipsoid"><pose>0 0 3 0 0 0</pose><geometry>
      <ellipsoid><radii>1 2 3</radii></ellipsoid></geometry></collision>
    <collision name="rad"><pose>0 0 0 0.3 0.2 0.1</pose>
      <geometry><box><size>1 2 3</size></box></geometry></collision>
    <collision name="deg">
      <pose degrees="true">0 0 0 17.188733853924695 11.459155902616466 5.729577951308232</pose>
      <geometry><box><size>1 2 3</size></box></geometry></collision>
    <collision name="quat"><pose rotation_format="quat_xyzw">0 0 0 QUAT</pose>
      <geometry><box><size>1 2 3</size></box></geometry></collision>
  </link>
  <model name="inner"><pose>0 5 0 0 0 0</pose>
    <include><uri>model://cube</uri><name>c</name><pose>0 0 1 0 0 0</pose></include>
  </model>
</model>""").replace(
            "QUAT",
            " ".join(repr(float(q)) for q in Rotation.from_euler("xyz", [0.3, 0.2, 0.1]).as_quat()),
        )
    )
    geo = read_world(world)
    index = labelled(geo)
    capsule = geo.part(index["outer/l/capsule"]).reshape(-1, 3)
    np.testing.assert_allclose(capsule.min(axis=0), [9.5, 0.5, -1], atol=1e-9)
    np.testing.assert_allclose(capsule.max(axis=0), [10.5, 1.5, 1], atol=1e-9)
    ellipsoid = geo.part(index["outer/l/ellipsoid"]).reshape(-1, 3)
    # The model's quarter turn swaps x and y.
    np.testing.assert_allclose(ellipsoid.max(axis=0) - ellipsoid.min(axis=0), [4, 2, 6], atol=2e-3)
    rad, deg, quat = (geo.part(index[f"outer/l/{k}"]) for k in ("rad", "deg", "quat"))
    np.testing.assert_allclose(deg, rad, atol=1e-12)
    np.testing.assert_allclose(quat, rad, atol=1e-6)
    cube = geo.part(index["outer::inner::c/link/col"]).reshape(-1, 3)
    np.testing.assert_allclose((cube.min(axis=0) + cube.max(axis=0)) / 2, [5, 0, 1], atol=1e-9)
    _, shapes = probe_shapes(world, [tmp_path / "models"], tmp_path / "probe")
    assert check_shapes(geo, [s for s in shapes if s.type in ("box", "mesh")]) == {
        "box": 3,
        "mesh": 1,
    }


def test_a_model_file_and_relative_uris(tmp_path: Path) -> None:
    """A file holding a <model> (no world) is read too; a relative mesh URI is relative to the
    file naming it, file:// names a path."""
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub/cube.stl").write_bytes(cube_stl())
    (tmp_path / "abs.stl").write_bytes(cube_stl(2.0))
    model = tmp_path / "sub/model.sdf"
    model.write_text(
        '<?xml version="1.0"?><sdf version="1.9"><model name="m"><link name="l">'
        '<collision name="rel"><geometry><mesh><uri>cube.stl</uri></mesh></geometry></collision>'
        f'<collision name="abs"><geometry><mesh><uri>file://{tmp_path}/abs.stl</uri></mesh>'
        "</geometry></collision></link></model></sdf>"
    )
    geo = read_world(model)
    assert np.ptp(geo.part(0).reshape(-1, 3), axis=0) == pytest.approx([1, 1, 1])
    assert np.ptp(geo.part(1).reshape(-1, 3), axis=0) == pytest.approx([2, 2, 2])


def test_heightmap_of_a_hand_made_16_bit_and_rgb_image(tmp_path: Path) -> None:
    """gz: a 16-bit greyscale image with sampling 3 and a turned, lifted collision; an 8-bit
    RGB image whose colour channels differ. Classic: an 8-bit grey one, turned, away from the
    origin (where Classic leaves it)."""
    rng = np.random.default_rng(3)
    (tmp_path / "m").mkdir()
    grey16 = (rng.random((17, 17)) * 60000).astype(np.uint16)
    Image.fromarray(grey16).save(tmp_path / "m/grey16.png")
    rgb = rng.integers(0, 256, (33, 33, 3), dtype=np.uint8)
    Image.fromarray(rgb).save(tmp_path / "m/rgb.png")

    def field(name: str, uri: str, pose: str, sampling: int) -> str:
        return (
            f'<model name="{name}"><static>true</static><link name="l"><collision name="c">'
            f"<pose>{pose}</pose><geometry><heightmap><uri>{uri}</uri>"
            f"<size>12 12 3</size><pos>0 0 0.5</pos><sampling>{sampling}</sampling>"
            f"</heightmap></geometry></collision></link></model>"
        )

    gz_world = tmp_path / "gz.sdf"
    gz_world.write_text(
        world_sdf(
            field("a", "m/grey16.png", "3 -2 1 0 0 0.4", 3)
            + field("b", "m/rgb.png", "-20 5 0 0 0 0", 1)
        )
    )
    geo = read_world(gz_world)
    _, probes = probe_world(gz_world, [], tmp_path / "probe_gz")
    assert check_heightmaps(geo, probes, "gz") == 2
    grey = rng.integers(0, 256, (33, 33), dtype=np.uint8)
    Image.fromarray(grey).save(tmp_path / "m/grey.png")
    classic_world = tmp_path / "classic.world"
    classic_world.write_text(world_sdf(field("b", "m/grey.png", "7 5 2 0 0 0.3", 2), "1.6"))
    geo = read_world(classic_world, simulator="classic")
    _, probes = probe_world(classic_world, [], tmp_path / "probe_classic")
    assert check_heightmaps(geo, probes, "classic") == 1


def test_max_elevation_counts_a_sample_of_one_as_full(tmp_path: Path) -> None:
    """gz-math's Color::Set keeps 0 and 1 and divides larger values by 255: an 8-bit image
    holding a 1 gets MaxElevation 1, and its brightest sample (200) lands at 200/255 of size.z,
    in gz-common and here."""
    pixels = np.zeros((9, 9), dtype=np.uint8)
    pixels[4, 4] = 200
    pixels[0, 0] = 1
    Image.fromarray(pixels).save(tmp_path / "hm.png")
    world = tmp_path / "w.sdf"
    world.write_text(
        world_sdf(
            '<model name="m"><static>true</static><link name="l"><collision name="c">'
            "<geometry><heightmap><uri>hm.png</uri><size>8 8 10</size></heightmap>"
            "</geometry></collision></link></model>"
        )
    )
    geo = read_world(world)
    assert "MaxElevation 1," in geo.parts[0]
    assert geo.vertices[:, 2].max() == pytest.approx(10 * 200 / 255, rel=1e-6)
    _, probes = probe_world(world, [], tmp_path / "probe")
    assert probes[0].max_elevation == pytest.approx(1.0)
    assert check_heightmaps(geo, probes, "gz") == 1


# --------------------------------------------------------------------------- refusals


def collision(geometry: str, pose: str = "0 0 0 0 0 0") -> str:
    return world_sdf(
        f'<model name="m"><static>true</static><link name="l"><collision name="c">'
        f"<pose>{pose}</pose><geometry>{geometry}</geometry></collision></link></model>"
    )


def refused(world: Path, **kwargs: object) -> InputError:
    with pytest.raises(InputError) as info:
        read_world(world, **kwargs)  # type: ignore[arg-type]
    message = str(info.value)
    assert "\n" not in message.strip()
    return info.value


BOX = "<box><size>1 1 1</size></box>"


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("<sdf version='1.9'><world name='w'>", "not XML"),
        ("<html><body>hello</body></html>", "not an SDF file"),
        ("<?xml version='1.0'?><sdf version='1.9'><light name='l'/></sdf>", "without a <world>"),
        (world_sdf(""), "no collision geometry"),
        (
            world_sdf(
                '<model name="m"><link name="l"><visual name="v"><geometry>'
                f"{BOX}</geometry></visual></link></model>"
            ),
            "no collision geometry",
        ),
        (collision("<box><size>-1 1 1</size></box>"), "non-negative"),
        (collision("<box><size>1 1</size></box>"), "must be 3 numbers"),
        (collision(BOX, "0 0 nan 0 0 0"), "not finite"),
        (collision(BOX, "1e12 0 0 0 0 0"), "beyond"),
        (collision("<box><size>1e12 1 1</size></box>"), "beyond"),
        (collision("<sphere><radius>0</radius></sphere>"), "positive"),
        (collision("<cylinder><radius>inf</radius><length>1</length></cylinder>"), "not finite"),
        (collision("<image><uri>x.png</uri></image>"), "not a geometry read here"),
        (collision(BOX + "<sphere><radius>1</radius></sphere>"), "more than one shape"),
        (collision("<plane><normal>0 0 0</normal></plane>"), "nonzero"),
        (
            collision(
                "<polyline><point>0 0</point><point>1 1</point><height>1</height></polyline>"
            ),
            "fewer than 3",
        ),
        (
            collision(
                "<polyline><point>0 0</point><point>1 0</point><point>1 1</point>"
                "<height>-1</height></polyline>"
            ),
            "positive",
        ),
        (
            collision(
                "<polyline><point>0 0</point><point>1 x</point><point>1 1</point>"
                "<height>1</height></polyline>"
            ),
            "2 numbers",
        ),
        (
            collision(
                "<polyline><point>0 0</point><point>2 2</point><point>2 0</point>"
                "<point>0 2</point><height>1</height></polyline>"
            ),
            "even-odd",
        ),
        (
            collision("<heightmap><uri>h.png</uri><size>0 10 1</size></heightmap>"),
            "must be positive",
        ),
        (collision("<heightmap><uri>h.png</uri><size>10 10 -1</size></heightmap>"), "negative"),
        (collision("<heightmap><uri>h.png</uri><size>1e12 1 1</size></heightmap>"), "beyond"),
        (
            collision("<mesh><uri>m.stl</uri><submesh><name>a</name></submesh></mesh>"),
            "<submesh>",
        ),
        (collision("<mesh><uri>https://fuel.gazebosim.org/m.stl</uri></mesh>"), "downloaded"),
        (collision("<mesh><uri>model://nowhere/m.stl</uri></mesh>"), "found nowhere"),
        (
            world_sdf(
                '<model name="m"><link name="l"><collision name="c">'
                '<pose relative_to="other">0 0 0 0 0 0</pose>'
                f"<geometry>{BOX}</geometry></collision></link></model>"
            ),
            "relative_to",
        ),
        (world_sdf("<include><uri>model://nowhere</uri></include>"), "found nowhere"),
        (world_sdf("<include><uri>self.sdf</uri></include>"), "includes itself"),
    ],
)
def test_bad_worlds_are_one_input_error_naming_the_world(
    tmp_path: Path, text: str, problem: str
) -> None:
    world = tmp_path / "self.sdf"
    world.write_text(text)
    error = refused(world)
    assert error.path == world
    assert problem in error.problem, error.problem


def test_missing_world_file(tmp_path: Path) -> None:
    error = refused(tmp_path / "nope.sdf")
    assert error.path == tmp_path / "nope.sdf" and "not found" in error.problem


def test_include_loop_through_two_models(tmp_path: Path) -> None:
    for a, b in (("a", "b"), ("b", "a")):
        folder = tmp_path / "models" / a
        folder.mkdir(parents=True)
        (folder / "model.sdf").write_text(
            f'<?xml version="1.0"?><sdf version="1.9"><model name="{a}">'
            f"<include><uri>model://{b}</uri></include></model></sdf>"
        )
    world = tmp_path / "w.sdf"
    world.write_text(world_sdf("<include><uri>model://a</uri></include>"))
    error = refused(world)
    assert "includes itself" in error.problem
    assert isinstance(error.path, Path) and error.path.name == "model.sdf"


def write_mesh_world(tmp_path: Path, name: str, data: bytes | None) -> Path:
    if data is not None:
        (tmp_path / name).write_bytes(data)
    world = tmp_path / "w.sdf"
    world.write_text(collision(f"<mesh><uri>{name}</uri></mesh>"))
    return world


@pytest.mark.parametrize(
    ("name", "data", "problem"),
    [
        ("gone.stl", None, "not found"),
        ("cut.stl", cube_stl()[:-20], "truncated"),
        ("short.stl", b"\x00" * 40, "not an STL"),
        ("empty.stl", b"\x00" * 80 + struct.pack("<I", 0), "no triangles"),
        ("cut_ascii.stl", b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\n", "endsolid"),
        (
            "nan.stl",
            b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n"
            b"vertex nan 1 0\nendloop\nendfacet\nendsolid x\n",
            "not finite",
        ),
        ("garbage.obj", b"this is not\x00 an obj file \xff\xfe at all\n" * 10, "no triangles"),
        ("garbage.dae", b"<COLLADA><oops", "not XML"),
        ("other.dae", b"<?xml version='1.0'?><svg/>", "not a COLLADA"),
        (
            "entity.dae",
            b'<?xml version="1.0"?><!DOCTYPE c [<!ENTITY e "x">]><COLLADA>&e;</COLLADA>',
            "entities",
        ),
        ("model.ply", b"ply\n", "not read"),
    ],
)
def test_bad_meshes_name_the_mesh_file(
    tmp_path: Path, name: str, data: bytes | None, problem: str
) -> None:
    error = refused(write_mesh_world(tmp_path, name, data))
    assert error.path == tmp_path / name
    assert problem in error.problem, error.problem


@pytest.mark.parametrize(
    ("data", "problem"),
    [
        (None, "not found"),
        (b"not an image at all", "not an image"),
        (b"\x89PNG\r\n\x1a\n\x00\x00\x00\x0dIHDR", "truncated"),
        ("16bit-rgb", "16-bit colour"),
        ("wide", "square"),
    ],
)
def test_bad_heightmap_images_name_the_image(
    tmp_path: Path, data: bytes | str | None, problem: str
) -> None:
    image = tmp_path / "h.png"
    if data == "16bit-rgb":
        # A 16-bit RGB PNG written by hand (Pillow cannot write one): IHDR bit depth 16, type 2.
        import zlib

        raw = b"".join(b"\x00" + b"\x12\x34" * 3 * 3 for _ in range(3))

        def chunk(kind: bytes, body: bytes) -> bytes:
            return (
                struct.pack(">I", len(body))
                + kind
                + body
                + struct.pack(">I", zlib.crc32(kind + body))
            )

        image.write_bytes(
            b"\x89PNG\r\n\x1a\n"
            + chunk(b"IHDR", struct.pack(">IIBBBBB", 3, 3, 16, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw))
            + chunk(b"IEND", b"")
        )
    elif data == "wide":
        Image.fromarray(np.zeros((9, 17), dtype=np.uint8)).save(image)
    elif isinstance(data, bytes):
        image.write_bytes(data)
    world = tmp_path / "w.sdf"
    world.write_text(collision("<heightmap><uri>h.png</uri><size>10 10 1</size></heightmap>"))
    error = refused(world)
    assert error.path == image
    assert problem in error.problem, error.problem


def test_classic_heightmaps_need_8_bits_and_a_side_of_2n_plus_1(tmp_path: Path) -> None:
    world = tmp_path / "w.world"
    world.write_text(collision("<heightmap><uri>h.png</uri><size>10 10 1</size></heightmap>"))
    Image.fromarray(np.zeros((17, 17), dtype=np.uint16) + 300).save(tmp_path / "h.png")
    assert "16-bit" in refused(world, simulator="classic").problem
    read_world(world, simulator="gz")  # gz reads 16 bits
    Image.fromarray(np.zeros((16, 16), dtype=np.uint8)).save(tmp_path / "h.png")
    assert "2^n+1" in refused(world, simulator="classic").problem
    read_world(world, simulator="gz")
    rgb = np.zeros((17, 17, 3), dtype=np.uint8)
    rgb[..., 1] = 9
    Image.fromarray(rgb).save(tmp_path / "h.png")
    assert "greyscale" in refused(world, simulator="classic").problem
    read_world(world, simulator="gz")


def test_a_world_over_the_triangle_budget_is_refused_before_it_is_built(tmp_path: Path) -> None:
    Image.fromarray(np.zeros((65, 65), dtype=np.uint8)).save(tmp_path / "h.png")
    world = tmp_path / "w.sdf"
    world.write_text(
        collision(
            "<heightmap><uri>h.png</uri><size>10 10 1</size><sampling>90</sampling></heightmap>"
        )
    )
    error = refused(world)
    assert error.path == world and f"{MAX_TRIANGLES:,}" in error.problem
