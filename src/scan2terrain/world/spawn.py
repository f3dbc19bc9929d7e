"""Where a robot is spawned in a world: the spawn search (grids/spawn.py) started from the
robot's recorded start, and the ground a heightmap has beyond its grid."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from scan2terrain.exporters.heightmap import Heightmap
from scan2terrain.exporters.tiles import Terrain
from scan2terrain.grids.spawn import Around, find_spawn
from scan2terrain.types import Pose2D, Spawn, StartPose


def spawn_for(
    heights: NDArray[np.floating],
    resolution: float,
    origin: Pose2D,
    start: StartPose | None,
    *,
    ground: NDArray[np.bool_] | None = None,
    free: NDArray[np.bool_] | None = None,
    samples: bool = False,
    around: Around | None = None,
) -> Spawn:
    """The spawn spot of a world's ground (map frame; see grids/spawn.py): searched from the
    robot's recorded start when there is one, else from the map origin (or the centre).
    ``samples``: a heightmap's (Gazebo interpolates between them); ``around``: the ground the
    world has beyond the grid (a walls world's slab, a heightmap's padding)."""
    if start is None:
        return find_spawn(
            heights, resolution, origin, ground=ground, free=free, samples=samples, around=around
        )
    p = start.pose
    return find_spawn(
        heights, resolution, origin, preferred=(p.x, p.y), yaw=p.yaw, ground=ground,
        free=free, why=start.why, samples=samples, around=around,
    )  # fmt: skip


def terrain_around(hm: Terrain, upsample: int, height: float) -> Around | None:
    """The padding of one heightmap around its grid, in whole grid cells (``upsample``
    pixels a cell), at ``height`` metres: ground Gazebo builds beyond the map. Tiles: None
    (their padding is on the far sides of the last tiles only)."""
    if not isinstance(hm, Heightmap):
        return None
    rows, cols = hm.grid_shape
    left, bottom = hm.pad
    right, top = hm.side - cols - left, hm.side - rows - bottom
    return Around(
        (left // upsample, bottom // upsample, right // upsample, top // upsample), height
    )
