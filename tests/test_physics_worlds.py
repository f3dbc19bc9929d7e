"""Every kind of world we write, driven in gz-sim's own physics (tests/physics_harness.py).

One physics run per world, as a user's robot would meet it: small spheres dropped on wall and
floor cells (or on level terrain) must first touch within 1 cm of the height the map says
(heightmap walls: half a cell, the ridge between pixels) and never end below the ground; a
0.5 x 0.5 x 0.1 m box set on open floor must stay on it; the Husky-sized robot driven at
straight walls 1, 2 and 3 cells thick must stop at the face (1 cm; heightmaps half a cell) and
never pass it; the robot put at the world's spawn pose (spawn.yaml) must rest there, level, on
the ground. Every shape must build (zero failures), and nothing may crash.

Worlds: the four real maps in every geometry, an image, a DEM, a bag (walls and a height grid),
a point cloud (walls and a height grid), and heightmap tiles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
import yaml
from numpy.typing import NDArray
from scipy import ndimage

from scan2terrain.cli import main
from scan2terrain.geometry.faces import faces_at_hits
from scan2terrain.readers import read_map_yaml
from scan2terrain.types import OccupancyGrid
from tests.bagmaker import synthetic_room
from tests.fixtures import HDL_PCD, IMAGES, MAPS, SFBAY
from tests.gazebo_harness import HeightmapProbe, probe_world, terrain_height
from tests.physics_harness import (
    ROBOT_FRONT,
    ROBOT_LENGTH,
    ROBOT_WIDTH,
    Body,
    BodyResult,
    Box,
    Robot,
    Scenario,
    SimResult,
    Sphere,
    simulate,
)

#: Every world driven in gz-sim's physics: `pytest -m 'not slow'` leaves it out, CI runs it.
pytestmark = pytest.mark.slow

H = 2.0  # wall height (the default --height)
RADIUS = 0.05  # probe spheres
GAP = 0.3  # the robot starts this far before a wall face
SPEED = 0.5  # m/s, wheel rim speed when driving at a wall
SETTLE = 0.3  # s braked before driving
DRIVE = 3.0  # s driving: 1.5 m at 0.5 m/s, 1.2 m more than the gap


@dataclass(frozen=True)
class Built:
    """A world folder and what the checks need of it."""

    out: Path
    walls: bool  #: occupancy world (walls from cells) rather than terrain
    heightmap: bool

    @property
    def kind(self) -> str:
        """The geometry the world was written with (its effective config)."""
        cfg = yaml.safe_load((self.out / "scan2terrain.yaml").read_text())
        return str(cfg["world"]["geometry"])

    @property
    def world(self) -> Path:
        return self.out / "world_gz.sdf"

    @property
    def models(self) -> Path:
        return self.out / "models"

    def grid(self) -> OccupancyGrid:
        """The walls' grid in the gz-sim world frame (world axes): the filtered map, or for
        walls whose faces are where the scans' end points lie (``world.wall_faces: hits``) the
        grid of half its cells they are built from (geometry/faces.py), the cells left out
        of a wall free."""
        _, grid = read_map_yaml(self.out / "map/map_gz.yaml")
        config = yaml.safe_load((self.out / "scan2terrain.yaml").read_text())
        if config["world"]["wall_faces"] != "hits" or config["world"]["geometry"] == "heightmap":
            return grid
        walls = grid.data == 100
        fine = faces_at_hits(walls, grid.data == 0)
        data = np.repeat(np.repeat(grid.data, 2, axis=0), 2, axis=1)
        data = np.where(fine, 100, np.where(data == 100, 0, data)).astype(np.int8)
        return OccupancyGrid(data, grid.resolution / 2, grid.origin)

    def spawn(self) -> tuple[float, float, float, float]:
        doc = yaml.safe_load((self.out / "spawn.yaml").read_text())
        x, y, z, _, _, yaw = doc["gz"]["pose"]
        return float(x), float(y), float(z), float(yaw)


def _room_bag(tmp: Path) -> Path:
    return synthetic_room("tf", n_scans=60).write(tmp / "room.bag", "ros1")


#: name -> (command line without -o, is an occupancy world, is a heightmap)
CASES: dict[str, tuple[list[object], bool, bool]] = {
    **{
        f"{m}-{g}": (["map2world", MAPS[m], "--geometry", g], True, g == "heightmap")
        for m in sorted(MAPS)
        for g in ("mesh", "boxes", "polylines", "heightmap")
    },
    "image": (["image2world", IMAGES["bowl_rgb"], "--resolution", "0.25"], False, True),
    "image-valley": (["image2world", IMAGES["winding_valley"]], False, True),
    # 8-bit: Debian's gz-common 4.5.1 (gz-sim Fortress) cannot scale a 16-bit image (its
    # MaxElevation() is 0, so physics keeps heights of 0..1 m); 16-bit DEMs need Garden+.
    "dem": (["dem2world", SFBAY, "--bit-depth", "8"], False, True),
    "bag-walls": (["bag2world", "ROOM_BAG"], True, False),
    "bag-height": (
        ["bag2world", "ROOM_BAG", "--grid", "height", "--geometry", "heightmap"],
        False,
        True,
    ),
    "cloud-walls": (["cloud2world", HDL_PCD, "--z-min", "0.2", "--z-max", "2.0"], True, False),
    "cloud-height": (
        ["cloud2world", HDL_PCD, "--grid", "height", "--resolution", "0.2"],
        False,
        True,
    ),
    "tiles": (
        ["map2world", MAPS["tb3"], "--geometry", "heightmap", "--config", "TILES"],
        True,
        True,
    ),
}


@pytest.fixture(scope="module")
def worlds(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Built]:
    """Worlds are built lazily, once per module."""
    return {}


def build(name: str, worlds: dict[str, Built], tmp: Path) -> Built:
    if name in worlds:
        return worlds[name]
    argv, walls, heightmap = CASES[name]
    args = [str(a) for a in argv]
    if "ROOM_BAG" in args:
        args[args.index("ROOM_BAG")] = str(_room_bag(tmp))
    if "TILES" in args:
        tiles = tmp / "tiles.yaml"
        tiles.write_text("terrain: {max_side: 129}\n")
        args[args.index("TILES")] = str(tiles)
    out = tmp / name
    code = main([*args, "-o", str(out), "-q", "--simulator", "gz"])
    assert code == 0, f"{name}: {args}"
    worlds[name] = Built(out, walls, heightmap)
    return worlds[name]


# --------------------------------------------------------------------------- finding targets


@dataclass(frozen=True)
class WallTarget:
    """A straight wall ``cells`` thick, and where the robot starts to drive at it."""

    cells: int
    x: float  #: robot start (chassis frame), world
    y: float
    yaw: float
    face: float  #: the wall face's coordinate along the heading (x for yaw 0, y for pi/2...)


def _orientations(a: NDArray[np.bool_]) -> list[tuple[float, NDArray[np.bool_]]]:
    """The grid seen so that the heading is +columns: (yaw, view) for +x, -x, +y, -y."""
    return [(0.0, a), (math.pi, a[:, ::-1]), (math.pi / 2, a.T), (-math.pi / 2, a.T[:, ::-1])]


def _back(yaw: float, r: int, c: int, shape: tuple[int, int]) -> tuple[int, int]:
    """(row, col) in the original grid of view cell (r, c)."""
    rows, cols = shape
    if yaw == 0.0:
        return r, c
    if yaw == math.pi:
        return r, cols - 1 - c
    if yaw == math.pi / 2:
        return c, r
    return rows - 1 - c, r


def wall_targets(grid: OccupancyGrid) -> list[WallTarget]:
    """For 1, 2 and 3 cells: a wall exactly that thick on the robot's centre line, whose face
    is straight (one column) for 0.25 m either side, with nothing in front of it across the
    robot's whole width and run-up; the targets' run-ups at least 4 m apart. Deterministic:
    the candidate nearest the map's centre."""
    res = grid.resolution
    wall = grid.data == 100
    inner = math.ceil(0.25 / res)
    outer = math.ceil((ROBOT_WIDTH / 2 + 0.1) / res)
    run = math.ceil((GAP + ROBOT_LENGTH + 0.3) / res)
    targets: list[WallTarget] = []
    starts: list[tuple[float, float]] = []
    rows, cols = grid.shape
    views = _orientations(wall)
    for k in (1, 2, 3):
        best: tuple[float, WallTarget] | None = None
        for yaw, w in views:
            n = w.shape[1]
            thick = np.ones(w.shape, dtype=bool)
            for j in range(k + 1):
                shifted = np.zeros(w.shape, dtype=bool)
                shifted[:, : n - j] = w[:, j:] if j < k else ~w[:, j:]
                thick &= shifted
            cs = np.concatenate([np.zeros((w.shape[0], 1), int), np.cumsum(w, axis=1)], axis=1)
            clear = np.zeros(w.shape, dtype=bool)  # no wall in the run cells before
            clear[:, run:] = (cs[:, run:-1] - cs[:, : n - run]) == 0
            faces = w & clear
            straight = ndimage.minimum_filter1d(faces.view(np.uint8), 2 * inner + 1, axis=0) > 0
            wide = ndimage.minimum_filter1d(clear.view(np.uint8), 2 * outer + 1, axis=0) > 0
            ok = thick & straight & wide
            for r, c in zip(*np.nonzero(ok), strict=True):
                gr, gc = _back(yaw, int(r), int(c), (rows, cols))
                # World coordinates: the face is the near edge of the first wall cell.
                cx = grid.origin.x + (gc + 0.5) * res
                cy = grid.origin.y + (gr + 0.5) * res
                dx, dy = math.cos(yaw), math.sin(yaw)
                face_x, face_y = cx - dx * res / 2, cy - dy * res / 2
                back = GAP + ROBOT_FRONT
                sx, sy = face_x - dx * back, face_y - dy * back
                if any(math.hypot(sx - px, sy - py) < 4.0 for px, py in starts):
                    continue
                face = face_x if abs(dx) > 0.5 else face_y
                target = WallTarget(k, sx, sy, yaw, face)
                d = math.hypot(
                    cx - grid.origin.x - cols * res / 2, cy - grid.origin.y - rows * res / 2
                )
                if best is None or d < best[0]:
                    best = (d, target)
        if best is not None:
            targets.append(best[1])
            starts.append((best[1].x, best[1].y))
    return targets


def drop_points(
    grid: OccupancyGrid, spawn: tuple[float, float], n: int = 24
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(wall points, floor points), each (<= n, 2) world x, y: cell centres on a lattice of
    4 cells (probes never touch each other), floor cells 3 cells clear of any wall, none on
    the robots' paths; spread over the map deterministically."""
    res = grid.resolution
    wall = grid.data == 100
    clear = ndimage.minimum_filter((grid.data == 0).view(np.uint8), size=7, mode="constant") > 0
    rows, cols = np.indices(grid.shape)
    x = grid.origin.x + (cols + 0.5) * res
    y = grid.origin.y + (rows + 0.5) * res
    lattice = (rows % 4 == 0) & (cols % 4 == 0)
    away = np.hypot(x - spawn[0], y - spawn[1]) > 1.5
    out = []
    for mask in (wall & lattice & away, clear & lattice & away):
        idx = np.flatnonzero(mask)
        pick = idx[np.linspace(0, len(idx) - 1, min(n, len(idx))).astype(int)] if len(idx) else idx
        out.append(np.column_stack([x.flat[pick], y.flat[pick]]))
    return out[0], out[1]


def box_spot(grid: OccupancyGrid, avoid: NDArray[np.bool_]) -> tuple[float, float] | None:
    """Open floor with 0.5 m clear all round, away from the other bodies (None: no room)."""
    res = grid.resolution
    size = 2 * math.ceil(0.5 / res) + 1
    ok = (
        ndimage.minimum_filter((grid.data == 0).view(np.uint8), size=size, mode="constant") > 0
    ) & ~avoid
    spots = np.argwhere(ok)
    if len(spots) == 0:
        return None
    r, c = spots[len(spots) // 2]
    return float(grid.origin.x + (c + 0.5) * res), float(grid.origin.y + (r + 0.5) * res)


# --------------------------------------------------------------------------- the run


@dataclass
class Plan:
    """What one world's runs put where, and what each body should do."""

    spawn: tuple[float, float, float, float]  #: x, y, z, yaw (spawn.yaml, gz world)
    bodies: list[Body] = field(default_factory=list)
    walls: NDArray[np.float64] = field(default_factory=lambda: np.empty((0, 2)))
    floor: NDArray[np.float64] = field(default_factory=lambda: np.empty((0, 2)))
    targets: list[WallTarget] = field(default_factory=list)
    terrain: list[tuple[float, float, float]] = field(default_factory=list)  #: x, y, ground
    collisions: list[HeightmapProbe] = field(default_factory=list)
    slope: float = 0.0  #: radians, the ground under the spawn (terrain worlds)


def plan_walls(b: Built, plan: Plan) -> None:
    """Probes on wall and floor cells, a box on open floor, robots at straight walls."""
    sx, sy = plan.spawn[:2]
    grid = b.grid()
    plan.targets = wall_targets(grid)
    plan.walls, plan.floor = drop_points(grid, (sx, sy))
    top = H + 0.3
    for group, points in (("wall", plan.walls), ("floor", plan.floor)):
        for i, (x, y) in enumerate(points):
            plan.bodies.append(Sphere(f"{group}{i}", RADIUS, 0.5, float(x), float(y), top))
    rows, cols = np.indices(grid.shape)
    gx = grid.origin.x + (cols + 0.5) * grid.resolution
    gy = grid.origin.y + (rows + 0.5) * grid.resolution
    avoid = np.hypot(gx - sx, gy - sy) < 1.5
    for x, y in np.concatenate([plan.walls, plan.floor]):
        avoid |= np.hypot(gx - x, gy - y) < 0.6
    spot = box_spot(grid, avoid)
    if spot is not None:
        plan.bodies.append(Box("box", (0.5, 0.5, 0.1), 2.0, (*spot, 0.1, 0.0, 0.0, 0.0)))


def plan_terrain(b: Built, plan: Plan, tmp: Path) -> None:
    """Probes on level ground, their heights from Gazebo's own heightmap loader."""
    sx, sy = plan.spawn[:2]
    _, probes = probe_world(b.world, [b.models], tmp / "hm")
    plan.collisions = [p for p in probes if p.kind == "collision"]
    for i, (x, y) in enumerate(level_points(plan.collisions, (sx, sy))):
        g = ground_at(plan.collisions, x, y)
        plan.terrain.append((x, y, g))
        plan.bodies.append(Sphere(f"terrain{i}", RADIUS, 0.5, x, y, g + 0.3))
    # How steep the ground under the spawned robot is: a plane fitted to Gazebo's heights
    # under its footprint (where no spot is level, the spawn is the flattest one).
    u = np.linspace(-0.5, 0.5, 7)
    gx, gy = np.meshgrid(sx + u, sy + u)
    gz = np.nanmax([terrain_height(c, gx, gy, "gz") for c in plan.collisions], axis=0)
    a = np.column_stack([gx.ravel(), gy.ravel(), np.ones(gx.size)])
    (kx, ky, _), *_ = np.linalg.lstsq(a, gz.ravel(), rcond=None)
    plan.slope = math.atan(math.hypot(kx, ky))


def ground_at(collisions: list[HeightmapProbe], x: float, y: float) -> float:
    """Gazebo's ground height at world (x, y): the highest heightmap there (NaN: none)."""
    heights = [float(terrain_height(c, x, y, "gz")) for c in collisions]
    finite = [h for h in heights if math.isfinite(h)]
    return max(finite) if finite else math.nan


def level_points(
    collisions: list[HeightmapProbe], spawn: tuple[float, float], n: int = 16
) -> list[tuple[float, float]]:
    """Points spread over the terrain where the ground under a probe is level to 5 mm (so the
    first touch is the height under its centre), far apart; never on the spawn."""
    p = collisions[0]
    span = 0.45 * min(p.size[0], p.size[1])
    out: list[tuple[float, float]] = []
    for y in p.pose[1] + np.linspace(-span, span, 25):
        for x in p.pose[0] + np.linspace(-span, span, 25):
            if math.hypot(x - spawn[0], y - spawn[1]) < 1.5:
                continue
            ring = [ground_at(collisions, x + dx, y + dy) for dx in (-RADIUS, 0, RADIUS)
                    for dy in (-RADIUS, 0, RADIUS)]  # fmt: skip
            if np.isfinite(ring).all() and max(ring) - min(ring) <= 0.005:
                out.append((float(x), float(y)))
    return out[:: max(1, len(out) // n)][:n]


def run_world(b: Built, tmp: Path) -> tuple[Plan, SimResult, SimResult | None]:
    """Two physics runs: the robot at the spawn pose with the dropped probes (and the box),
    then, for walls, the robots driven at walls."""
    sx, sy, sz, syaw = b.spawn()
    plan = Plan((sx, sy, sz, syaw), [Robot("spawned", sx, sy, sz, syaw)])
    if b.walls:
        plan_walls(b, plan)
    else:
        plan_terrain(b, plan, tmp)
    result = simulate(b.world, [b.models], Scenario(plan.bodies, steps=1500, dt=0.001), tmp / "s")
    drive = None
    if plan.targets:
        robots: list[Body] = [
            Robot(f"drive{t.cells}", t.x, t.y, 0.0, t.yaw, SPEED, SPEED, SETTLE)
            for t in plan.targets
        ]
        steps = round((SETTLE + DRIVE) / 0.001)
        drive = simulate(b.world, [b.models], Scenario(robots, steps=steps, dt=0.001), tmp / "d")
    return plan, result, drive


# --------------------------------------------------------------------------- the checks


def spawn_problems(b: Built, plan: Plan, result: SimResult) -> list[str]:
    """The robot at the spawn pose rests there, on the ground, level: within 3 degrees, or
    where the world has no level spot (the spawn is the flattest), within 2.5 degrees of the
    ground's own slope there (four rigid wheels on quantised heights)."""
    sx, sy, sz, _ = plan.spawn
    s = result.bodies["spawned"]
    x, y, z, roll, pitch, _ = s.final_pose
    # On terrain the robot settles below the footprint's highest point by up to the rise
    # across its wheelbase.
    dz = 0.02 if b.walls else 0.04
    out = []
    if not (math.hypot(x - sx, y - sy) < 0.05 and abs(z - sz) < dz):
        out.append(f"spawned robot ended at {s.final_pose[:3]}, spawn {(sx, sy, sz)}")
    tilt = math.acos(max(-1.0, min(1.0, math.cos(roll) * math.cos(pitch))))
    if tilt > max(math.radians(3), plan.slope + math.radians(2.5)):
        out.append(f"spawned robot not level: roll {roll:.3f} pitch {pitch:.3f}")
    return out


def touched(body: BodyResult) -> float | None:
    """The height of what a probe sphere first touched (its lowest point then)."""
    c = body.first_contact
    return None if c is None else c.pose[2] + c.depth - RADIUS


def wall_problems(b: Built, plan: Plan, result: SimResult, drive: SimResult | None) -> list[str]:
    """Probes touch wall tops at the wall height and the floor at 0, nothing goes below the
    floor, the box stays on it, and robots stop at wall faces without passing them."""
    out = []
    res = b.grid().resolution
    one_piece_tops = b.kind in ("mesh", "polylines")  # read once: it is the world's config
    # Heightmap walls are ridges between pixels: half a cell of slack (and 5 mm).
    tol_wall = res / 2 + 0.005 if b.heightmap else 0.01
    for body in [*result.bodies.values(), *(drive.bodies.values() if drive else [])]:
        if body.min_z < -0.05:
            out.append(f"{body.name} fell below the ground: min z {body.min_z:.3f}")
    for group, points, want, tol in (
        ("wall", plan.walls, H, tol_wall),
        ("floor", plan.floor, 0.0, 0.01),
    ):
        for i, (x, y) in enumerate(points):
            body = result.bodies[f"{group}{i}"]
            h = touched(body)
            if h is None or abs(h - want) > tol:
                out.append(f"{group}{i} at ({x:.3f}, {y:.3f}) first touched {h}, want {want}")
            if body.final_pose[2] < RADIUS - 0.01:
                out.append(f"{group}{i} ended below the floor: z {body.final_pose[2]:.3f}")
            # One-piece wall tops (mesh, polylines) hold a probe. A heightmap's 1-cell wall is a
            # ridge it rolls off (even up-sampled 2 or 3 times, within 3 s); on boxes a probe
            # that lands on a seam between two boxes can get a sideways contact and roll off.
            held = abs(body.final_pose[2] - H - RADIUS) <= 0.01
            if group == "wall" and one_piece_tops and not held:
                out.append(f"wall{i} at ({x:.3f}, {y:.3f}) not held on top: {body.final_pose[:3]}")
    box = result.bodies.get("box")
    if box is not None and (abs(box.final_pose[2] - 0.05) > 0.01 or box.min_z < 0.0):
        out.append(f"box on open floor ended at z {box.final_pose[2]:.3f} (min {box.min_z:.3f})")
    tol_face = res / 2 + 0.005 if b.heightmap else 0.01
    for t in plan.targets:
        assert drive is not None
        r = drive.bodies[f"drive{t.cells}"]
        dx, dy = math.cos(t.yaw), math.sin(t.yaw)
        along = r.front_final[0] * dx + r.front_final[1] * dy
        face = t.face * (dx if abs(dx) > 0.5 else dy)  # the heading is +-x or +-y
        farthest = r.front_initial[0] * dx + r.front_initial[1] * dy + r.max_advance
        if abs(along - face) > tol_face:
            out.append(f"robot at the {t.cells}-cell wall stopped {face - along:+.4f} m short")
        if farthest > face + tol_face:
            out.append(f"robot at the {t.cells}-cell wall went {farthest - face:.4f} m past it")
    return out


def terrain_problems(plan: Plan, result: SimResult) -> list[str]:
    """Probes first touch the terrain at Gazebo's own height there and end on top of it."""
    out = []
    for i, (x, y, g) in enumerate(plan.terrain):
        body = result.bodies[f"terrain{i}"]
        h = touched(body)
        if h is None or abs(h - g) > 0.01:
            out.append(f"terrain{i} at ({x:.2f}, {y:.2f}) first touched {h}, ground {g:.4f}")
        fx, fy, fz = body.final_pose[:3]
        under = ground_at(plan.collisions, fx, fy)
        if not fz > under + RADIUS - 0.02:  # NaN (off the terrain) fails too
            out.append(f"terrain{i} ended at z {fz:.4f}, the ground there is {under:.4f}")
    return out


@pytest.mark.parametrize("name", list(CASES))
def test_world_in_physics(
    name: str, worlds: dict[str, Built], tmp_path_factory: pytest.TempPathFactory
) -> None:
    tmp = tmp_path_factory.mktemp(name)
    b = build(name, worlds, tmp)
    plan, result, drive = run_world(b, tmp)
    for run in (result, drive):
        if run is not None:
            assert not run.crashed, run.crash_summary()
            assert run.shapes_failed == 0, run.failures
            assert run.shapes_built > 0
    if b.walls:
        # Real maps and the synthetic room have straight walls; a single lidar scan's rings
        # (cloud-walls) may have none that a robot could meet square on.
        assert plan.targets or name.startswith("cloud"), "no straight 1, 2 or 3-cell wall"
    problems = spawn_problems(b, plan, result)
    if b.walls:
        problems += wall_problems(b, plan, result, drive)
    else:
        problems += terrain_problems(plan, result)
    assert not problems, f"{name}: " + "; ".join(problems)
