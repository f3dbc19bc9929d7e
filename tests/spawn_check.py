"""Is a world folder's spawn spot on free, level ground in what the simulator builds?

Read from the written world, not the grid: each world of spawn.yaml is parsed by SDFormat 12
and its geometry rebuilt as Gazebo builds it (tests/gazebo_harness.py), and the ground under
the spawn square (FOOTPRINT a side, axis-aligned in the world: the test maps have yaw 0) is
measured there:

* heightmaps: the surface Gazebo interpolates between the pixels, at every vertex line and
  edge of the square, so a wall pixel whose slope reaches into the square is seen;
* walls (mesh, boxes, polylines) and voxels: every collision box, mesh and extruded polyline
  that reaches into the open square (touching its edge is room enough) below ``CLEARANCE``
  over the spawn z (a ceiling is no obstacle) must stay at or below the spawn z, and a ground
  slab must hold the whole square;
* the spawn z must be on the floor: ``floor`` (default 0), or the slab's top and at most
  ``band`` above it (voxel worlds' floor voxels).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from numpy.typing import NDArray

from scan2terrain.grids.spawn import FOOTPRINT, LEVEL_RISE, LEVEL_SLOPE
from scan2terrain.readers.world import SIMULATORS, Simulator
from tests.gazebo_harness import (
    HeightmapProbe,
    ShapeProbe,
    probe_shapes,
    probe_world,
    terrain_height,
)

#: The spawn pose is written with 3 decimals.
ROUND = 1e-3
#: Reaching into the square by less than this is touching it.
TOUCH = 1e-6
#: Room a robot needs above the spawn z (metres): voxel worlds' obstacles are those up to 2 m
#: above the ground, the floor band (0.3 m) under them.
CLEARANCE = 1.7


@dataclass
class SpawnGround:
    """What lies under the spawn square of one world: ``lowest``/``highest`` surface there
    (metres, world frame), ``z`` the spawn pose's z, ``problems`` in words (empty: free ground)."""

    simulator: str
    z: float
    lowest: float
    highest: float
    problems: list[str]


def spawn_doc(out: Path) -> dict[str, object]:
    doc: dict[str, object] = yaml.safe_load((out / "spawn.yaml").read_text())
    return doc


def spawn_ground(
    out: Path, tmp: Path, *, floor: float | None = 0.0, band: float = ROUND
) -> list[SpawnGround]:
    """The ground under the spawn square in every world of ``out`` (see the module docstring).
    Free ground is at most ``band`` above ``floor`` (metres, world frame; None: the top of the
    ground slab; voxel worlds' floor is the voxels on it)."""
    doc = spawn_doc(out)
    found = []
    for sim in SIMULATORS:
        entry = doc.get(sim)
        if not isinstance(entry, dict):
            continue
        world = out / str(entry["world"])
        x, y, z = (float(v) for v in entry["pose"][:3])
        models = out / "models"
        _, fields = probe_world(world, [models], tmp / f"hm_{sim}")
        fields = [f for f in fields if f.kind == "collision"]
        if fields:
            found.append(_on_heightmaps(fields, sim, x, y, z))
        else:
            _, shapes = probe_shapes(world, [models], tmp / f"shapes_{sim}")
            found.append(_on_shapes([s for s in shapes if s.kind == "collision"], sim, x, y, z))
        ground = found[-1]
        base = ground.lowest if floor is None else floor
        if not base - ROUND <= z <= base + band + ROUND:
            ground.problems.append(f"the spawn z {z} is not on the floor ({base} + {band})")
    assert found, f"{out}: spawn.yaml names no world"
    return found


def _on_heightmaps(
    fields: list[HeightmapProbe], sim: Simulator, x: float, y: float, z: float
) -> SpawnGround:
    half = FOOTPRINT / 2
    xs, ys = [np.array([x - half, x + half])], [np.array([y - half, y + half])]
    for f in fields:
        # Every vertex line crossing the square: the interpolated surface's extremes are there.
        n = f.vert_size
        assert n is not None, f.name
        step = f.size[0] / n if sim == "gz" else f.size[0] / (n - 1)
        ox, oy = (f.pose[0], f.pose[1]) if sim == "gz" else (0.0, 0.0)
        k = np.arange(n) - (n - 1) / 2
        xs.append(ox + k * step)
        ys.append(oy + k * step)
    gx = np.unique(np.concatenate(xs))
    gy = np.unique(np.concatenate(ys))
    gx = gx[(gx >= x - half) & (gx <= x + half)]
    gy = gy[(gy >= y - half) & (gy <= y + half)]
    px, py = np.meshgrid(gx, gy)
    # Tiles meet on shared samples: each point's height from the field that holds it.
    heights = np.full(px.shape, np.nan)
    for f in fields:
        h = np.asarray(terrain_height(f, px, py, sim))
        heights = np.where(np.isnan(heights), h, heights)
    problems = []
    if np.isnan(heights).any():
        problems.append("part of the square is off the terrain")
    lo, hi = float(np.nanmin(heights)), float(np.nanmax(heights))
    _level(problems, z, lo, hi)
    return SpawnGround(sim, z, lo, hi, problems)


def _on_shapes(
    shapes: list[ShapeProbe], sim: Simulator, x: float, y: float, z: float
) -> SpawnGround:
    half = FOOTPRINT / 2
    problems = []
    tops = []
    ground = []
    for s in shapes:
        c, si = np.cos(s.pose[5]), np.sin(s.pose[5])
        if s.type == "box":
            assert s.size is not None
            sx, sy, sz = (v / 2 for v in s.size)
            corners = np.array([[-sx, -sy], [sx, -sy], [sx, sy], [-sx, sy]])
            xy = corners @ np.array([[c, si], [-si, c]]) + np.array(s.pose[:2])
            top = s.pose[2] + sz
            tri = np.array([xy[[0, 1, 2]], xy[[0, 2, 3]]])
            if s.name.startswith("ground_"):
                ground.append(top)
                # The slab holds the whole square: its four corners are inside it.
                local = (np.array([[x - half, y - half], [x + half, y + half], [x - half, y + half],
                                   [x + half, y - half]]) - np.array(s.pose[:2])) @ np.array(
                    [[c, -si], [si, c]])  # fmt: skip
                if (np.abs(local) > np.array([sx, sy]) + TOUCH).any():
                    problems.append(f"{s.name}: the slab does not hold the whole square")
                continue
            if _reach_into(tri, x, y, half).any():
                tops.append(top)
        elif s.triangles is not None:
            t = s.triangles
            xy = t[..., :2] @ np.array([[c, si], [-si, c]]) + np.array(s.pose[:2])
            zs = t[..., 2].max(axis=1) + s.pose[2]
            # A ceiling over the square is no obstacle: the robot drives under it.
            low = t[..., 2].min(axis=1) + s.pose[2] < z + CLEARANCE
            inside = _reach_into(xy, x, y, half) & low
            if inside.any():
                tops.append(float(zs[inside].max()))
        elif s.type != "plane":
            problems.append(f"{s.name}: a {s.type} the check cannot read")
    if not ground:
        problems.append("no ground slab")
    floor = max(ground, default=-np.inf)
    hi = max([floor, *tops])
    if hi > z + ROUND:
        problems.append(f"something {hi - z:.3f} m above the spawn z reaches into the square")
    return SpawnGround(sim, z, floor, hi, problems)


def _reach_into(tri: np.ndarray, x: float, y: float, half: float) -> np.ndarray:
    """Which triangles (T, 3, 2) reach into the open square of half-side ``half`` centred on
    (x, y) by more than TOUCH: the separating axis test (the square's axes, the edge normals;
    a vertical face, a segment in plan, has a zero-length edge, which separates nothing)."""
    h = half - TOUCH
    lo, hi = tri.min(axis=1), tri.max(axis=1)
    apart: NDArray[np.bool_] = (
        (lo[:, 0] >= x + h) | (hi[:, 0] <= x - h) | (lo[:, 1] >= y + h) | (hi[:, 1] <= y - h)
    )
    for k in range(3):
        edge = tri[:, (k + 1) % 3] - tri[:, k]
        normal = np.stack([-edge[:, 1], edge[:, 0]], axis=1)
        proj = np.einsum("tij,tj->ti", tri, normal)
        centre = normal @ np.array([x, y])
        radius = h * np.abs(normal).sum(axis=1)
        real = np.abs(normal).sum(axis=1) > 0
        apart |= real & (
            (proj.min(axis=1) >= centre + radius) | (proj.max(axis=1) <= centre - radius)
        )
    return ~apart


def _level(problems: list[str], z: float, lo: float, hi: float) -> None:
    if hi > z + ROUND:
        problems.append(f"ground up to {hi - z:.3f} m above the spawn z under the square")
    if hi - lo > max(LEVEL_RISE, LEVEL_SLOPE * FOOTPRINT) + ROUND:
        problems.append(f"the ground under the square rises {hi - lo:.3f} m")
