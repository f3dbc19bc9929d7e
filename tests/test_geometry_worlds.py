"""Worlds of walls (--geometry mesh | boxes | polylines), checked with Gazebo's own code.

Every world, gz-sim (SDF 1.9) and Classic (SDF 1.6), is parsed strictly by SDFormat 12 through
tests/gazebo/heightmap_probe.cpp, which also loads every mesh with gz-common's MeshManager (the
loader gz-sim uses). From what the probe returns, not from our own data:

* boxes: the collision boxes, painted back onto the grid one by one (world pose -> grid cells);
* polylines: each collision's <polyline> elements as one polygon with holes, rasterised with
  ``outlines.rasterize`` (even-odd, like Gazebo's triangulation); and every polyline geometry
  (collisions and visuals) extruded by gz-common's ``MeshManager::CreateExtrudedPolyline`` as
  gz-sim builds it: none may fail or crash, and the cell centres inside the extrusions' top caps,
  and inside their bottom caps, must be the wall cells, each covered once;
* mesh: the STL (collision) and COLLADA (visual) triangles as gz-common loaded them: a closed,
  consistently oriented surface between z = 0 and the wall height, whose volume is the wall
  cells' volume and whose top face's outline, scan-line filled, is the wall cells;

and each must give back exactly the occupied cells of the filtered map that the command wrote
beside the world (map/map_<sim>.yaml, the world frame), on every real map. Map frame = world frame
in both simulators: no offset anywhere.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from scan2terrain import grids
from scan2terrain.cli import main
from scan2terrain.commands import maps, voxels
from scan2terrain.config import load_config
from scan2terrain.exporters.sdf import GROUND_MARGIN
from scan2terrain.geometry.outlines import Polygon, rasterize
from scan2terrain.readers import read_map_yaml
from scan2terrain.types import OccupancyGrid, Pose2D
from scan2terrain.world.folder import Result
from tests.conftest import write_map
from tests.fixtures import BOWL, GEB079, MAPS
from tests.gazebo_harness import ShapeProbe, probe_shapes

H = 2.0  # wall height used throughout
GEOMETRIES = ("boxes", "polylines", "mesh")


def build(source: Path, out: Path, geometry: str, **overrides: object) -> Result:
    cfg = load_config(None, {"terrain.height": H, "world.geometry": geometry, **overrides})
    return maps.map2world(source, out, cfg)


def to_grid(grid: OccupancyGrid, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Map-frame points to grid units (u along columns, v along rows, 0 at the lower-left)."""
    o = grid.origin
    c, s = math.cos(o.yaw), math.sin(o.yaw)
    dx, dy = np.asarray(x) - o.x, np.asarray(y) - o.y
    return (c * dx + s * dy) / grid.resolution, (-s * dx + c * dy) / grid.resolution


def paint_boxes(boxes: list[ShapeProbe], grid: OccupancyGrid) -> np.ndarray:
    """How many collision boxes cover each cell of ``grid`` (boxes must sit on cell edges)."""
    counts = np.zeros(grid.shape, dtype=np.int64)
    r = grid.resolution
    for b in boxes:
        x, y, z, roll, pitch, yaw = b.pose
        assert b.size is not None
        sx, sy, sz = b.size
        assert (z, roll, pitch, sz) == pytest.approx((H / 2, 0.0, 0.0, H), abs=1e-9)
        turn = (yaw - grid.origin.yaw) % math.pi
        assert min(turn, math.pi - turn) < 1e-9, f"box {b.name} is not aligned with the grid"
        u, v = to_grid(grid, np.array(x), np.array(y))
        edges = np.array([u - sx / r / 2, v - sy / r / 2, u + sx / r / 2, v + sy / r / 2])
        cells = np.rint(edges).astype(int)
        assert np.abs(edges - cells).max() < 1e-6, f"box {b.name} is not on cell edges"
        c0, r0, c1, r1 = cells
        assert 0 <= r0 < r1 <= grid.shape[0] and 0 <= c0 < c1 <= grid.shape[1]
        counts[r0:r1, c0:c1] += 1
    return counts


def polyline_polygons(shapes: list[ShapeProbe]) -> list[Polygon]:
    """One polygon per geometry: its first <polyline> is the exterior, the others holes."""
    polygons = []
    for s in shapes:
        assert s.type == "polyline" and s.polylines, s.name
        assert s.pose == pytest.approx((0, 0, 0, 0, 0, 0), abs=1e-12)
        assert {h for h, _ in s.polylines} == {H}
        rings = [pts for _, pts in s.polylines]
        assert all(len(ring) >= 4 for ring in rings)
        polygons.append(Polygon(rings[0], tuple(rings[1:])))
    return polygons


def paint_extrusions(shapes: list[ShapeProbe], grid: OccupancyGrid) -> list[np.ndarray]:
    """How many of gz-common's extruded polylines cover each cell centre of ``grid``: one count
    per cap (top, bottom), from the flat triangles at z = H and z = 0 of every extrusion.

    Every geometry must have extruded ("ok"); a failure or crash fails here, by name. A centre
    on an edge shared by two triangles (a diagonal through a cell) is tested a millionth of a
    cell off it, along a direction no triangle edge has, so it counts once.
    """
    broken = [
        f"{s.name}: {s.extrusion} (signal {s.extrusion_signal})"
        for s in shapes
        if s.extrusion != "ok"
    ]
    assert not broken, f"gz-common could not extrude {len(broken)} polylines: {broken[:20]}"
    return paint_caps(
        np.concatenate([s.triangles for s in shapes if s.triangles is not None]), grid
    )


def paint_caps(tri: np.ndarray, grid: OccupancyGrid) -> list[np.ndarray]:
    """How many triangles of ``tri`` (T, 3, 3), flat at z = H (top caps) and at z = 0 (bottom
    caps), cover each cell centre of ``grid``: [top counts, bottom counts]. Other triangles
    must be vertical (walls' sides)."""
    z = tri[..., 2]
    assert np.all(np.isclose(z, 0.0, atol=1e-9) | np.isclose(z, H, atol=1e-9))
    counts: list[np.ndarray] = []
    for level in (H, 0.0):
        cap = tri[np.all(np.isclose(z, level, atol=1e-9), axis=1)]
        u, v = to_grid(grid, cap[..., 0], cap[..., 1])  # (T, 3) each, cells
        # Candidates: the centres in each triangle's bounding box and one cell around it.
        c0 = np.clip(np.floor(u.min(axis=1) - 0.5), 0, grid.shape[1]).astype(np.int64)
        c1 = np.clip(np.ceil(u.max(axis=1) - 0.5) + 1, 0, grid.shape[1]).astype(np.int64)
        r0 = np.clip(np.floor(v.min(axis=1) - 0.5), 0, grid.shape[0]).astype(np.int64)
        r1 = np.clip(np.ceil(v.max(axis=1) - 0.5) + 1, 0, grid.shape[0]).astype(np.int64)
        nc, nr = np.maximum(c1 - c0, 0), np.maximum(r1 - r0, 0)
        size = nc * nr
        t = np.repeat(np.arange(len(cap)), size)
        k = np.arange(int(size.sum())) - np.repeat(np.cumsum(size) - size, size)
        col = c0[t] + k % np.maximum(nc[t], 1)
        row = r0[t] + k // np.maximum(nc[t], 1)
        pu = col + 0.5 + 1e-6
        pv = row + 0.5 + 1e-6 * math.sqrt(2.0)
        side = [
            (u[t, (i + 1) % 3] - u[t, i]) * (pv - v[t, i])
            - (v[t, (i + 1) % 3] - v[t, i]) * (pu - u[t, i])
            for i in range(3)
        ]
        inside = ((side[0] > 0) & (side[1] > 0) & (side[2] > 0)) | (
            (side[0] < 0) & (side[1] < 0) & (side[2] < 0)
        )
        painted = np.zeros(grid.shape, dtype=np.int64)
        np.add.at(painted, (row[inside], col[inside]), 1)
        counts.append(painted)
    return counts


def scanline_fill(segments: np.ndarray, grid: OccupancyGrid) -> np.ndarray:
    """Cells whose centre is inside the closed outline made of ``segments`` (S, 2, 2) in the map
    frame, by the even-odd rule: toggles where each row's centre line crosses a segment."""
    h, w = grid.shape
    u, v = to_grid(grid, segments[..., 0], segments[..., 1])
    u0, v0, u1, v1 = u[:, 0], v[:, 0], u[:, 1], v[:, 1]
    lo, hi = np.minimum(v0, v1), np.maximum(v0, v1)
    first = np.clip(np.ceil(lo - 0.5), 0, h).astype(int)
    stop = np.clip(np.ceil(hi - 0.5), 0, h).astype(int)
    counts = stop - first
    seg = np.repeat(np.arange(len(u0)), counts)
    rows = (
        np.repeat(first, counts)
        + np.arange(seg.size)
        - np.repeat(np.cumsum(counts) - counts, counts)
    )
    yc = rows + 0.5
    t = (yc - v0[seg]) / (v1[seg] - v0[seg])
    xc = u0[seg] + t * (u1[seg] - u0[seg])
    cols = np.clip(np.ceil(xc - 0.5), 0, w).astype(int)
    toggles = np.zeros((h, w + 1), dtype=np.int64)
    np.add.at(toggles, (rows, cols), 1)
    inside: np.ndarray = toggles.cumsum(axis=1)[:, :w] % 2 == 1
    return inside


def top_outline(triangles: np.ndarray) -> np.ndarray:
    """Edges (S, 2, 2), x and y, that belong to exactly one triangle of the top face (z = H)."""
    top = triangles[np.all(np.isclose(triangles[..., 2], H, atol=1e-6), axis=1)]
    edges = np.concatenate([top[:, [0, 1]], top[:, [1, 2]], top[:, [2, 0]]])[..., :2]
    keys = np.round(edges * 1e6).astype(np.int64).reshape(-1, 4)
    swap = (keys[:, 0] > keys[:, 2]) | ((keys[:, 0] == keys[:, 2]) & (keys[:, 1] > keys[:, 3]))
    keys[swap] = keys[swap][:, [2, 3, 0, 1]]
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    outline: np.ndarray = edges[counts[inverse.ravel()] == 1]
    return outline


def check_surface(
    triangles: np.ndarray, grid: OccupancyGrid, occupied: np.ndarray, *, volume: bool = True
) -> None:
    """A closed, outward-oriented prism surface from z = 0 to H over exactly ``occupied``
    (``volume``: exactly the cells' volume, as for outlines along cell edges)."""
    assert triangles.ndim == 3 and triangles.shape[1:] == (3, 3) and len(triangles) > 0
    z = triangles[..., 2]
    assert np.all(np.isclose(z, 0.0, atol=1e-6) | np.isclose(z, H, atol=1e-6))
    # Closed and consistently oriented: each directed edge has as many reverse twins as uses.
    # Boxes may share vertical edges where two solids touch at a corner; the wall mesh moves its
    # vertices there a hair apart (contacts.SPLIT), so its edges are each used once.
    keys = np.round(triangles * 1e6).astype(np.int64)
    forward = np.concatenate(
        [np.concatenate([keys[:, k], keys[:, (k + 1) % 3]], axis=1) for k in range(3)]
    )
    edges, uses = np.unique(forward, axis=0, return_counts=True)
    twins, twin_uses = np.unique(forward[:, [3, 4, 5, 0, 1, 2]], axis=0, return_counts=True)
    assert np.array_equal(edges, twins) and np.array_equal(uses, twin_uses), "not closed"
    shared = edges[uses > 1]
    assert np.all((shared[:, 0] == shared[:, 3]) & (shared[:, 1] == shared[:, 4]))
    # Outward: the enclosed volume (divergence theorem) is positive, the wall cells' volume for
    # outlines along cell edges.
    # (About the mesh's own middle: STL holds float32, and far from the origin the terms of the
    # sum would cancel.)
    local = triangles - triangles.reshape(-1, 3).mean(axis=0)
    six_v = np.einsum("ij,ij->i", local[:, 0], np.cross(local[:, 1], local[:, 2]))
    cells = int(occupied.sum()) * grid.resolution**2 * H
    assert six_v.sum() / 6 > 0.5 * cells
    if volume:
        # At a cell-corner contact each solid loses a sliver at most SPLIT_MAX wide along
        # its two outline edges there (their length is the mesh's business, hence 1e-3).
        assert cells * (1 - 1e-3) <= six_v.sum() / 6 <= cells * (1 + 1e-5)
    # The top face's outline, scan-line filled, is the wall cells.
    assert np.array_equal(scanline_fill(top_outline(triangles), grid), occupied)


def check_walls(
    result: Result, tmp: Path, *, reference: OccupancyGrid | None = None
) -> dict[str, int]:
    """Check every world of ``result``; the walls must be the occupied cells of ``reference``
    (default: the map the command wrote for that world). Returns the wall geometries per sim."""
    found = {}
    kind = result.geometry
    for w in result.worlds:
        sim = w.placement.simulator
        assert w.placement.offset == (0.0, 0.0) and w.placement.geometry == kind
        version, shapes = probe_shapes(w.world, [w.models], tmp / f"probe_{sim}")
        assert version == "1.9"  # parsed strictly by SDFormat 12 (converted from 1.6 for Classic)
        if reference is None:
            assert w.map_yaml is not None
            _, grid = read_map_yaml(w.map_yaml)
        else:
            grid = reference
        occupied = grid.data == 100
        ground = [s for s in shapes if s.name.startswith("ground_")]
        assert sorted(s.kind for s in ground) == ["collision", "visual"]
        extent = (grid.shape[1] * grid.resolution, grid.shape[0] * grid.resolution)
        for g in ground:
            if g.kind == "visual":
                assert g.type == "plane" and g.normal == pytest.approx((0, 0, 1))
                assert g.size == pytest.approx(extent)
            else:  # a slab with its top at z = 0, wider than the grid (not a 2100 m cube)
                assert g.type == "box" and g.size is not None
                assert g.size == pytest.approx(
                    (extent[0] + 2 * GROUND_MARGIN, extent[1] + 2 * GROUND_MARGIN, 1.0)
                )
                assert g.pose[2] == pytest.approx(-g.size[2] / 2)
        walls = [s for s in shapes if not s.name.startswith("ground_")]
        collisions = [s for s in walls if s.kind == "collision"]
        visuals = [s for s in walls if s.kind == "visual"]
        if kind == "boxes":
            assert {s.type for s in collisions} == {"box"}
            counts = paint_boxes(collisions, grid)
            assert counts.max() <= 1, "collision boxes overlap"
            assert np.array_equal(counts == 1, occupied)
            # One visual for all the boxes: a mesh of the same boxes, as gz-common loads it.
            ((vis,),) = (visuals,)
            assert vis.type == "mesh" and vis.mesh_loaded and vis.triangles is not None
            for painted in paint_caps(vis.triangles, grid):
                assert np.array_equal(painted, counts)
        else:
            assert len(collisions) == len(visuals) > 0
        if kind == "polylines":
            polygons = polyline_polygons(collisions)
            for p, s in zip(polygons, visuals, strict=True):
                assert [pts.tolist() for _, pts in s.polylines] == [r.tolist() for r in p.rings()]
            raster = rasterize(polygons, grid.shape, grid.resolution, grid.origin)
            assert np.array_equal(raster, occupied)
            # No two polygons overlap: their areas add up to the wall cells' area.
            area = sum(p.area() for p in polygons)
            assert area == pytest.approx(occupied.sum() * grid.resolution**2, rel=1e-9)
            # What gz-sim builds: gz-common extrudes every one, to exactly the wall cells.
            paint_extrusions(visuals, grid)
            for painted in paint_extrusions(collisions, grid):
                assert np.array_equal(painted, occupied.astype(np.int64))
        elif kind == "mesh":
            ((col,), (vis,)) = collisions, visuals
            assert col.uri is not None and col.uri.endswith(".stl") and col.mesh_loaded
            assert vis.uri is not None and vis.uri.endswith(".dae") and vis.mesh_loaded
            assert col.path is not None and col.path.with_suffix(".obj").is_file()
            for s in (col, vis):
                assert s.pose == pytest.approx((0, 0, 0, 0, 0, 0), abs=1e-12)
                assert s.scale == pytest.approx((1, 1, 1))
                assert s.triangles is not None
                check_surface(s.triangles, grid, occupied)
        found[sim] = len(collisions)
    return found


# --- the real maps ------------------------------------------------------------------------------


@pytest.mark.parametrize("geometry", GEOMETRIES)
@pytest.mark.parametrize("name", sorted(MAPS))
def test_real_map_walls_are_the_occupied_cells(tmp_path: Path, name: str, geometry: str) -> None:
    result = build(MAPS[name], tmp_path / "w", geometry)
    found = check_walls(result, tmp_path)
    assert found["gz"] == found["classic"]
    assert result.heightmap_side == 0 and result.size_z == H
    # The map/ folder, preview and config are written as for heightmaps.
    for rel in ("map/map.pgm", "map/map_gz.yaml", "map/map_classic.yaml", "preview.png"):
        assert (result.out / rel).is_file()
    cfg = load_config(result.out / "scan2terrain.yaml")
    assert cfg.world.geometry == geometry


@pytest.mark.parametrize(
    ("name", "overrides"),
    [(name, {"filter.kind": "paper"}) for name in sorted(MAPS)]
    + [("willow", {"world.simplify": 0.1})],
    ids=[f"{name}-paper" for name in sorted(MAPS)] + ["willow-simplify"],
)
def test_real_map_polylines_build_in_gz_common(
    tmp_path: Path, name: str, overrides: dict[str, object]
) -> None:
    """gz-common 4 (gz-sim Fortress; Garden/Harmonic's gz-common 5 and Classic 11 share the
    code) triangulates every polyline geometry of the real maps with the paper's filter too,
    and straightened: no geometry fails or crashes, the extrusions are exactly the wall cells.
    (The default filter: test_real_map_walls_are_the_occupied_cells.) gz-sim worlds only: the
    Classic world holds the same points."""
    result = build(
        MAPS[name], tmp_path / "w", "polylines", **overrides, **{"world.simulator": "gz"}
    )
    ((w,),) = (result.worlds,)
    assert w.placement.simulator == "gz" and w.map_yaml is not None
    _, grid = read_map_yaml(w.map_yaml)
    occupied = grid.data == 100
    _, shapes = probe_shapes(w.world, [w.models], tmp_path / "probe")
    walls = [s for s in shapes if not s.name.startswith("ground_")]
    collisions = [s for s in walls if s.kind == "collision"]
    visuals = [s for s in walls if s.kind == "visual"]
    assert len(collisions) == len(visuals) > 0
    polygons = polyline_polygons(collisions)
    assert np.array_equal(rasterize(polygons, grid.shape, grid.resolution, grid.origin), occupied)
    paint_extrusions(visuals, grid)
    for painted in paint_extrusions(collisions, grid):
        assert np.array_equal(painted, occupied.astype(np.int64))


def test_real_map_walls_with_unfiltered_source(tmp_path: Path) -> None:
    """Without a filter, the walls are the map_server cells of the ORIGINAL map YAML."""
    _, source = read_map_yaml(MAPS["tb3"])
    source = source.with_data(grids.to_trinary(source.data))
    for geometry in GEOMETRIES:
        result = build(MAPS["tb3"], tmp_path / geometry, geometry, **{"filter.enabled": False})
        check_walls(result, tmp_path / geometry, reference=source)


# --- frames, policies, options ------------------------------------------------------------------


@pytest.mark.parametrize("geometry", GEOMETRIES)
def test_yawed_map_walls_are_placed_exactly(tmp_path: Path, geometry: str) -> None:
    """Walls keep the grid's own yaw (no resampling): exact in the map frame at any yaw."""
    rng = np.random.default_rng(7)
    pixels = np.full((40, 60), 254, dtype=np.uint8)
    pixels[5:8, 3:50] = 0
    pixels[10:35, 20:23] = 0
    pixels[12:30, 40:55] = 0
    pixels[15:25, 45:50] = 254  # a room (hole) in a block
    pixels[rng.random(pixels.shape) < 0.02] = 0
    yaml_path = write_map(tmp_path / "m", pixels, resolution=0.1, origin="[2.5, -1.25, 0.5236]")
    result = build(yaml_path, tmp_path / "w", geometry, **{"filter.enabled": False})
    _, source = read_map_yaml(yaml_path)
    assert source.origin.yaw != 0
    check_walls(result, tmp_path, reference=source)


def test_unknown_as_obstacle_makes_walls(tmp_path: Path) -> None:
    pixels = np.full((30, 30), 254, dtype=np.uint8)
    pixels[3:6, :] = 0
    pixels[10:20, 10:20] = 205  # unknown
    yaml_path = write_map(tmp_path / "m", pixels)
    result = build(
        yaml_path,
        tmp_path / "w",
        "boxes",
        **{"filter.enabled": False, "terrain.unknown": "obstacle"},
    )
    _, source = read_map_yaml(yaml_path)
    walls = source.with_data(np.where(source.data == -1, 100, source.data).astype(np.int8))
    assert check_walls(result, tmp_path, reference=walls) == {"gz": 2, "classic": 2}


@pytest.mark.parametrize("geometry", ["polylines", "mesh"])
def test_simplified_outlines_cover_the_same_cells(tmp_path: Path, geometry: str) -> None:
    """--simplify straightens staircases but moves no cell centre across: still exact."""
    exact = build(MAPS["warehouse"], tmp_path / "exact", geometry)
    simple = build(MAPS["warehouse"], tmp_path / "simple", geometry, **{"world.simplify": 0.12})
    sizes = []
    for result in (exact, simple):
        w = result.worlds[0]
        assert w.map_yaml is not None
        _, grid = read_map_yaml(w.map_yaml)
        occupied = grid.data == 100
        _, shapes = probe_shapes(w.world, [w.models], tmp_path / f"probe_{result.out.name}")
        walls = [s for s in shapes if s.kind == "collision" and not s.name.startswith("ground_")]
        if geometry == "polylines":
            got = rasterize(polyline_polygons(walls), grid.shape, grid.resolution, grid.origin)
            sizes.append(sum(len(pts) for s in walls for _, pts in s.polylines))
            for painted in paint_extrusions(walls, grid):
                assert np.array_equal(painted, occupied.astype(np.int64))
        else:
            ((col,),) = (walls,)
            assert col.triangles is not None
            check_surface(col.triangles, grid, occupied, volume=result is exact)
            outline = top_outline(col.triangles)
            got = scanline_fill(outline, grid)
            sizes.append(len(outline))
        assert np.array_equal(got, occupied)
    assert sizes[1] < 0.9 * sizes[0]  # fewer outline vertices


def test_octree_occupancy_walls(tmp_path: Path) -> None:
    cfg = load_config(
        None,
        {
            "terrain.height": H,
            "world.geometry": "boxes",
            "octree.z_min": 0.1,
            "octree.z_max": 1.8,
            "world.wall_faces": "cells",  # the boxes on the cell edges of the map
        },
    )
    result = voxels.octree2world(GEB079, tmp_path / "w", cfg)
    found = check_walls(result, tmp_path)
    assert found["gz"] > 1000


def test_walls_are_deterministic(tmp_path: Path) -> None:
    def files(folder: Path) -> dict[str, bytes]:
        return {
            str(p.relative_to(folder)): p.read_bytes()
            for p in sorted(folder.rglob("*"))
            if p.is_file() and p.suffix != ".png"
        }

    for geometry in GEOMETRIES:
        a = build(MAPS["tb3"], tmp_path / f"a_{geometry}", geometry)
        b = build(MAPS["tb3"], tmp_path / f"b_{geometry}", geometry)
        assert files(a.out) == files(b.out)
        names = {p.name for p in (a.out / "models").iterdir()}
        assert len(names) == 2 and all(n.startswith("map_") for n in names)


# --- the command line ---------------------------------------------------------------------------


def test_cli_reports_walls(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "w"
    assert main(["map2world", str(MAPS["tb3"]), "-o", str(out), "--geometry", "boxes"]) == 0
    text = capsys.readouterr().out
    assert text.startswith(f"Wrote {out}/ (boxes: 202 boxes")
    assert text.count("map frame = world frame: a map point (x, y) is world (x, y).") == 2
    assert "Classic cannot move" not in text


@pytest.mark.parametrize("geometry", ["mesh", "boxes", "polylines"])
def test_map_without_walls_is_a_ground_alone(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], geometry: str
) -> None:
    """No wall cell: a world of the ground alone (an empty room is a world), parsed strictly."""
    pixels = np.full((20, 20), 254, dtype=np.uint8)
    pixels[5:8, 5:8] = 205
    yaml_path = write_map(tmp_path / "m", pixels)
    out = tmp_path / "w"
    code = main(["map2world", str(yaml_path), "-o", str(out), "--geometry", geometry])
    assert code == 0, capsys.readouterr().err
    for name in ("world_gz.sdf", "world_classic.world"):
        _, shapes = probe_shapes(out / name, [out / "models"], tmp_path / name)
        assert sorted((s.name, s.type) for s in shapes) == [
            ("ground_collision", "box"),
            ("ground_visual", "plane"),
        ]
    assert not list((out / "models").glob("*/meshes"))


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["map2world", str(MAPS["tb3"]), "--geometry", "boxes", "--unknown", "height"], "unknown"),
        (["map2world", str(MAPS["tb3"]), "--geometry", "mesh", "--simplify", "-1"], "simplify"),
        (["octree2world", "x.bt", "--geometry", "boxes", "--grid", "height"], "octree.grid"),
    ],
)
def test_bad_geometry_config(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    out = tmp_path / "w"
    assert main([*args, "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err
    assert not out.exists()


def test_unknown_geometry_is_a_usage_error(tmp_path: Path) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["map2world", str(MAPS["tb3"]), "-o", str(tmp_path / "w"), "--geometry", "cubes"])
    assert exc.value.code == 2


def test_image_input_refuses_walls(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "c.yaml"
    config.write_text("world:\n  geometry: mesh\n")
    image = BOWL
    out = tmp_path / "w"
    assert main(["image2world", str(image), "-o", str(out), "--config", str(config)]) == 2
    assert "image2world makes heightmaps only" in capsys.readouterr().err
    assert not out.exists()


def test_pose2d_is_what_to_grid_inverts() -> None:
    o = Pose2D(1.0, -2.0, 0.7)
    grid = OccupancyGrid(np.zeros((3, 3), dtype=np.int8), 0.5, o)
    x, y = o.transform(np.array([0.25, 1.0]), np.array([0.75, 0.5]))
    u, v = to_grid(grid, x, y)
    np.testing.assert_allclose(u, [0.5, 2.0])
    np.testing.assert_allclose(v, [1.5, 1.0])
